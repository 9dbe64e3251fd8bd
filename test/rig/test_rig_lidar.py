"""The Ouster simulator and the static scene: layout, timing, geometry, occlusion, sensor model."""

from __future__ import annotations

import numpy as np
import pytest

from lip_msgs_py.ouster import OUSTER_ORIGINAL_DTYPE
from lip_ros.core.body import BodyModel
from lip_ros.core.skeleton import forward_kinematics, load_skeleton
from lip_ros.rig.lidar import Actor, OusterModel
from lip_ros.rig.scene import CLEARANCE, Boxes, KeepOut, Scene
from lip_ros.rig.trajectory import BodyPose

H_LIDAR = 1.1  # LiDAR height above the ground
R_L_M = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # facing the LiDAR
SKELETON = load_skeleton()
BODY = BodyModel(SKELETON)
GROUND = Scene(ground_z=-H_LIDAR)


def standing(x: float, y: float, pose: str = "a_pose") -> tuple[np.ndarray, np.ndarray]:
    """A performer standing on the ground at (x, y), facing the LiDAR."""
    local = SKELETON.pose_local_rotations(pose)
    local[0] = R_L_M
    return forward_kinematics(SKELETON, local, np.array([x, y, SKELETON.pelvis_height - H_LIDAR]))


def still(x: float, y: float) -> Actor:
    pose = standing(x, y)
    return Actor(BODY, lambda t: pose)


def xyz(frame, mask: np.ndarray) -> np.ndarray:
    return np.stack([frame.points[c][mask] for c in "xyz"], axis=1).astype(np.float64)


