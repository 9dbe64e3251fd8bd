"""The offline refinement's map rebuilt from the refined trajectory (lip_ros.hsc4d.refinement)."""

from __future__ import annotations

import numpy as np

from lip_ros.core.rotations import rot_x, rot_y, rot_z
from lip_ros.hsc4d.refinement import sweep_shifts


def _poses(rng: np.random.Generator, n: int) -> np.ndarray:
    T = np.tile(np.eye(4), (n, 1, 1))
    for k in range(n):
        a, b, c = rng.uniform(-0.3, 0.3, 3)
        T[k, :3, :3] = rot_z(3 * a) @ rot_y(b) @ rot_x(c)
        T[k, :3, 3] = rng.uniform(-20.0, 20.0, 3)
    return T


def test_each_sweep_moves_to_where_the_refined_pelvis_puts_its_sensor_through_the_mounting():
    """Sweeps placed by their odometry poses T_map_L. A refined pelvis that is the odometry's own through the
    mounting the graph used leaves every sweep where it is, however the live fused pelvis differed from it (before
    session 35 each sweep moved by the refined pelvis less the live fused one); one moved by d moves its sweep by d,
    whatever the refined pelvis's attitude (the sweep keeps the attitude ICP gave it), and the moved sensor stands
    where the refined pelvis puts it through the mounting turned as the sweep was registered."""
    rng = np.random.default_rng(0)
    lidar = _poses(rng, 50)
    T_L_M = np.eye(4)
    T_L_M[:3, :3] = rot_x(np.radians(-30.0)) @ rot_y(np.radians(90.0))
    T_L_M[:3, 3] = [0.12, -0.17, 0.05]
    own = lidar @ T_L_M
    np.testing.assert_allclose(sweep_shifts(lidar, own, T_L_M), 0.0, atol=1e-12)
    d = rng.normal(0.0, 0.05, (50, 3))
    refined = own.copy()
    refined[:, :3, 3] += d
    refined[:, :3, :3] = refined[:, :3, :3] @ rot_y(np.radians(4.0))  # the graph turned the pelvis a little
    shifts = sweep_shifts(lidar, refined, T_L_M)
    np.testing.assert_allclose(shifts, d, atol=1e-12)
    as_registered = own.copy()  # the refined pelvis's position with the attitude the sweep was registered with
    as_registered[:, :3, 3] = refined[:, :3, 3]
    np.testing.assert_allclose(lidar[:, :3, 3] + shifts, (as_registered @ np.linalg.inv(T_L_M))[:, :3, 3],
                               atol=1e-12)
