"""JointState, PoseStamped, PoseArray and Odometry <-> numpy (quaternions xyzw).

Writers validate their arrays (shape, finite, unit quaternions, normalised when
within tolerance) and readers validate the message the same way; both raise
``MalformedMessageError``. Readers return new arrays, never views of a message.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lip_msgs_py._validate import covariance_matrix, finite_array, unit_quaternions
from lip_msgs_py.backend import Backend
from lip_msgs_py.errors import MalformedMessageError
from lip_msgs_py.geometry import pose_msg, quat_of, vector3_msg, xyz_of
from lip_msgs_py.stamps import read_header

__all__ = [
    "StampedJointState",
    "StampedPose",
    "StampedPoses",
    "StampedOdometry",
    "joint_state_to_msg",
    "msg_to_joint_state",
    "pose_stamped_to_msg",
    "msg_to_pose_stamped",
    "pose_array_to_msg",
    "msg_to_pose_array",
    "odometry_to_msg",
    "msg_to_odometry",
]


@dataclass(frozen=True, eq=False)
class StampedJointState:
    """Joint names and positions (rad for revolute joints) of a JointState."""

    stamp_ns: int
    frame_id: str
    names: tuple[str, ...]
    positions: np.ndarray  # (J,)


@dataclass(frozen=True, eq=False)
class StampedPose:
    """Position (3,) and orientation (4,) xyzw of a PoseStamped."""

    stamp_ns: int
    frame_id: str
    position: np.ndarray
    quat: np.ndarray


@dataclass(frozen=True, eq=False)
class StampedPoses:
    """Positions (N, 3) and orientations (N, 4) xyzw of a PoseArray."""

    stamp_ns: int
    frame_id: str
    positions: np.ndarray
    quats: np.ndarray


@dataclass(frozen=True, eq=False)
class StampedOdometry:
    """An Odometry: pose in ``frame_id``, twist in ``child_frame_id``, (6, 6) covariances."""

    stamp_ns: int
    frame_id: str
    child_frame_id: str
    position: np.ndarray  # (3,)
    quat: np.ndarray  # (4,) xyzw
    linear: np.ndarray  # (3,) m/s
    angular: np.ndarray  # (3,) rad/s
    pose_cov: np.ndarray  # (6, 6)
    twist_cov: np.ndarray  # (6, 6)


def unique_names(names: Sequence[str], what: str) -> tuple[str, ...]:
    """``names`` as a tuple of strings; MalformedMessageError if one repeats."""
    names = tuple(str(n) for n in names)
    if len(set(names)) != len(names):
        raise MalformedMessageError(f"{what}: duplicate joint names")
    return names


def joint_state_to_msg(
    backend: Backend, stamp_ns: int, frame_id: str, names: Sequence[str], positions: Any
) -> Any:
    """``sensor_msgs/msg/JointState`` with ``positions`` (J,) for ``names`` (e.g. the 69 ``<joint>_rz/_ry/_rx``)."""
    names = unique_names(names, "JointState")
    positions = finite_array(positions, (len(names),), "JointState position")
    return backend.msg(
        "sensor_msgs/msg/JointState",
        header=backend.header(stamp_ns, frame_id),
        name=list(names),
        position=positions,
    )


def msg_to_joint_state(msg: Any, names: Sequence[str] | None = None) -> StampedJointState:
    """Names and positions of a JointState, reordered to ``names`` if given (all must be present)."""
    stamp_ns, frame_id = read_header(msg)
    have = unique_names(msg.name, "JointState")
    positions = finite_array(msg.position, (len(have),), "JointState position")
    if names is None:
        return StampedJointState(stamp_ns, frame_id, have, positions)
    index = {name: i for i, name in enumerate(have)}
    missing = [name for name in names if name not in index]
    if missing:
        raise MalformedMessageError(f"JointState lacks {len(missing)} joint(s), e.g. {missing[:3]}")
    return StampedJointState(stamp_ns, frame_id, tuple(names), positions[[index[n] for n in names]])


def pose_stamped_to_msg(backend: Backend, stamp_ns: int, frame_id: str, position: Any, quat: Any) -> Any:
    """``geometry_msgs/msg/PoseStamped`` of a position (3,) and an xyzw quaternion (4,)."""
    p = finite_array(position, (3,), "PoseStamped position")
    q = unit_quaternions(quat, (), "PoseStamped orientation")
    return backend.msg(
        "geometry_msgs/msg/PoseStamped", header=backend.header(stamp_ns, frame_id), pose=pose_msg(backend, p, q)
    )


def msg_to_pose_stamped(msg: Any) -> StampedPose:
    """Position and xyzw quaternion of a PoseStamped."""
    stamp_ns, frame_id = read_header(msg)
    return StampedPose(
        stamp_ns,
        frame_id,
        finite_array(xyz_of(msg.pose.position), (3,), "PoseStamped position"),
        unit_quaternions(quat_of(msg.pose.orientation), (), "PoseStamped orientation"),
    )


def pose_array_to_msg(backend: Backend, stamp_ns: int, frame_id: str, positions: Any, quats: Any) -> Any:
    """``geometry_msgs/msg/PoseArray`` of positions (N, 3) and xyzw quaternions (N, 4)."""
    p = finite_array(positions, (None, 3), "PoseArray positions")
    q = unit_quaternions(quats, (len(p),), "PoseArray orientations")
    return backend.msg(
        "geometry_msgs/msg/PoseArray",
        header=backend.header(stamp_ns, frame_id),
        poses=[pose_msg(backend, pi, qi) for pi, qi in zip(p, q)],
    )


def msg_to_pose_array(msg: Any, num_poses: int | None = None) -> StampedPoses:
    """Positions (N, 3) and xyzw quaternions (N, 4) of a PoseArray; ``num_poses`` checks N."""
    stamp_ns, frame_id = read_header(msg)
    if num_poses is not None and len(msg.poses) != num_poses:
        raise MalformedMessageError(f"PoseArray has {len(msg.poses)} poses, expected {num_poses}")
    positions = np.reshape([xyz_of(p.position) for p in msg.poses], (-1, 3))
    quats = np.reshape([quat_of(p.orientation) for p in msg.poses], (-1, 4))
    return StampedPoses(
        stamp_ns,
        frame_id,
        finite_array(positions, (None, 3), "PoseArray positions"),
        unit_quaternions(quats, (None,), "PoseArray orientations"),
    )


def odometry_to_msg(
    backend: Backend,
    stamp_ns: int,
    frame_id: str,
    child_frame_id: str,
    position: Any,
    quat: Any,
    linear: Any = None,
    angular: Any = None,
    pose_cov: Any = None,
    twist_cov: Any = None,
) -> Any:
    """``nav_msgs/msg/Odometry``; omitted twist is zero, omitted (6, 6) covariances are zeros (unknown)."""
    zeros3 = np.zeros(3)
    twist = backend.msg(
        "geometry_msgs/msg/Twist",
        linear=vector3_msg(backend, zeros3 if linear is None else finite_array(linear, (3,), "Odometry linear")),
        angular=vector3_msg(backend, zeros3 if angular is None else finite_array(angular, (3,), "Odometry angular")),
    )
    pose = pose_msg(
        backend, finite_array(position, (3,), "Odometry position"), unit_quaternions(quat, (), "Odometry orientation")
    )
    return backend.msg(
        "nav_msgs/msg/Odometry",
        header=backend.header(stamp_ns, frame_id),
        child_frame_id=str(child_frame_id),
        pose=backend.msg(
            "geometry_msgs/msg/PoseWithCovariance",
            pose=pose,
            covariance=covariance_matrix(pose_cov, 6, "Odometry pose").reshape(36),
        ),
        twist=backend.msg(
            "geometry_msgs/msg/TwistWithCovariance",
            twist=twist,
            covariance=covariance_matrix(twist_cov, 6, "Odometry twist").reshape(36),
        ),
    )


def msg_to_odometry(msg: Any) -> StampedOdometry:
    """Pose, twist and covariances of an Odometry."""
    stamp_ns, frame_id = read_header(msg)
    pose, twist = msg.pose, msg.twist
    return StampedOdometry(
        stamp_ns=stamp_ns,
        frame_id=frame_id,
        child_frame_id=str(msg.child_frame_id),
        position=finite_array(xyz_of(pose.pose.position), (3,), "Odometry position"),
        quat=unit_quaternions(quat_of(pose.pose.orientation), (), "Odometry orientation"),
        linear=finite_array(xyz_of(twist.twist.linear), (3,), "Odometry linear"),
        angular=finite_array(xyz_of(twist.twist.angular), (3,), "Odometry angular"),
        pose_cov=covariance_matrix(pose.covariance, 6, "Odometry pose"),
        twist_cov=covariance_matrix(twist.covariance, 6, "Odometry twist"),
    )
