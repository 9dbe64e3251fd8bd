"""The offline refinement's map rebuilt from the refined trajectory (lip_ros.hsc4d.refinement)."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.core.rotations import rot_x, rot_y, rot_z
from lip_ros.hsc4d.refinement import MapViews, sweep_shifts
from lip_ros.hsc4d.site_map import SiteMap, SiteMapConfig


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


def test_each_window_stands_on_the_map_as_it_stood_then_moved_with_its_sweeps():
    """A voxel seen again later from nearer (a second visit) gets the later sweep's point in the site map; the
    view kept at the first visit keeps the first sweep's, so a window of the first visit stands on the ground as
    the sweeps of its own time placed it (the contact term moved the feet by the pose error of the other visit
    where the final map was used: docs/hsc4d/optimisation.md). A view is the first kept at the step or later, only
    near its path, each point moved by its own sweep's shift."""
    site = SiteMap(SiteMapConfig(voxel_m=0.1))
    views = MapViews(radius_m=1.0)
    ground = np.array([[5.0, 0.0, 0.0], [20.0, 0.0, 0.0]])  # in the sensor's frame, which stands at the origin
    site.add(ground, np.eye(4), 0)  # the first visit sees the patch at x = 5 m from 5 m
    views.add(99, site, np.array([[4.5, 0.0], [5.0, 0.0]]))
    later = np.eye(4)
    later[:3, 3] = [4.0, 0.0, 0.01]  # the second visit, 1 m away, placed 1 cm higher
    site.add(ground[:1] - [4.0, 0.0, 0.0], later, 1)
    views.add(199, site, np.array([[5.0, 0.0]]))
    assert site.replaced == 1 and np.allclose(site.points()[site.sweeps() == 1], [5.0, 0.0, 0.01], atol=1e-6)
    shifts = np.array([[0.0, 0.0, 0.002], [0.0, 0.0, -0.01]])
    for step in (0, 99):
        np.testing.assert_allclose(views.at(step, shifts), [[5.0, 0.0, 0.002]], atol=1e-6)  # far point left out
    np.testing.assert_allclose(views.at(100, shifts), [[5.0, 0.0, 0.0]], atol=1e-6)
    assert views.newest == 199 and views.size == 2
    with pytest.raises(LookupError):
        views.at(200, shifts)
    with pytest.raises(ValueError):
        views.add(199, site, np.zeros((1, 2)))
