"""The contract's pose messages of one frame, for any message backend (rclpy nodes, rosbags bags).

A set of pose topics (:class:`PoseTopics`): joint states (JointState, 69
``<joint>_rz/_ry/_rx`` angles), root pose (PoseStamped), joint poses
(PoseArray, 24 joints) and, optionally, the skeleton (MarkerArray). Each branch
names its own (LIP: :data:`lip_ros.lip.sensors.LIP_TOPICS`, ``/lip/*``); the
rig's ground truth is :data:`GT_TOPICS` (``/gt/*``), built the same way.
:func:`pose_messages` builds message objects (bags, tools), :func:`pose_cdr`
the same messages as CDR bytes (live nodes publish them as they are).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from lip_msgs_py import (
    Backend,
    joint_state_to_msg,
    pose_array_to_msg,
    pose_stamped_to_msg,
    skeleton_to_markers,
)
from lip_msgs_py.cdr_writer import joint_state_cdr, pose_array_cdr, pose_stamped_cdr, skeleton_markers_cdr
from lip_ros.core.rotations import matrix_to_quat
from lip_ros.core.skeleton import Skeleton, joint_state_names, local_rotations_to_joint_angles

__all__ = ["PoseTopics", "GT_TOPICS", "pose_messages", "pose_cdr"]


@dataclass(frozen=True)
class PoseTopics:
    """Topic names of one set of pose outputs (``skeleton`` None: no markers)."""

    joint_states: str
    root_pose: str
    joint_poses: str
    skeleton: str | None = None


GT_TOPICS = PoseTopics("/gt/joint_states", "/gt/root_pose", "/gt/joint_poses")


@dataclass(frozen=True)
class _Writers:
    """Writers of the four pose messages, from arrays (the object writers with their backend, or the CDR ones)."""

    joint_state: Callable[..., Any]
    pose_stamped: Callable[..., Any]
    pose_array: Callable[..., Any]
    markers: Callable[..., Any]


_CDR_WRITERS = _Writers(joint_state_cdr, pose_stamped_cdr, pose_array_cdr, skeleton_markers_cdr)


def _pose_outputs(write: _Writers, topics: PoseTopics, skeleton: Skeleton, stamp_ns: int, frame_id: str,
                  local_rot: np.ndarray, glob_rot: np.ndarray, joint_pos: np.ndarray) -> dict[str, tuple[str, Any]]:
    """topic -> (type name, what ``write`` wrote) for one pose."""
    quats = matrix_to_quat(glob_rot)
    out = {
        topics.joint_states: ("sensor_msgs/msg/JointState", write.joint_state(
            stamp_ns, frame_id, joint_state_names(skeleton), local_rotations_to_joint_angles(local_rot))),
        topics.root_pose: ("geometry_msgs/msg/PoseStamped",
                           write.pose_stamped(stamp_ns, frame_id, joint_pos[0], quats[0])),
        topics.joint_poses: ("geometry_msgs/msg/PoseArray", write.pose_array(stamp_ns, frame_id, joint_pos, quats)),
    }
    if topics.skeleton is not None:
        out[topics.skeleton] = ("visualization_msgs/msg/MarkerArray",
                                write.markers(stamp_ns, frame_id, joint_pos, skeleton.parents))
    return out


def pose_messages(
    backend: Backend,
    topics: PoseTopics,
    skeleton: Skeleton,
    stamp_ns: int,
    frame_id: str,
    local_rot: np.ndarray,
    glob_rot: np.ndarray,
    joint_pos: np.ndarray,
) -> dict[str, tuple[str, Any]]:
    """topic -> (type name, message) for one pose: local rotations (24, 3, 3), global rotations and positions in L."""
    write = _Writers(*(partial(f, backend) for f in (joint_state_to_msg, pose_stamped_to_msg, pose_array_to_msg,
                                                       skeleton_to_markers)))
    return _pose_outputs(write, topics, skeleton, stamp_ns, frame_id, local_rot, glob_rot, joint_pos)


def pose_cdr(
    topics: PoseTopics,
    skeleton: Skeleton,
    stamp_ns: int,
    frame_id: str,
    local_rot: np.ndarray,
    glob_rot: np.ndarray,
    joint_pos: np.ndarray,
) -> dict[str, bytes]:
    """topic -> the CDR bytes of the message :func:`pose_messages` builds for it (the same arguments, no backend)."""
    return {topic: raw for topic, (_, raw) in _pose_outputs(_CDR_WRITERS, topics, skeleton, stamp_ns, frame_id,
                                                            local_rot, glob_rot, joint_pos).items()}
