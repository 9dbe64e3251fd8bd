"""geometry_msgs Vector3 / Point / Quaternion / Pose <-> numpy (shared by the other converters)."""

from __future__ import annotations

from typing import Any

import numpy as np

from lip_msgs_py.backend import Backend

__all__ = ["vector3_msg", "point_msg", "quaternion_msg", "pose_msg", "xyz_of", "quat_of"]


def _xyz_fields(v: np.ndarray) -> dict[str, float]:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def vector3_msg(backend: Backend, v: np.ndarray) -> Any:
    """``geometry_msgs/msg/Vector3`` of a (3,) array (validated by the caller)."""
    return backend.msg("geometry_msgs/msg/Vector3", **_xyz_fields(v))


def point_msg(backend: Backend, p: np.ndarray) -> Any:
    """``geometry_msgs/msg/Point`` of a (3,) array (validated by the caller)."""
    return backend.msg("geometry_msgs/msg/Point", **_xyz_fields(p))


def quaternion_msg(backend: Backend, q: np.ndarray) -> Any:
    """``geometry_msgs/msg/Quaternion`` of a (4,) xyzw array (validated by the caller)."""
    return backend.msg("geometry_msgs/msg/Quaternion", w=float(q[3]), **_xyz_fields(q))


def pose_msg(backend: Backend, p: np.ndarray, q: np.ndarray) -> Any:
    """``geometry_msgs/msg/Pose`` of a position (3,) and an xyzw quaternion (4,)."""
    return backend.msg("geometry_msgs/msg/Pose", position=point_msg(backend, p), orientation=quaternion_msg(backend, q))


def xyz_of(msg: Any) -> list[float]:
    """``[x, y, z]`` of a Vector3 or Point message."""
    return [msg.x, msg.y, msg.z]


def quat_of(msg: Any) -> list[float]:
    """``[x, y, z, w]`` of a Quaternion message."""
    return [msg.x, msg.y, msg.z, msg.w]
