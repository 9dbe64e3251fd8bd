"""The whole site's map of the offline refinement (lip_ros.hsc4d.site_map)."""

from __future__ import annotations

import numpy as np

from lip_ros.core.rotations import rot_z
from lip_ros.hsc4d.site_map import SiteMap, SiteMapConfig


def _pose(yaw: float, t: tuple[float, float, float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rot_z(yaw), t
    return T


def test_one_point_per_voxel_the_nearest_sighting_keeps_it():
    """Without a range to see from (``sighting_from_m`` 0) each voxel keeps the point of the sweep that saw it from
    the nearest range so far: a sweep's attitude error moves a point by its range times it."""
    site = SiteMap(SiteMapConfig(voxel_m=0.1, max_range_m=50.0, sighting_from_m=0.0))
    rng = np.random.default_rng(0)
    wall = np.stack([np.full(2000, 5.05), rng.uniform(-2, 2, 2000), rng.uniform(0, 2, 2000)], axis=1)
    assert site.add(wall, np.eye(4), 0) > 0
    n = site.size
    assert n <= 40 * 20 + 100 and n == len(site.points()) == len(site.sweeps())  # a 4 x 2 m wall at 0.1 m
    farther = _pose(0.2, (-3.0, -0.5, 0.0))  # the same wall seen again from farther: nothing changes
    assert site.add((wall - farther[:3, 3]) @ farther[:3, :3], farther, 1) == 0 and site.size == n
    assert site.replaced == 0 and set(site.sweeps().tolist()) == {0}
    nearer = _pose(-0.2, (2.0, 0.5, 0.0))  # ... and from nearer: every point now that sweep's, on the same wall
    assert site.add((wall - nearer[:3, 3]) @ nearer[:3, :3], nearer, 2) == 0 and site.size == n
    assert site.replaced == n and set(site.sweeps().tolist()) == {2}
    assert np.allclose(site.points()[:, 0], 5.05, atol=1e-5)
    moved = wall + [3.0, 0.0, 0.0]  # a new wall (voxel centres: clear of their borders)
    assert site.add(moved, np.eye(4), 3) > 0
    assert set(site.sweeps().tolist()) == {2, 3}
    p = site.points()
    assert np.allclose(p[site.sweeps() == 3][:, 0], 8.05, atol=1e-5) and np.allclose(p[site.sweeps() == 2][:, 0], 5.05)
    one = SiteMap(SiteMapConfig(voxel_m=1.0, sighting_from_m=0.0))  # within one sweep, a voxel's nearest point
    assert one.add(np.array([[5.9, 0.5, 0.5], [5.1, 0.5, 0.5], [5.5, 0.5, 0.5]]), np.eye(4), 0) == 1
    assert np.allclose(one.points(), [[5.1, 0.5, 0.5]])


def test_a_voxel_keeps_its_nearest_sighting_from_far_enough():
    """Sightings nearer than ``sighting_from_m`` rank behind every one from that far (nearest first among them):
    they are placed by the pose of about the time the wearer stands there."""
    site = SiteMap(SiteMapConfig(voxel_m=1.0, max_range_m=30.0, sighting_from_m=8.0))
    point = np.array([[10.5, 0.5, 0.5]])

    def seen_from(x: float, sweep: int) -> None:
        T = _pose(0.0, (x, 0.0, 0.0))
        site.add(point - T[:3, 3], T, sweep)

    seen_from(0.0, 0)  # from 10 m
    seen_from(8.0, 1)  # 2.5 m: ranks behind
    seen_from(6.0, 2)  # 4.5 m: also behind
    assert site.sweeps().tolist() == [0] and site.replaced == 0
    seen_from(2.0, 3)  # 8.5 m: the nearest from far enough
    seen_from(-10.0, 4)  # 20.5 m: farther
    assert site.sweeps().tolist() == [3] and site.replaced == 1
    near = SiteMap(SiteMapConfig(voxel_m=1.0, max_range_m=30.0, sighting_from_m=8.0))
    for sweep, x in enumerate((8.0, 10.0, 6.0)):  # only near sightings: the nearest of them
        T = _pose(0.0, (x, 0.0, 0.0))
        near.add(point - T[:3, 3], T, sweep)
    assert near.sweeps().tolist() == [1]
    one = SiteMap(SiteMapConfig(voxel_m=4.0, sighting_from_m=6.0))  # within one sweep too: one voxel, [4, 8) m
    assert one.add(np.array([[7.5, 1.0, 1.0], [4.5, 1.0, 1.0], [6.5, 1.0, 1.0]]), np.eye(4), 0) == 1
    assert np.allclose(one.points(), [[6.5, 1.0, 1.0]])


def test_far_points_are_left_out_and_the_size_is_bounded():
    site = SiteMap(SiteMapConfig(voxel_m=0.5, max_range_m=10.0, max_points=50))
    far = np.array([[20.0, 0.0, 0.0]])
    assert site.add(far, np.eye(4), 0) == 0 and site.size == 0
    grid = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0), [0.0]), -1).reshape(-1, 3) * 0.5 + 0.25
    assert site.add(grid, np.eye(4), 1) == 50 and site.size == 50 and site.refused == 50
    assert site.add(grid + [0.0, 0.0, 1.0], np.eye(4), 2) == 0 and site.refused == 150


