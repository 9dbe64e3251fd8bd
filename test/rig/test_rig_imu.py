"""IMU simulator (lip_ros.rig.imu) on analytic motions whose readings are known exactly."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import pytest
import yaml

from lip_ros.core.rotations import axis_angle_to_matrix, geodesic_angle, matrix_to_axis_angle, quat_to_matrix, rot_z
from lip_ros.core.skeleton import NUM_JOINTS, Skeleton, forward_kinematics, load_skeleton
from lip_ros.rig.imu import (
    GRAVITY,
    ImuNoise,
    ImuRigConfig,
    ImuStream,
    ImuTruth,
    make_imu_truth,
    simulate_imus,
)
from lip_ros.rig.trajectory import BodyPose

R_L_M = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # facing the LiDAR
UP = np.array([0.0, 0.0, GRAVITY])
EXACT = ImuNoise.none()


@dataclass
class Analytic:
    """A Trajectory from closed-form root position (T,) -> (T, 3) and local rotations (T,) -> (T, 24, 3, 3)."""

    skeleton: Skeleton
    root_pos: Callable[[np.ndarray], np.ndarray]
    local_rot: Callable[[np.ndarray], np.ndarray]

    def sample(self, t: np.ndarray) -> BodyPose:
        t = np.asarray(t, dtype=np.float64)
        return BodyPose(self.root_pos(t), self.local_rot(t))


def rest_rot(t: np.ndarray) -> np.ndarray:
    rot = np.tile(np.eye(3), (t.size, NUM_JOINTS, 1, 1))
    rot[:, 0] = R_L_M
    return rot


def standing(skel: Skeleton) -> Analytic:
    """T-pose, 3 m in front of the LiDAR, facing it."""
    return Analytic(skel, lambda t: np.tile([3.0, 0.0, 0.0], (t.size, 1)), rest_rot)


def circling(skel: Skeleton, radius: float, rate: float) -> Analytic:
    """T-pose body turning rigidly about L's z axis: pelvis on a circle, heading along with it."""

    def local(t):
        rot = rest_rot(t)
        rot[:, 0] = rot_z(rate * t) @ R_L_M
        return rot

    return Analytic(skel, lambda t: radius * np.stack([np.cos(rate * t), np.sin(rate * t), 0 * t], -1), local)


def arm_turning(skel: Skeleton, axis: np.ndarray, rate: float) -> Analytic:
    """Standing still, the left forearm turning about ``axis`` (unit, elbow's parent frame) at ``rate``."""
    elbow = skel.index("left_elbow")

    def local(t):
        rot = rest_rot(t)
        rot[:, elbow] = axis_angle_to_matrix(np.outer(rate * t, axis))
        return rot

    return Analytic(skel, lambda t: np.tile([3.0, 0.0, 0.0], (t.size, 1)), local)


def true_R_I_S(truth: ImuTruth, stream: ImuStream) -> np.ndarray:
    spec = next(s for s in truth.specs if s.name == stream.name)
    return truth.R_L_I.T @ stream.R_L_B_true @ spec.R_B_S


def sensor_position(skel: Skeleton, traj: Analytic, truth: ImuTruth, stream: ImuStream) -> np.ndarray:
    spec = next(s for s in truth.specs if s.name == stream.name)
    pose = traj.sample(stream.t_true)
    glob, pos = forward_kinematics(skel, pose.local_rot, pose.root_pos)
    j = skel.index(spec.bone_joint)
    return pos[:, j] + glob[:, j] @ spec.offset_in_bone


@pytest.fixture(scope="module")
def skel() -> Skeleton:
    return load_skeleton()


@pytest.fixture(scope="module")
def lip(skel) -> ImuTruth:
    return make_imu_truth(skel, ImuRigConfig.lip(skel), np.random.default_rng(7))


