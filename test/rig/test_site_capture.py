"""The HSC4D rig's captures (lip_ros.rig.site_capture and what it builds on): a walk that follows the terrain, a
ballistic sync jump, the suit's drifting odometry, and the bag with its ground truth."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation, Slerp

from lip_msgs_py import cloud_to_array, msg_to_imu, read_header
from lip_ros.bagio import bag_topics, read_messages
from lip_ros.core.frames import GRAVITY
from lip_ros.core.rotations import rot_z
from lip_ros.core.skeleton import forward_kinematics
from lip_ros.rig.bag import TRUTH_FILE
from lip_ros.rig.motion import make_site_motion
from lip_ros.rig.motion.posture import sole_points
from lip_ros.rig.motion.primitives import RoutePath
from lip_ros.rig.site_bag import HIP_LIDAR_TOPIC, SITE_TRUTH_FILE, SUIT_ODOMETRY_TOPIC
from lip_ros.rig.site_capture import SiteCapture, SiteCaptureConfig
from lip_ros.rig.suit_odometry import SuitOdometryConfig, simulate_suit_odometry
from lip_ros.rig.terrain import ROUTE_RADIUS_M, Terrain
from lip_ros.tools.rig import main as lip_rig

SEEDS = (0, 3, 11)


@pytest.fixture(scope="module", params=SEEDS)
def site_walk(request):
    terrain = Terrain.random(request.param)
    return terrain, make_site_motion(terrain, 80.0, request.param)


def test_the_route_keeps_clear_of_obstacles_and_stays_on_the_site():
    """Over 20 sites: the route passes every wall, pillar and crate at 1.5 m or more (footprints, rotated boxes),
    stays on the site, and is straight over the whole stair flight and ramp, along its middle (within 2 cm: the
    smoothed turns and the closure spread along the loop move the straights by up to 1.3 cm)."""
    for seed in range(20):
        terrain = Terrain.random(seed)
        route = RoutePath(*terrain.route(), ROUTE_RADIUS_M)
        xy, _, kappa = route.at(np.arange(0.0, route.length, 0.05))
        b = terrain.blocks
        for i in np.flatnonzero(~b.walkable):
            local = (xy - b.centre[i, :2]) @ b.rotation[i][:2, :2]
            outside = np.maximum(np.abs(local) - b.half[i, :2], 0.0)
            assert np.linalg.norm(outside, axis=1).min() > 1.5, (seed, i)
        assert np.isfinite(terrain.surface_height(xy)).all()
        lay = terrain.layout
        for band, run in ((lay["stair_y_m"], (lay["risers"] - 1) * lay["tread_m"]), (lay["ramp_y_m"],
                                                                                     lay["ramp_run_m"])):
            on = (xy[:, 1] > band[0]) & (xy[:, 1] < band[1]) & (xy[:, 0] > lay["terrace_x_m"] - run) & (
                xy[:, 0] < lay["terrace_x_m"])
            assert on.any() and np.abs(kappa[on]).max() < 1e-3
            np.testing.assert_allclose(xy[on, 1], np.mean(band), atol=0.02)  # smoothed turns: 1.3 cm at most


def test_the_walk_follows_the_terrain(site_walk):
    """80 s captures: the A-pose, the jump, then 60+ m of walking up the stairs, across the terrace and down the
    ramp; while walking the lower foot's lowest sole point is on the surface (measured: within 1 mm for 99 % of
    frames, p95 7 mm), no sole point sinks more than 7 cm into it (a toe tip brushing a step edge), and the
    pelvis is a standing height above the ground under it on the terrace."""
    terrain, motion = site_walk
    assert [p.name for p in motion.phases] == ["a_pose", "to_jump", "jump", "to_walk", "walk"]
    walk = motion.phase("walk")
    t = np.arange(walk.t_start, walk.t_end, 0.02)
    pose = motion.sample(t)
    glob, joints = forward_kinematics(motion.skeleton, pose.local_rot, pose.root_pos)
    soles = sole_points(motion.skeleton, glob, joints)
    above = soles[..., 2] - terrain.surface_height(soles[..., :2].reshape(-1, 2)).reshape(soles.shape[:-1])
    lower = above.min(axis=1)
    assert np.percentile(lower, 1) > -0.005 and np.percentile(lower, 95) < 0.015
    assert above.min() > -0.07
    path = np.sum(np.linalg.norm(np.diff(pose.root_pos[:, :2], axis=0), axis=1))
    assert path > 60.0
    height = terrain.layout["terrace_height_m"]
    on_terrace = terrain.surface_height(pose.root_pos[:, :2]) > height - 1e-6
    assert on_terrace.any()
    stand = pose.root_pos[on_terrace, 2] - height
    assert 0.7 * motion.skeleton.scale < np.median(stand) < 1.0 * motion.skeleton.scale


def test_the_sync_jump_flies_ballistically():
    """The pelvis in the air falls exactly as gravity says (for 0.3-0.5 s), standing still before and after."""
    terrain = Terrain.random(5)
    for seed in (1, 2, 3):
        motion = make_site_motion(terrain, 20.0, seed)
        jump = motion.phase("jump")
        t = np.arange(jump.t_start, jump.t_end, 0.001)
        z = motion.sample(t).root_pos[:, 2]
        acc = np.gradient(np.gradient(z, t), t)
        free = np.abs(acc + GRAVITY) < 0.05  # measured: within 0.02 m/s^2 (the legs' reach planning lowers it
        assert 0.3 < free.sum() * 1e-3 < 0.5  # by 0.2 mm at most in the air)
        runs = np.flatnonzero(np.diff(free.astype(int)))
        assert len(runs) == 2  # one flight
        pose = motion.sample(np.array([0.5, 2.0]))
        np.testing.assert_allclose(pose.root_pos[0], pose.root_pos[1], atol=1e-9)  # the A-pose stands still


def test_the_suit_odometry_drifts_as_drawn_and_knows_no_stairs(site_walk):
    """Without errors the dead reckoning from the planted feet reproduces the pelvis path (within 3 cm over the
    walk); with the drawn stride scale and heading drift it ends metres off in proportion, and its height stays
    the pelvis's above the feet (under 1.5 m) while the truth climbs the terrace."""
    terrain, motion = site_walk
    t = np.arange(0.0, motion.duration, 0.01)
    truth = motion.sample(t).root_pos
    exact = simulate_suit_odometry(motion, 0.0, motion.duration, 0.0, 0.0, np.random.default_rng(0),
                                   SuitOdometryConfig(0.0, 0.0, 0.0))
    n = len(exact.stamp_ns)
    err = np.linalg.norm(exact.position[:, :2] - (truth[:n, :2] - truth[0, :2]), axis=1)
    assert err.max() < 0.03
    psi = 0.8
    odo = simulate_suit_odometry(motion, 0.0, motion.duration, psi, 0.4, np.random.default_rng(1))
    assert odo.stamp_ns[0] == 400_000_000  # on the suit's clock
    in_world = odo.position[:, :2] @ rot_z(psi)[:2, :2].T  # mocap_world is the suit's inertial frame
    # the drift as the errors make it: the truth's steps scaled and turned by the heading error
    step = np.diff(truth[:n, :2], axis=0)
    turned = np.einsum("tab,tb->ta", rot_z(odo.heading_error[1:])[:, :2, :2], odo.scale * step)
    expected = truth[0, :2] + np.concatenate([[np.zeros(2)], np.cumsum(turned, axis=0)])
    np.testing.assert_allclose(in_world + truth[0, :2], expected, atol=0.1)
    assert odo.position[:, 2].max() < 1.5 and truth[:, 2].max() > 2.3  # the jump: 1.3 m; terraces: 1.5 m up