def test_shifted_puts_each_point_where_its_own_sweep_went():
    site = SiteMap(SiteMapConfig(voxel_m=0.05))
    a, b = np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 2.0, 0.0]])
    site.add(a, np.eye(4), 0)
    site.add(b, _pose(0.0, (0.0, 0.0, 1.0)), 1)
    shifted = site.shifted(np.array([[0.0, -0.25, 0.0], [0.5, 0.0, 0.0]]))
    assert shifted.dtype == np.float32
    assert np.allclose(shifted, [[1.0, -0.25, 0.0], [0.5, 2.0, 1.0]], atol=1e-6)
    many = SiteMap()  # past the set of recent voxels into the sorted array, still one point per voxel
    rng = np.random.default_rng(1)
    cloud = rng.uniform(-20, 20, (300_000, 3))
    many.add(cloud, np.eye(4), 0)
    before = many.size
    assert many.add(cloud[:1000], np.eye(4), 1) == 0 and many.size == before and many.replaced == 0
    at_first = _pose(0.0, tuple(cloud[0] - [8.5, 0.0, 0.0]))  # a merged voxel seen from nearer: its point replaced
    assert many.add(cloud[:1] - at_first[:3, 3], at_first, 2) == 0 and many.size == before and many.replaced == 1
    assert np.allclose(many.points()[many.sweeps() == 2], cloud[:1], atol=1e-5)


def test_near_keeps_the_points_within_the_radius_of_a_path_with_their_sweeps():
    site = SiteMap(SiteMapConfig(voxel_m=0.05))
    rng = np.random.default_rng(2)
    clouds = [rng.uniform(-10.0, 10.0, (2000, 3)) for _ in range(3)]
    for k, cloud in enumerate(clouds):
        site.add(cloud, np.eye(4), k)
    path = np.array([[0.0, 0.0], [3.0, 1.0], [3.5, 4.0]])
    points, sweeps = site.near(path, 1.2)
    everything, all_sweeps = site.points(), site.sweeps()
    distance = np.min(np.linalg.norm(everything[:, None, :2] - path[None], axis=2), axis=1)
    inside = distance <= 1.2
    assert 0 < inside.sum() < len(everything) and len(points) == inside.sum()
    assert {tuple(p) for p in points} == {tuple(p) for p in everything[inside]}
    order, expected = np.lexsort(points.T), np.lexsort(everything[inside].T)
    np.testing.assert_array_equal(sweeps[order], all_sweeps[inside][expected])
    assert site.near(np.zeros((0, 2)), 1.0)[0].shape == (0, 3) and SiteMap().near(path, 1.0)[1].shape == (0,)
