"""The level frame of a tilted sensor; the hip LiDAR's mounting rotation."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.core.frames import R_L_M_FACING_X, hip_lidar_rotation, level_rotation
from lip_ros.core.rotations import geodesic_angle


@pytest.mark.parametrize("up", [(0.0, 0.0, 1.0), (0.1, -0.05, 1.0), (0.0, 0.3, 0.95), (-0.17, 0.0, 0.98)])
def test_level_frame_is_the_smallest_rotation_to_up(up):
    up = np.asarray(up) / np.linalg.norm(up)
    r = level_rotation(up)
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(r[:, 2], up, atol=1e-12)  # its z is up
    assert geodesic_angle(r, np.eye(3)) == pytest.approx(np.arccos(up[2]), abs=1e-12)  # no turn beyond the tilt


def test_level_frame_of_a_level_sensor_is_the_identity_and_down_has_none():
    np.testing.assert_array_equal(level_rotation(np.array([0.0, 0.0, 2.0])), np.eye(3))
    with pytest.raises(ValueError, match="points down"):
        level_rotation(np.array([0.0, 0.0, -1.0]))


@pytest.mark.parametrize("spin_deg", [90.0, 180.0, -45.0])
def test_a_hip_lidar_spun_about_its_axis_keeps_its_axis_and_turns_its_x(spin_deg):
    """The spin turns the sensor about its own z (where an Ouster's connector and column 0 point); its axis in the
    pelvis frame stays the tilted one, and no spin is the rotation as before, to the bit."""
    R, spun = hip_lidar_rotation(30.0), hip_lidar_rotation(30.0, spin_deg)
    np.testing.assert_allclose(spun.T @ spun, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(spun[:, 2], R[:, 2], atol=1e-12)
    a = np.radians(spin_deg)
    np.testing.assert_allclose(spun[:, 0], np.cos(a) * R[:, 0] + np.sin(a) * R[:, 1], atol=1e-12)
    t = np.radians(30.0)
    np.testing.assert_array_equal(hip_lidar_rotation(30.0, 0.0), R_L_M_FACING_X.T @ np.array(
        [[np.cos(t), 0.0, -np.sin(t)], [0.0, 1.0, 0.0], [np.sin(t), 0.0, np.cos(t)]]))