@pytest.fixture(scope="module")
def site_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp("site") / "bag"
    capture = SiteCapture(SiteCaptureConfig(seed=3, seconds=12.0, columns=512))
    assert lip_rig(["site-bag", "--seed", "3", "--seconds", "12", "--columns", "512", "--out", str(out),
                    "--quiet"]) == 0
    return capture, out


def test_the_site_bag_has_the_contracts_topics_on_their_clocks(site_bag):
    """/hip/points at 10 Hz (64 x 512, frame hip_lidar), 17 suit IMUs and the suit's odometry at 100 Hz, stamped
    on the suit's clock (ahead by the drawn offset), the ground truth in the sidecars."""
    capture, out = site_bag
    topics = bag_topics(out)
    assert topics[HIP_LIDAR_TOPIC].count == capture.num_frames == 120
    suit = [t for t in topics if t.startswith("/mocap/") and t.endswith("/imu")]
    assert len(suit) == 17 and topics[SUIT_ODOMETRY_TOPIC].msgtype == "nav_msgs/msg/Odometry"
    offset_ns = capture.suit.clock_offset_s * 1e9
    first: dict[str, int] = {}
    log_before = 0
    for m in read_messages(out, topics=[HIP_LIDAR_TOPIC, "/mocap/pelvis/imu", SUIT_ODOMETRY_TOPIC]):
        assert m.log_ns >= log_before
        log_before = m.log_ns
        stamp, frame_id = read_header(m.msg)
        first.setdefault(m.topic, stamp)
        if m.topic == HIP_LIDAR_TOPIC:
            assert frame_id == "hip_lidar" and cloud_to_array(m.msg, ["x"]).shape == (64, 512)
            assert m.log_ns > stamp + capture.lidar.period_ns  # received when its sweep is over
        elif m.topic == "/mocap/pelvis/imu":
            assert abs(m.log_ns - (stamp - offset_ns)) < 10e6  # received on the LiDAR's clock
            msg_to_imu(m.msg)
    assert abs(first["/mocap/pelvis/imu"] - capture.epoch_ns - offset_ns) < 20e6
    assert first[HIP_LIDAR_TOPIC] == capture.epoch_ns
    with open(out / TRUTH_FILE, encoding="utf-8") as f:
        truth = yaml.safe_load(f)
    assert truth["suit"]["clock_offset_s"] == pytest.approx(capture.suit.clock_offset_s)
    np.testing.assert_allclose(truth["lidar"]["R_M_L"], capture.mount.R_M_L)