def test_lip_rig_draw(skel):
    """Contract sensors; distinct rates within 0.5 %; mounting within 40 deg.

    Origins 85 % of the way down the bone, 3.5 cm off its axis (on the limb surface near the wrist / ankle).
    """
    rng = np.random.default_rng(1)
    truths = [make_imu_truth(skel, ImuRigConfig.lip(skel), rng) for _ in range(10)]
    specs = truths[0].specs
    assert [(s.name, s.bone_joint, s.topic) for s in specs] == [
        (n, d["bone_joint"], d["topic"]) for n, d in skel.lip_imus.items()
    ]
    assert specs[0].topic == "/dot/left_wrist/imu" and specs[0].bone_joint == "left_elbow"
    rates = np.array([s.rate_hz for s in specs])
    assert np.all(np.abs(rates / 60.0 - 1.0) <= 0.005) and np.unique(rates).size == 4
    assert all(0.0 <= s.phase_s < 1.0 / s.rate_hz for s in specs)
    angles = np.degrees([geodesic_angle(np.eye(3), s.R_B_S) for t in truths for s in t.specs])
    assert angles.max() <= 40.0 and angles.max() > 30.0 and angles.min() < 15.0
    psi = np.array([t.psi for t in truths])
    assert np.all(np.abs(psi) <= np.pi) and np.ptp(psi) > 1.0
    for s in specs:
        child = skel.offsets[skel.children(skel.index(s.bone_joint))[0]]
        along = s.offset_in_bone @ child / np.linalg.norm(child)
        off_axis = np.linalg.norm(s.offset_in_bone - along * child / np.linalg.norm(child))
        assert along == pytest.approx(0.85 * np.linalg.norm(child))
        assert off_axis == pytest.approx(0.035)
    assert np.all(np.isclose(truths[0].R_L_I, rot_z(truths[0].psi)))


def test_at_rest_gravity_points_up(skel, lip):
    """Standing still: |f| = g and R_I_S f = +g z (exact without noise, within the errors with DOT noise)."""
    streams = simulate_imus(standing(skel), lip, 0.0, 5.0, EXACT, np.random.default_rng(0))
    for s in streams.values():
        up = np.einsum("nab,nb->na", quat_to_matrix(s.quat), s.accel)
        np.testing.assert_allclose(np.linalg.norm(s.accel, axis=1), GRAVITY, atol=1e-9)
        np.testing.assert_allclose(up, np.tile(UP, (len(up), 1)), atol=1e-9)
        np.testing.assert_allclose(s.gyro, 0.0, atol=1e-12)
        np.testing.assert_allclose(s.acc_L_true, 0.0, atol=1e-9)
        assert abs(s.accel[:, 2]).max() < 9.0  # mounted on a T-posed limb: S is not level
    streams = simulate_imus(standing(skel), lip, 0.0, 5.0, ImuNoise(), np.random.default_rng(0))
    for s in streams.values():
        up = np.einsum("nab,nb->na", quat_to_matrix(s.quat), s.accel)
        tilt = np.degrees(np.arccos(up[:, 2] / np.linalg.norm(up, axis=1)))
        assert np.all(np.abs(np.linalg.norm(s.accel, axis=1) - GRAVITY) < 0.15)
        assert tilt.max() < 3.0


def test_orientation_composes_as_conventions(skel):
    """R_L_I @ R_I_S @ R_B_S^T is the bone's global rotation (LIP eq. 13), here the turning forearm."""
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    traj = arm_turning(skel, axis, 2.0)
    truth = make_imu_truth(skel, ImuRigConfig.lip(skel), np.random.default_rng(3))
    streams = simulate_imus(traj, truth, 0.0, 4.0, EXACT, np.random.default_rng(0))
    for spec in truth.specs:
        s = streams[spec.name]
        recovered = truth.R_L_I @ quat_to_matrix(s.quat) @ spec.R_B_S.T
        glob, _ = forward_kinematics(skel, traj.sample(s.t_true).local_rot)
        expected = glob[:, skel.index(spec.bone_joint)]
        np.testing.assert_allclose(recovered, expected, atol=1e-12)
        np.testing.assert_allclose(s.R_L_B_true, expected, atol=1e-12)
    forearm = streams["left_wrist"].R_L_B_true
    turn = axis_angle_to_matrix(np.outer(2.0 * streams["left_wrist"].t_true, axis))
    np.testing.assert_allclose(forearm, R_L_M @ turn, atol=1e-12)


