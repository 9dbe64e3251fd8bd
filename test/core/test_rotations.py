"""The turns of the axes onto the axes (lip_ros.core.rotations.nearest_axes_turn): another axis convention."""

from __future__ import annotations

import numpy as np

from lip_ros.core.frames import R_L_M_FACING_X
from lip_ros.core.rotations import axis_angle_to_matrix, geodesic_angle, nearest_axes_turn


def test_the_nearest_turn_of_the_axes_is_found_within_a_few_degrees_of_noise():
    """Each of the 24 rotations that take the axes onto the axes, turned by up to 20 deg, gives itself back; the
    24 are distinct proper rotations."""
    rng = np.random.default_rng(0)
    turns = set()
    for _ in range(200):
        axes = nearest_axes_turn(axis_angle_to_matrix(rng.normal(size=3) * 3.0))  # any of them
        turns.add(axes.tobytes())
        assert np.linalg.det(axes) == 1.0 and set(np.abs(axes).sum(axis=0)) == {1.0}
        noise = rng.normal(size=3)
        noisy = axes @ axis_angle_to_matrix(noise / np.linalg.norm(noise) * np.radians(rng.uniform(0.0, 20.0)))
        np.testing.assert_array_equal(nearest_axes_turn(noisy), axes)
    assert len(turns) == 24
    np.testing.assert_array_equal(nearest_axes_turn(R_L_M_FACING_X), R_L_M_FACING_X)  # base_link's axes in M's
    assert geodesic_angle(nearest_axes_turn(np.eye(3)), np.eye(3)) == 0.0