def test_the_hip_clouds_put_in_the_world_with_the_true_sensor_poses_lie_on_the_site(site_bag):
    """Each point of a cloud, taken to the world with the sidecar's sensor pose at its own time (per-point t),
    lies on the site: its distance to the surface under it is small for the ground returns (median under 2 cm;
    100 Hz poses interpolated), while without deskewing (the pose at the sweep's start) it is several times
    larger when the performer walks."""
    capture, out = site_bag
    with np.load(out / SITE_TRUTH_FILE) as z:
        stamps, position, quat = z["stamp_ns"], z["lidar_position"], z["lidar_quat"]
    slerp = Slerp(stamps * 1e-9, Rotation.from_quat(quat))
    errors, first_pose = [], []
    walk_start = capture.epoch_ns + capture.motion.phase("walk").t_start * 1e9
    for m in read_messages(out, topics=[HIP_LIDAR_TOPIC]):
        stamp, _ = read_header(m.msg)
        if stamp < walk_start:
            continue
        pts = cloud_to_array(m.msg, ["x", "y", "z", "t"]).ravel()
        pts = pts[np.isfinite(pts["x"])]
        xyz = np.stack([pts["x"], pts["y"], pts["z"]], 1).astype(np.float64)
        t = np.clip((stamp + pts["t"].astype(np.int64)) * 1e-9, stamps[0] * 1e-9, stamps[-1] * 1e-9)
        p = np.stack([np.interp(t, stamps * 1e-9, position[:, k]) for k in range(3)], 1)
        world = slerp(t).apply(xyz) + p
        start = slerp(np.full(1, stamp * 1e-9))[0].apply(xyz) + p[np.argmin(t)]
        for out_list, w in ((errors, world), (first_pose, start)):
            ground = capture.terrain.surface_height(w[:, :2])
            low = np.abs(w[:, 2] - ground) < 0.3  # the ground returns (not walls or the body)
            out_list.append(np.median(np.abs(w[low, 2] - ground[low])))
    assert np.median(errors) < 0.02
    assert np.median(first_pose) > 2.0 * np.median(errors)