def test_organized_layout_and_timing():
    lidar = OusterModel.os1_128()
    frame = lidar.scan(123_000_000, lidar.static_image(GROUND), [], np.random.default_rng(0))
    pts, (h, w) = frame.points, lidar.shape
    assert pts.shape == (128, 1024) and pts.dtype == OUSTER_ORIGINAL_DTYPE and frame.labels.shape == (128, 1024)
    assert frame.labels.dtype == np.int16 and frame.stamp_ns == 123_000_000
    assert np.all(pts["ring"] == np.arange(h)[:, None])
    assert np.all(pts["t"] == pts["t"][0]) and np.all(np.diff(pts["t"][0].astype(np.int64)) > 0)
    assert pts["t"][0, 0] == 0 and pts["t"][0, w // 2] == 50_000_000 and pts["t"][0, -1] < 100_000_000
    ground = pts["range"] > 0
    for col, direction in ((w // 2, [1, 0]), (0, [-1, 0]), (w // 4, [0, 1]), (3 * w // 4, [0, -1])):
        m = ground[:, col]
        assert m.sum() > 20
        planar = np.stack([pts["x"][m, col], pts["y"][m, col]], axis=1)
        unit = planar / np.linalg.norm(planar, axis=1, keepdims=True)
        np.testing.assert_allclose(unit, np.tile(direction, (m.sum(), 1)), atol=1e-6)
    assert np.all(np.diff(lidar.elevation) < 0) and lidar.elevation[0] == pytest.approx(np.deg2rad(22.5))
    # xyz is the quantised range along the beam
    p = xyz(frame, ground)
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), pts["range"][ground] / 1000.0, rtol=1e-6)
    np.testing.assert_allclose(p / np.linalg.norm(p, axis=1, keepdims=True), lidar.directions[ground], atol=1e-6)


def test_os1_64_preset():
    lidar = OusterModel.os1_64()
    assert lidar.shape == (64, 1024) and lidar.period_ns == 50_000_000
    frame = lidar.scan(0, None, [still(5.0, 0.0)], np.random.default_rng(0))
    assert frame.points.shape == (64, 1024) and (frame.labels == 0).sum() > 100


@pytest.mark.parametrize("dist", [4.0, 10.0])
def test_body_in_front_is_hit_at_distance_minus_radius(dist):
    lidar = OusterModel.os1_128(range_noise_std=0.0, range_noise_per_m=0.0, dropout_prob=0.0)
    glob, pos = standing(0.0, 0.0)
    a, b, r = BODY.capsules(glob, pos)
    k = BODY.names.index("head")
    pos = pos + np.array([dist, 0.0, 0.0]) - 0.5 * (a[k] + b[k])  # head axis centred on +x
    frame = lidar.scan(0, None, [Actor(BODY, lambda t: (glob, pos))], np.random.default_rng(0))
    col = lidar.columns // 2
    for row in (63, 64):  # the two beams nearest to horizontal
        assert frame.labels[row, col] == 0
        assert frame.points["range"][row, col] / 1000.0 == pytest.approx(dist - r[k], abs=1e-3)
        assert frame.points["x"][row, col] == pytest.approx(dist - r[k], abs=1e-3)


@pytest.mark.parametrize("dist", [4.0, 10.0, 20.0])
def test_labelled_points_lie_on_the_body(dist):
    lidar = OusterModel.os1_128()
    frame = lidar.scan(0, lidar.static_image(GROUND), [still(dist, 0.5)], np.random.default_rng(1))
    mask = frame.labels == 0
    assert mask.sum() > {4.0: 600, 10.0: 100, 20.0: 25}[dist]
    p = xyz(frame, mask)
    sd = BODY.surface_distance(p, *frame.actor_poses[0])
    sigma = lidar.range_sigma(np.linalg.norm(p, axis=1))
    assert np.all(np.abs(sd) < 5.0 * sigma + 1e-3)
    assert np.all(np.isfinite(p)) and np.all(frame.points["range"][mask] > 0)


def test_moving_actor_is_scanned_when_the_sweep_passes_it():
    lidar = OusterModel.os1_128()
    start, stamp = 5_000_000_000, 7_000_000_000
    glob0, pos0 = standing(6.0, 6.0)

    def walk(t: float) -> tuple[np.ndarray, np.ndarray]:  # 12 m/s across the line of sight, at azimuth 45 deg
        return glob0, pos0 + 12.0 * (t - 2.05) * np.array([-np.sqrt(0.5), np.sqrt(0.5), 0.0])

    frame = lidar.scan(stamp, None, [Actor(BODY, walk)], np.random.default_rng(2), start_ns=start)
    t_ns = int(frame.actor_stamps_ns[0])
    glob, pos = frame.actor_poses[0]
    np.testing.assert_allclose(pos, walk((t_ns - start) * 1e-9)[1])
    assert abs(lidar.column_t_ns[lidar.column_of(pos[0])] - (t_ns - stamp)) <= 100_000  # within a column
    assert 36_000_000 < t_ns - stamp < 39_000_000  # root near azimuth 45 deg: 3/8 of a sweep
    mask = frame.labels == 0
    assert abs(frame.points["t"][mask].mean() - (t_ns - stamp)) < 1_000_000
    p = xyz(frame, mask)
    sigma = lidar.range_sigma(np.linalg.norm(p, axis=1))
    assert np.all(np.abs(BODY.surface_distance(p, glob, pos)) < 5.0 * sigma + 1e-3)
    # the pose at the frame stamp is 45 cm away: most points would be off that body
    early = BODY.surface_distance(p, *walk((stamp - start) * 1e-9))
    assert np.mean(np.abs(early) > 5.0 * sigma + 1e-3) > 0.5


@pytest.mark.parametrize("y, fraction", [(6.0, 0.25), (-6.0, 0.75), (0.0, 0.5)])
def test_actor_time_follows_its_azimuth(y, fraction):
    lidar = OusterModel.os1_128(columns=2048)
    x = 0.0 if y else 6.0
    frame = lidar.scan(0, None, [still(x, y)], np.random.default_rng(0))
    assert frame.actor_stamps_ns[0] == pytest.approx(fraction * 100_000_000, abs=1e5)


@pytest.mark.parametrize(
    "x, y, up", [(4.0, 0.0, 0.0), (-3.0, 0.1, 0.0), (1.5, 0.0, 0.0), (0.6, 0.2, 0.0), (0.0, -2.5, 0.0), (1.8, 0.5, 1.6)]
)
def test_angular_culling_misses_no_beam(x, y, up):
    """Casting only inside the bounding sphere's angular box finds every beam that meets the body."""
    lidar = OusterModel.os1_128(
        columns=512, range_noise_std=0.0, range_noise_per_m=0.0, dropout_prob=0.0, min_range=0.0
    )
    glob, pos = standing(x, y)
    pose = glob, pos + [0.0, 0.0, up]  # up: on a balcony, high in the field of view
    frame = lidar.scan(0, None, [Actor(BODY, lambda t: pose)], np.random.default_rng(0))
    t, cos, refl = BODY.raycast(np.zeros(3), lidar.directions.reshape(-1, 3), *pose)
    seen = np.isfinite(t) & (t <= lidar.max_range * np.sqrt(np.minimum(refl * cos / 0.8, 1.0)))
    assert seen.sum() > 100
    np.testing.assert_array_equal(frame.labels == 0, seen.reshape(lidar.shape))


def test_trajectory_actor():
    glob, pos = standing(5.0, 0.0)
    local = SKELETON.pose_local_rotations("a_pose")
    local[0] = R_L_M

    class Stand:
        skeleton = SKELETON

        def sample(self, t: np.ndarray) -> BodyPose:
            return BodyPose(np.tile(pos[0], (len(t), 1)), np.tile(local, (len(t), 1, 1, 1)))

    g, p = Actor(BODY, Stand()).pose_at(0.3)
    np.testing.assert_allclose(g, glob)
    np.testing.assert_allclose(p, pos)


def test_occlusion_by_a_person_in_front():
    lidar = OusterModel.os1_128(dropout_prob=0.0)
    front, back = still(5.0, 0.0), still(8.0, 0.35)
    alone = lidar.scan(0, None, [back], np.random.default_rng(3))
    both = lidar.scan(0, None, [front, back], np.random.default_rng(3))
    n_alone, n_hidden = (alone.labels == 0).sum(), (both.labels == 1).sum()
    assert 0 < n_hidden < 0.7 * n_alone  # partly hidden
    front_alone = lidar.scan(0, None, [front], np.random.default_rng(3))
    np.testing.assert_array_equal(both.labels == 0, front_alone.labels == 0)  # the front person is untouched
    assert not np.any((both.labels == 1) & (front_alone.labels == 0))


def test_occlusion_by_the_scene():
    box = Boxes(np.array([[4.0, 0.0, -0.1]]), np.array([[0.3, 1.5, 1.0]]), np.zeros(1), np.array([0.5]))
    scene = Scene(ground_z=-H_LIDAR, boxes=box)
    lidar = OusterModel.os1_128()
    frame = lidar.scan(0, lidar.static_image(scene), [still(7.0, 0.0)], np.random.default_rng(4))
    assert (frame.labels == 0).sum() < 80  # only the head shows above the box
    hit_box = (frame.points["range"] > 0) & (np.abs(frame.points["x"] - 3.7) < 0.05)
    assert hit_box.sum() > 500


def test_ground_and_no_returns():
    lidar = OusterModel.os1_128()
    frame = lidar.scan(0, lidar.static_image(GROUND), [], np.random.default_rng(5))
    pts = frame.points
    ret = pts["range"] > 0
    up = lidar.elevation >= 0.0
    assert not ret[up].any()  # only sky above the horizon
    assert ret[~up].mean() > 0.5
    z = pts["z"][ret].astype(np.float64)
    rng_m = pts["range"][ret] / 1000.0
    assert np.all(np.abs(z + H_LIDAR) < 5.0 * lidar.range_sigma(rng_m) + 1e-3)
    for c in "xyz":
        assert np.all(np.isnan(pts[c][~ret])) and np.all(np.isfinite(pts[c][ret]))
    assert np.all(pts["intensity"][~ret] == 0) and np.all(pts["reflectivity"][~ret] == 0)
    assert np.all(frame.labels == -1)
    # grazing ground: no return beyond the range where rho cos(i) is too weak
    elev = np.broadcast_to(lidar.elevation[:, None], lidar.shape)[ret]
    assert np.all(rng_m <= lidar.max_range * np.sqrt(GROUND.ground_reflectivity * np.sin(-elev) / 0.8) + 0.1)
    assert rng_m.max() > 8.0


def test_max_range_and_dropouts():
    near = OusterModel.os1_128(max_range=6.0, dropout_prob=0.0)
    frame = near.scan(0, near.static_image(GROUND), [still(12.0, 0.0)], np.random.default_rng(6))
    assert frame.points["range"].max() <= 6000 and not (frame.labels == 0).any()
    lossy = OusterModel.os1_128(dropout_prob=0.3)
    clean = OusterModel.os1_128(dropout_prob=0.0)
    static = clean.static_image(GROUND)
    n_lossy = (lossy.scan(0, static, [], np.random.default_rng(7)).points["range"] > 0).sum()
    n_clean = (clean.scan(0, static, [], np.random.default_rng(7)).points["range"] > 0).sum()
    assert n_lossy / n_clean == pytest.approx(0.7, abs=0.02)


def test_intensity_and_reflectivity():
    lidar = OusterModel.os1_128()
    near = lidar.scan(0, None, [still(4.0, 0.0)], np.random.default_rng(8))
    far = lidar.scan(0, None, [still(12.0, 0.0)], np.random.default_rng(8))
    i_near, i_far = (f.points["intensity"][f.labels == 0].mean() for f in (near, far))
    assert i_near > 5.0 * i_far > 0.0  # ~1/r^2
    r_near, r_far = (f.points["reflectivity"][f.labels == 0].mean() for f in (near, far))
    assert r_near == pytest.approx(r_far, rel=0.25)  # calibrated for range
    assert 10 < r_near < 100 * BODY.reflectivity.max()
    assert np.all(near.points["ambient"] > 0)


def test_azimuth_window():
    lidar = OusterModel.os1_128(azimuth_window_deg=(90.0, 270.0))
    frame = lidar.scan(0, lidar.static_image(GROUND), [still(5.0, 0.0), still(-5.0, 0.0)], np.random.default_rng(9))
    ret = frame.points["range"] > 0
    valid = np.zeros(lidar.columns, dtype=bool)
    valid[256:768] = True
    assert ret[:, valid].any() and not ret[:, ~valid].any()
    assert np.all(frame.points["ambient"][:, ~valid] == 0)
    assert (frame.labels == 0).sum() > 300 and not (frame.labels == 1).any()


def test_determinism_per_seed():
    scene = Scene.random(11, KeepOut(2.0, 12.0, -4.0, 4.0), -H_LIDAR)
    assert len(scene.boxes) > 0 and len(scene.cylinders) > 0
    again = Scene.random(11, KeepOut(2.0, 12.0, -4.0, 4.0), -H_LIDAR)
    np.testing.assert_array_equal(scene.boxes.centre, again.boxes.centre)
    np.testing.assert_array_equal(scene.cylinders.axis, again.cylinders.axis)
    other = Scene.random(12, KeepOut(2.0, 12.0, -4.0, 4.0), -H_LIDAR)
    assert not np.array_equal(scene.cylinders.axis, other.cylinders.axis)
    lidar = OusterModel.os1_128()
    static = lidar.static_image(scene)
    f1, f2, f3 = (lidar.scan(0, static, [still(6.0, 0.0)], np.random.default_rng(s)) for s in (1, 1, 2))
    assert f1.points.tobytes() == f2.points.tobytes()
    np.testing.assert_array_equal(f1.labels, f2.labels)
    assert f1.points.tobytes() != f3.points.tobytes()


def test_clutter_keeps_out_of_the_capture_area():
    keep = KeepOut(2.0, 14.0, -5.0, 5.0)
    lidar = OusterModel.os1_128(dropout_prob=0.0)
    ground = lidar.static_image(GROUND)
    for seed in range(4):
        room = 22.0 if seed % 2 else None
        scene = Scene.random(seed, keep, -H_LIDAR, n_boxes=15, n_cylinders=25, extent=20.0, room=room)
        box_r = np.hypot(scene.boxes.half[:, 0], scene.boxes.half[:, 1])
        walls = scene.boxes.half[:, :2].max(axis=1) > 20.0
        assert np.all(keep.distance(scene.boxes.centre[~walls, :2]) > box_r[~walls] + CLEARANCE)
        assert np.all(keep.distance(scene.cylinders.axis) > scene.cylinders.radius + CLEARANCE)
        assert walls.sum() == (4 if seed % 2 else 0)
        assert not keep.shadows(np.zeros(2), scene.boxes.centre[~walls, :2], box_r[~walls]).any()
        assert not keep.shadows(np.zeros(2), scene.cylinders.axis, scene.cylinders.radius).any()
        static = lidar.static_image(scene)
        for x, y in ((2.5, -4.5), (8.0, 0.0), (13.5, 4.5)):  # nothing hides a performer anywhere on the stage
            seen = (lidar.scan(0, static, [still(x, y)], np.random.default_rng(0)).labels == 0).sum()
            assert seen == (lidar.scan(0, ground, [still(x, y)], np.random.default_rng(0)).labels == 0).sum()


def test_keep_out_rejects_shadows():
    keep = KeepOut(4.0, 8.0, -1.0, 1.0)
    xy = np.array([[2.0, 0.0], [2.0, 3.0], [10.0, 0.0], [-3.0, 0.0]])
    np.testing.assert_array_equal(keep.shadows(np.zeros(2), xy, np.full(4, 0.3)), [True, False, False, False])
    with pytest.raises(ValueError):
        Scene.random(0, KeepOut(2.0, 30.0, -1.0, 1.0), -1.0, room=10.0)


def test_sensor_pose_in_a_world_frame():
    """A LiDAR at height h over ground z = 0 sees what a LiDAR at the origin sees over ground z = -h."""
    up = np.array([0.0, 0.0, H_LIDAR])
    glob, pos = standing(6.0, 1.0)
    local = OusterModel.os1_128(dropout_prob=0.0)
    world = OusterModel.os1_128(dropout_prob=0.0, position=up)
    f_local = local.scan(0, local.static_image(GROUND), [Actor(BODY, lambda t: (glob, pos))], np.random.default_rng(0))
    f_world = world.scan(
        0, world.static_image(Scene(ground_z=0.0)), [Actor(BODY, lambda t: (glob, pos + up))], np.random.default_rng(0)
    )
    np.testing.assert_array_equal(f_local.labels, f_world.labels)
    diff = f_local.points["range"].astype(np.int64) - f_world.points["range"].astype(np.int64)
    assert np.abs(diff).max() <= 1
