"""The whole site's map of the offline refinement (lip_ros.hsc4d.site_map)."""

from __future__ import annotations

import numpy as np

from lip_ros.core.rotations import rot_z
from lip_ros.hsc4d.site_map import SiteMap, SiteMapConfig


def _pose(yaw: float, t: tuple[float, float, float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rot_z(yaw), t
    return T


def test_one_point_per_voxel_the_first_sweep_to_see_it_keeps_it():
    site = SiteMap(SiteMapConfig(voxel_m=0.1, max_range_m=50.0))
    rng = np.random.default_rng(0)
    wall = np.stack([np.full(2000, 5.05), rng.uniform(-2, 2, 2000), rng.uniform(0, 2, 2000)], axis=1)
    assert site.add(wall, np.eye(4), 0) > 0
    n = site.size
    assert n <= 40 * 20 + 100 and n == len(site.points()) == len(site.sweeps())  # a 4 x 2 m wall at 0.1 m
    T = _pose(0.2, (1.0, -0.5, 0.0))  # the same wall seen again from elsewhere: nothing new
    assert site.add((wall - T[:3, 3]) @ T[:3, :3], T, 1) == 0 and site.size == n
    moved = wall + [3.0, 0.0, 0.0]  # a new wall (voxel centres: clear of their borders)
    assert site.add(moved, np.eye(4), 2) > 0
    assert set(site.sweeps().tolist()) == {0, 2}
    p = site.points()
    assert np.allclose(p[site.sweeps() == 2][:, 0], 8.05, atol=1e-5) and np.allclose(p[site.sweeps() == 0][:, 0], 5.05)


def test_far_points_are_left_out_and_the_size_is_bounded():
    site = SiteMap(SiteMapConfig(voxel_m=0.5, max_range_m=10.0, max_points=50))
    far = np.array([[20.0, 0.0, 0.0]])
    assert site.add(far, np.eye(4), 0) == 0 and site.size == 0
    grid = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0), [0.0]), -1).reshape(-1, 3) * 0.5 + 0.25
    assert site.add(grid, np.eye(4), 1) == 50 and site.size == 50 and site.refused == 50
    assert site.add(grid + [0.0, 0.0, 1.0], np.eye(4), 2) == 0 and site.refused == 150


def test_moved_puts_each_point_where_its_own_sweep_went():
    site = SiteMap(SiteMapConfig(voxel_m=0.05))
    a, b = np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 2.0, 0.0]])
    site.add(a, np.eye(4), 0)
    site.add(b, _pose(0.0, (0.0, 0.0, 1.0)), 1)
    corrections = np.stack([_pose(np.pi / 2, (0.0, 0.0, 0.0)), _pose(0.0, (0.5, 0.0, 0.0))])
    moved = site.moved(corrections)
    assert np.allclose(moved, [[0.0, 1.0, 0.0], [0.5, 2.0, 1.0]], atol=1e-6)
    many = SiteMap()  # past the set of recent voxels into the sorted array, still one point per voxel
    rng = np.random.default_rng(1)
    cloud = rng.uniform(-20, 20, (300_000, 3))
    many.add(cloud, np.eye(4), 0)
    before = many.size
    assert many.add(cloud[:1000], np.eye(4), 1) == 0 and many.size == before