def test_turning_forearm_rate_and_centripetal(skel):
    """Forearm at a constant rate w about a: gyro = R_B_S^T a w; a_B = w^2 a x (a x o); other sensors read zero rate."""
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    rate = 2.0
    truth = make_imu_truth(skel, ImuRigConfig.lip(skel), np.random.default_rng(4))
    streams = simulate_imus(arm_turning(skel, axis, rate), truth, 0.0, 4.0, EXACT, np.random.default_rng(0))
    spec = truth.specs[0]
    s = streams[spec.name]
    assert spec.name == "left_wrist"
    np.testing.assert_allclose(s.gyro, np.tile(spec.R_B_S.T @ axis * rate, (len(s.gyro), 1)), atol=1e-9)
    world_rate = np.einsum("ab,nbc,c->na", truth.R_L_I, quat_to_matrix(s.quat), s.gyro[0])
    np.testing.assert_allclose(world_rate, np.tile(R_L_M @ axis * rate, (len(s.gyro), 1)), atol=1e-9)
    acc_B = rate**2 * np.cross(axis, np.cross(axis, spec.offset_in_bone))
    np.testing.assert_allclose(s.acc_L_true, s.R_L_B_true @ acc_B, atol=1e-5)
    expected_f = np.einsum("ba,nb->na", spec.R_B_S, acc_B + np.einsum("nba,b->na", s.R_L_B_true, UP))
    np.testing.assert_allclose(s.accel, expected_f, atol=1e-5)
    for other in truth.specs[1:]:
        np.testing.assert_allclose(streams[other.name].gyro, 0.0, atol=1e-12)


def test_circling_body_centripetal(skel):
    """Body turning at w about z (pelvis on a 2 m circle): a_L = -w^2 (x, y, 0), gyro = R_L_S^T (0, 0, w).

    25 s spans several trajectory windows; the pelvis sensor of the suit and the four DOTs all checked.
    """
    rate, radius = 0.8, 2.0
    traj = circling(skel, radius, rate)
    rng = np.random.default_rng(5)
    for config in (ImuRigConfig.lip(skel), ImuRigConfig.suit(skel)):
        truth = make_imu_truth(skel, config, rng)
        streams = simulate_imus(traj, truth, 0.0, 25.0, EXACT, rng)
        for spec in truth.specs:
            s = streams[spec.name]
            assert np.all(np.diff(s.index) == 1)
            p = sensor_position(skel, traj, truth, s)
            centripetal = -(rate**2) * p * [1.0, 1.0, 0.0]
            np.testing.assert_allclose(s.acc_L_true, centripetal, atol=1e-5)
            R_L_S = truth.R_L_I @ quat_to_matrix(s.quat)
            np.testing.assert_allclose(s.accel, np.einsum("nba,nb->na", R_L_S, centripetal + UP), atol=1e-5)
            np.testing.assert_allclose(s.gyro, R_L_S[:, 2, :] * rate, atol=1e-9)
    pelvis = streams["pelvis"]  # half-way to the hips, spine and neck: 1.7 cm off the pelvis joint
    assert np.linalg.norm(pelvis.acc_L_true, axis=1) == pytest.approx(rate**2 * radius, rel=0.01)


