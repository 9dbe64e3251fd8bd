"""The ground under the LiDAR, from ``segmentation_node`` (which fits it) to the nodes that work level.

``calibration_node`` and ``pose_node`` work in the LiDAR's level frame P (see
:mod:`lip_ros.lip.stages`), so that a tilted LiDAR is no different from a
level one. ``segmentation_node`` publishes P once it has fitted the ground, on
``ground_topic`` (default ``/lip/ground``) as a geometry_msgs/PoseStamped,
reliable and transient local (a late subscriber gets it): in the cloud's frame,
orientation R_L_P (z along the ground's normal, up; L's heading) and position
the point on the ground straight below the LiDAR (its height is minus that z).
Until it arrives the other nodes take L as level.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped

from lip_msgs_py import MalformedMessageError, msg_to_pose_stamped, pose_stamped_to_msg
from lip_ros.core.frames import level_rotation
from lip_ros.core.ground_plane import GroundPlane
from lip_ros.core.rotations import geodesic_angle, matrix_to_quat, quat_to_matrix
from lip_ros.nodes.base import LATCHED, GraphNode, Param

__all__ = ["GROUND_PARAM", "ground_message", "describe_level", "subscribe_ground"]

#: The parameter of the ground topic, in each node that publishes or reads it.
GROUND_PARAM = Param("the ground under the LiDAR: its level frame in the cloud's frame (PoseStamped, latched)")


def ground_message(backend: Any, stamp_ns: int, frame_id: str, plane: GroundPlane) -> Any:
    """The PoseStamped of the level frame of ``plane`` (see the module docstring)."""
    return pose_stamped_to_msg(backend, stamp_ns, frame_id, -plane.offset * plane.normal,
                               matrix_to_quat(level_rotation(plane.normal)))


def describe_level(level: np.ndarray) -> str:
    """How far the LiDAR frame is tilted from its level frame R_L_P, in words."""
    return f"the LiDAR is tilted {np.degrees(geodesic_angle(level, np.eye(3))):.1f} deg from level"


def subscribe_ground(node: GraphNode, topic: str, use: Callable[[np.ndarray], None]) -> None:
    """Call ``use(R_L_P)`` with each ground message on ``topic`` (a malformed one is logged and skipped)."""

    def on_ground(msg: PoseStamped) -> None:
        try:
            level = quat_to_matrix(msg_to_pose_stamped(msg).quat)
        except MalformedMessageError as exc:
            node.get_logger().warning(f"ground message skipped: {exc}")
            return
        use(level)
        node.get_logger().info(f"ground received on {topic}: {describe_level(level)}")

    node.create_subscription(PoseStamped, topic, on_ground, LATCHED, callback_group=node.group)
