"""tf2_msgs/TFMessage of stamped transforms (for /tf), for any backend that knows tf2_msgs."""

from __future__ import annotations

from typing import Any

from lip_msgs_py._validate import finite_array, unit_quaternions
from lip_msgs_py.backend import Backend
from lip_msgs_py.geometry import quaternion_msg, vector3_msg

__all__ = ["transform_stamped_to_msg", "tf_message"]


def transform_stamped_to_msg(backend: Backend, stamp_ns: int, parent: str, child: str, translation: Any,
                             quat: Any) -> Any:
    """``geometry_msgs/msg/TransformStamped``: ``child`` in ``parent`` (position (3,), xyzw quaternion (4,))."""
    t = finite_array(translation, (3,), "TransformStamped translation")
    q = unit_quaternions(quat, (), "TransformStamped rotation")
    transform = backend.msg("geometry_msgs/msg/Transform", translation=vector3_msg(backend, t),
                            rotation=quaternion_msg(backend, q))
    return backend.msg("geometry_msgs/msg/TransformStamped", header=backend.header(stamp_ns, parent),
                       child_frame_id=child, transform=transform)


def tf_message(backend: Backend, transforms: list[Any]) -> Any:
    """``tf2_msgs/msg/TFMessage`` of TransformStamped messages."""
    return backend.msg("tf2_msgs/msg/TFMessage", transforms=transforms)