def test_stamps_exact_without_jitter(skel, lip):
    """Stamps = measurement times in ns, one period apart, each sensor at its own rate."""
    streams = simulate_imus(standing(skel), lip, 0.0, 30.0, EXACT, np.random.default_rng(0))
    for spec in lip.specs:
        s = streams[spec.name]
        np.testing.assert_array_equal(s.index, np.arange(s.index[0], s.index[0] + len(s.index)))
        np.testing.assert_allclose(s.t_true, spec.phase_s + s.index / spec.rate_hz, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(s.stamp_ns, np.rint(s.t_true * 1e9).astype(np.int64))
        assert np.all(np.abs(np.diff(s.stamp_ns) - 1e9 / spec.rate_hz) <= 1.0)
        assert s.t_true[0] >= 2e-3 and s.t_true[-1] <= 30.0 - 2e-3
        assert len(s.t_true) == pytest.approx(30.0 * spec.rate_hz, abs=1)
        assert s.stamp_ns.dtype == np.int64


def test_long_capture_every_sample_once(skel):
    """Each sample once and in order across the simulator's time windows, also with samples on the edges.

    A round rate (100 Hz, no tolerance) puts a sample on every window edge, up to rounding.
    """
    rng = np.random.default_rng(0)
    for _ in range(40):
        truth = make_imu_truth(skel, ImuRigConfig((("a", "left_knee", "/a"),), 100.0), rng)
        s = simulate_imus(standing(skel), truth, 0.0, 31.0, EXACT, rng)["a"]
        np.testing.assert_array_equal(np.diff(s.index), 1)
        assert len(s.index) == len(s.accel) == len(s.quat) == len(s.R_L_B_true) == len(s.t_true)
        assert len(s.index) == pytest.approx(3100, abs=1)


def test_stamp_jitter_and_order(skel, lip):
    """Jitter std as configured, clipped at 3 std, stamps strictly increasing, mean period 1 / rate."""
    noise = replace(EXACT, stamp_jitter=1e-3)
    streams = simulate_imus(standing(skel), lip, 0.0, 120.0, noise, np.random.default_rng(0))
    for spec in lip.specs:
        s = streams[spec.name]
        err = s.stamp_ns * 1e-9 - s.t_true
        assert np.std(err) == pytest.approx(1e-3, rel=0.05)
        assert np.abs(err).max() <= 3e-3 + 1e-9 and abs(np.mean(err)) < 1e-4
        assert np.all(np.diff(s.stamp_ns) > 0)
        period = np.polyfit(s.index, s.stamp_ns * 1e-9, 1)[0]
        assert period == pytest.approx(1.0 / spec.rate_hz, rel=5e-6)
    with pytest.raises(ValueError, match="reorder"):
        simulate_imus(standing(skel), lip, 0.0, 1.0, replace(EXACT, stamp_jitter=3e-3), np.random.default_rng(0))


def test_latency_stamps_on_arrival(skel):
    """A sensor with a latency is stamped its latency plus a non-negative random delay late, in arrival order; the
    latencies are drawn per sensor in the configured range, after everything else (the same rig otherwise)."""
    config = ImuRigConfig.lip(skel, latency_s=(0.02, 0.06))
    truth = make_imu_truth(skel, config, np.random.default_rng(7))
    assert replace(truth, specs=tuple(replace(s, latency_s=0.0) for s in truth.specs)).as_dict() == \
        make_imu_truth(skel, ImuRigConfig.lip(skel), np.random.default_rng(7)).as_dict()
    latency = np.array([s.latency_s for s in truth.specs])
    assert np.all((latency >= 0.02) & (latency <= 0.06)) and np.ptp(latency) > 0.005
    streams = simulate_imus(standing(skel), truth, 0.0, 60.0, replace(EXACT, latency_jitter=0.005),
                            np.random.default_rng(0))
    for spec in truth.specs:
        s = streams[spec.name]
        late = s.stamp_ns * 1e-9 - s.t_true - spec.latency_s
        assert late.min() >= -1e-9 and np.median(late) == pytest.approx(0.005 * 0.674, abs=0.001)  # |N(0, 5 ms)|
        assert np.all(np.diff(s.stamp_ns) > 0)


def test_drops_at_configured_probability(skel, lip):
    streams = simulate_imus(standing(skel), lip, 0.0, 100.0, replace(EXACT, drop_prob=0.1), np.random.default_rng(0))
    kept = sum(len(s.index) for s in streams.values())
    total = sum(s.index[-1] - s.index[0] + 1 for s in streams.values())
    assert 1.0 - kept / total == pytest.approx(0.1, abs=0.008)  # 4 binomial std
    for s in streams.values():
        assert np.any(np.diff(s.index) > 1) and np.all(np.diff(s.index) >= 1)
        np.testing.assert_array_equal(np.rint(s.t_true * 1e9).astype(np.int64), s.stamp_ns)


def test_same_seed_same_streams(skel):
    def run(seed: int) -> tuple[ImuTruth, dict[str, ImuStream]]:
        rng = np.random.default_rng(seed)
        truth = make_imu_truth(skel, ImuRigConfig.lip(skel), rng)
        return truth, simulate_imus(circling(skel, 1.0, 1.0), truth, 0.0, 3.0, ImuNoise(), rng)

    (ta, a), (tb, b), (_, c) = run(11), run(11), run(12)
    assert ta.as_dict() == tb.as_dict()
    for name in a:
        for f in ("stamp_ns", "quat", "gyro", "accel", "index", "t_true"):
            np.testing.assert_array_equal(getattr(a[name], f), getattr(b[name], f))
    assert not np.array_equal(a["left_wrist"].accel, c["left_wrist"].accel)


@pytest.fixture(scope="module")
def crowd(skel) -> ImuTruth:
    """300 sensors on the pelvis, one clock, 25 Hz: a population for error statistics."""
    sensors = tuple((f"s{i}", "pelvis", f"/s{i}/imu") for i in range(300))
    return make_imu_truth(skel, ImuRigConfig(sensors, 25.0, shared_clock=True), np.random.default_rng(2))


def crowd_errors(skel, crowd, noise: ImuNoise, t_end: float):
    """Gyro and accel errors (sensors, N, 3) and orientation errors R_err (sensors, N, 3, 3) in I, at rest."""
    streams = simulate_imus(standing(skel), crowd, 0.0, t_end, noise, np.random.default_rng(3)).values()
    R_I_S = np.stack([true_R_I_S(crowd, s) for s in streams])
    gyro = np.stack([s.gyro for s in streams])
    accel = np.stack([s.accel for s in streams]) - np.einsum("snba,b->sna", R_I_S, UP)
    R_err = np.stack([quat_to_matrix(s.quat) for s in streams]) @ R_I_S.swapaxes(-1, -2)
    return gyro, accel, R_err


def test_white_noise_levels(skel, crowd):
    noise = replace(EXACT, gyro_noise=1e-3, accel_noise=2e-3)
    gyro, accel, R_err = crowd_errors(skel, crowd, noise, 4.0)
    assert np.std(gyro) == pytest.approx(1e-3 * np.sqrt(25.0), rel=0.02)
    assert np.std(accel) == pytest.approx(2e-3 * np.sqrt(25.0), rel=0.02)
    assert abs(np.corrcoef(gyro[:, 1:, 0].ravel(), gyro[:, :-1, 0].ravel())[0, 1]) < 0.02  # white
    np.testing.assert_allclose(R_err, np.broadcast_to(np.eye(3), R_err.shape), atol=1e-12)


def test_bias_constant_plus_walk(skel, crowd):
    noise = replace(EXACT, gyro_bias=0.01, accel_bias=0.05, gyro_bias_walk=2e-3, accel_bias_walk=1e-2)
    gyro, accel, _ = crowd_errors(skel, crowd, noise, 20.0)
    span = 20.0 - 2 * 2e-3 - 1 / 25.0  # roughly first to last sample
    assert np.std(gyro[:, 0]) == pytest.approx(0.01, rel=0.12)
    assert np.std(accel[:, 0]) == pytest.approx(0.05, rel=0.12)
    assert np.std(gyro[:, -1] - gyro[:, 0]) == pytest.approx(2e-3 * np.sqrt(span), rel=0.12)
    assert np.std(accel[:, -1] - accel[:, 0]) == pytest.approx(1e-2 * np.sqrt(span), rel=0.12)
    half = gyro.shape[1] // 2  # a walk: the spread over half the time is sqrt(1/2) of it
    assert np.std(gyro[:, half] - gyro[:, 0]) == pytest.approx(2e-3 * np.sqrt(span / 2), rel=0.12)


def test_orientation_errors_in_inertial_frame(skel, crowd):
    """Heading: a random walk about I's z from zero; roll/pitch: Gauss-Markov of the configured std and tau."""
    noise = replace(EXACT, heading_walk=np.deg2rad(3.0) / np.sqrt(60.0))
    _, _, R_err = crowd_errors(skel, crowd, noise, 60.0)
    rv = matrix_to_axis_angle(R_err)
    np.testing.assert_allclose(rv[..., :2], 0.0, atol=1e-12)  # about the vertical of I, not of S
    np.testing.assert_allclose(rv[:, 0], 0.0, atol=1e-12)
    assert np.degrees(np.std(rv[:, -1, 2])) == pytest.approx(3.0, rel=0.12)

    noise = replace(EXACT, tilt=np.deg2rad(0.8), tilt_tau=5.0)
    _, _, R_err = crowd_errors(skel, crowd, noise, 30.0)
    rv = matrix_to_axis_angle(R_err)
    np.testing.assert_allclose(rv[..., 2], 0.0, atol=1e-12)
    assert np.degrees(np.std(rv[..., :2])) == pytest.approx(0.8, rel=0.05)
    lag = 5 * 25  # one time constant
    corr = np.corrcoef(rv[:, :-lag, 0].ravel(), rv[:, lag:, 0].ravel())[0, 1]
    assert corr == pytest.approx(np.exp(-1.0), abs=0.06)


def test_suit_config(skel):
    """17 calibrated segments at 100 Hz on one clock: orientation = segment in I, stamps offset by the suit clock."""
    rng = np.random.default_rng(9)
    truth = make_imu_truth(skel, ImuRigConfig.suit(skel), rng)
    assert len(truth.specs) == 17 and 0 < abs(truth.clock_offset_s) <= 1.0
    assert {s.topic for s in truth.specs} == {f"/mocap/{seg}/imu" for seg in skel.suit_imus}
    assert all(np.array_equal(s.R_B_S, np.eye(3)) and s.rate_hz == 100.0 for s in truth.specs)
    traj = arm_turning(skel, np.array([0.0, 0.0, 1.0]), 1.5)
    streams = simulate_imus(traj, truth, 0.0, 3.0, ImuNoise.suit(), rng)
    times = streams["pelvis"].t_true
    for spec in truth.specs:
        s = streams[spec.name]
        np.testing.assert_array_equal(s.t_true, times)
        np.testing.assert_array_equal(s.stamp_ns, np.rint((times + truth.clock_offset_s) * 1e9).astype(np.int64))
        err = np.degrees(geodesic_angle(truth.R_L_I @ quat_to_matrix(s.quat), s.R_L_B_true))
        assert err.max() < 3.0
    exact = simulate_imus(traj, truth, 0.0, 3.0, EXACT, rng)
    glob, _ = forward_kinematics(skel, traj.sample(times).local_rot)
    forearm = exact["left_forearm"]
    segment = truth.R_L_I.T @ glob[:, skel.index("left_elbow")]
    np.testing.assert_allclose(quat_to_matrix(forearm.quat), segment, atol=1e-12)
    np.testing.assert_allclose(forearm.gyro, np.tile([0.0, 0.0, 1.5], (len(times), 1)), atol=1e-9)


def test_truth_as_dict_and_validation(lip):
    d = yaml.safe_load(yaml.safe_dump(lip.as_dict()))
    np.testing.assert_allclose(d["R_L_I"], rot_z(d["psi"]))
    assert set(d["sensors"]) == {s.name for s in lip.specs}
    np.testing.assert_allclose(d["sensors"]["left_wrist"]["R_B_S"], lip.specs[0].R_B_S)
    for bad in ({"drop_prob": 1.0}, {"gyro_noise": -1.0}, {"tilt_tau": 0.0}):
        with pytest.raises(ValueError):
            ImuNoise(**bad)