@pytest.mark.parametrize("change", [{"mount_tilt_up_deg": 15.0}, {"mount_spin_deg": 90.0},
                                    {"mount_lever_m": (0.15, 0.0, -0.1)}])
def test_a_mount_variant_moves_what_it_names_of_the_true_mounting_only(change):
    """Each mount variant moves what it names of the true mounting (each seed's perturbation stays the same) and
    nothing else of the capture: ``mount_tilt_up_deg`` the tilt (still within 5 deg of it), ``mount_spin_deg``
    the sensor about its own axis (the axis stays, +x turns by the spin), ``mount_lever_m`` the lever arm (on the
    other hip: the side mirrored); the motion stays. Values off the rig's range are refused."""
    nominal = SiteCapture(SiteCaptureConfig(seed=3, seconds=14.0))
    variant = SiteCapture(SiteCaptureConfig(seed=3, seconds=14.0, **change))
    a, b = nominal.mount, variant.mount
    t = np.linspace(1.0, 10.0, 5)
    np.testing.assert_array_equal(variant.truth(t).pelvis, nominal.truth(t).pelvis)
    if "mount_tilt_up_deg" in change:
        assert abs(b.tilt_up_deg - a.tilt_up_deg + 15.0) < 1e-9 and abs(b.tilt_up_deg - 15.0) <= 5.0
    elif "mount_spin_deg" in change:
        np.testing.assert_allclose(b.R_M_L[:, 2], a.R_M_L[:, 2], atol=1e-12)  # the spin axis in the pelvis frame
        np.testing.assert_allclose(b.R_M_L[:, 0], a.R_M_L[:, 1], atol=1e-12)  # +x turned 90 deg: where +y was
    else:
        np.testing.assert_array_equal(b.R_M_L, a.R_M_L)
    if "mount_lever_m" in change:
        np.testing.assert_allclose(b.lever_m - a.lever_m, [0.3, 0.0, 0.0], atol=1e-12)
    else:
        np.testing.assert_array_equal(b.lever_m, a.lever_m)
    for wrong in ({"mount_tilt_up_deg": 75.0}, {"mount_spin_deg": 270.0}, {"mount_lever_m": (0.1, float("nan"), 0.0)}):
        with pytest.raises(ValueError):
            SiteCaptureConfig(**wrong)


def test_a_suit_rate_variant_samples_the_imus_and_the_odometry_at_that_rate():
    """``suit_rate_hz``: every segment and the suit's odometry at the variant's rate, the suit's clock offset as in
    the contract's 100 Hz capture; a rate off the rig's range is refused."""
    nominal = SiteCapture(SiteCaptureConfig(seed=3, seconds=14.0))
    variant = SiteCapture(SiteCaptureConfig(seed=3, seconds=14.0, suit_rate_hz=240.0))
    for capture, rate in ((nominal, 100.0), (variant, 240.0)):
        periods = [np.median(np.diff(s.stamp_ns)) for s in capture.suit_streams().values()]
        periods.append(np.median(np.diff(capture.suit_odometry().stamp_ns)))
        np.testing.assert_allclose(periods, 1e9 / rate, rtol=1e-3)
    assert variant.suit.clock_offset_s == nominal.suit.clock_offset_s
    with pytest.raises(ValueError):
        SiteCaptureConfig(suit_rate_hz=5.0)
