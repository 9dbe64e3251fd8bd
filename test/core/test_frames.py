"""The level frame of a tilted sensor."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.core.frames import level_rotation
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
