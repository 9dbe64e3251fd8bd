"""The ground message between the LIP nodes: the level frame of a fitted plane, and back."""

from __future__ import annotations

import numpy as np

from lip_msgs_py import RclpyBackend, msg_to_pose_stamped
from lip_ros.core.frames import level_rotation
from lip_ros.core.ground_plane import GroundPlane
from lip_ros.core.rotations import quat_to_matrix, rot_x, rot_y
from lip_ros.nodes.lip.ground import describe_level, ground_message


def test_ground_message_carries_the_level_frame_and_the_point_below_the_lidar():
    R_S_L = rot_y(np.radians(8.0)) @ rot_x(np.radians(-3.0))  # a tripod pitched down and rolled
    up = R_S_L.T @ [0.0, 0.0, 1.0]
    plane = GroundPlane.from_coefficients((*up, 2.5))  # 2.5 m below the LiDAR
    pose = msg_to_pose_stamped(ground_message(RclpyBackend(), 123, "os_lidar", plane))
    assert (pose.stamp_ns, pose.frame_id) == (123, "os_lidar")
    level = quat_to_matrix(pose.quat)
    np.testing.assert_allclose(level, level_rotation(up), atol=1e-9)
    np.testing.assert_allclose(level[:, 2], up, atol=1e-9)  # P's z is gravity-up
    np.testing.assert_allclose(pose.position, -2.5 * up, atol=1e-9)  # straight below, on the plane
    assert abs(plane.height(pose.position[None])[0]) < 1e-9
    assert describe_level(level) == "the LiDAR is tilted 8.5 deg from level"
    assert describe_level(np.eye(3)) == "the LiDAR is tilted 0.0 deg from level"
