"""A-pose / T-pose calibration (lip_ros.lip.calibration) against the rig's ground truth."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest
from helpers import feed_detector

from lip_ros.core.body import BodyModel
from lip_ros.core.frames import R_L_M_FACING_X
from lip_ros.core.rotations import (
    axis_angle_to_matrix,
    geodesic_angle,
    matrix_to_axis_angle,
    matrix_to_quat,
    quat_to_matrix,
    rot_x,
    rot_z,
)
from lip_ros.core.skeleton import NUM_JOINTS, Skeleton, load_skeleton
from lip_ros.lip.calibration import (
    POSES,
    Calibration,
    CalibrationConfig,
    CalibrationDetector,
    CalibrationError,
    calibrate,
    detect_pose_windows,
    heading_from_tpose,
    load_calibration,
    save_calibration,
)
from lip_ros.rig.capture import CaptureConfig, CaptureSession
from lip_ros.rig.imu import ImuNoise, ImuRigConfig, ImuStream, make_imu_truth, simulate_imus
from lip_ros.rig.lidar import Actor, OusterModel
from lip_ros.rig.trajectory import BodyPose

SEEDS = (0, 1, 2)
MS = 1_000_000


def deg(x: np.ndarray) -> np.ndarray:
    return np.rad2deg(x)


def wrap_deg(a: float) -> float:
    return float(deg(np.angle(np.exp(1j * a))))


def xyz(frame) -> np.ndarray:
    """The performer's points (N, 3) of a rig frame."""
    p = frame.points[frame.labels == 0]
    return np.stack([p["x"], p["y"], p["z"]], axis=-1).astype(np.float64)


@dataclass
class Capture:
    session: CaptureSession
    streams: dict[str, ImuStream]
    phases: dict[str, tuple[int, int]]
    clouds: list[tuple[int, np.ndarray]]  # (effective stamp, performer points) of the frames in the T-pose

    @property
    def points(self) -> np.ndarray:
        return np.concatenate([p for _, p in self.clouds])

    @property
    def heading(self) -> float:
        """The performer's true heading while calibrating."""
        return float(np.arctan2(-self.session.motion.centre[1], -self.session.motion.centre[0]))


def make_capture(seed: int, **kwargs) -> Capture:
    session = CaptureSession(CaptureConfig(scenario="mixed", seconds=14.0, seed=seed, **kwargs))
    phases = {n: (a, b) for n, a, b in session.phases_ns()}
    a, b = ((t - session.epoch_ns) / session.lidar.period_ns for t in phases["t_pose"])
    clouds = [(f.truth.stamp_ns, xyz(f.frame)) for f in session.frames(int(np.ceil(a)), int(b))]
    return Capture(session, session.imu_streams(), phases, clouds)


@pytest.fixture(scope="module", params=SEEDS)
def capture(request) -> Capture:
    return make_capture(request.param, bearing_deg=30.0 * request.param - 20.0)


@pytest.fixture(scope="module")
def one() -> Capture:
    """One more capture, for the tests that need just one."""
    return make_capture(3, bearing_deg=15.0)


def bone_errors_deg(cal: Calibration, streams: dict[str, ImuStream]) -> np.ndarray:
    """Calibrated R_L_B against the truth, every sample of every sensor."""
    return np.concatenate([deg(geodesic_angle(cal.apply(n, x.quat, x.accel)[0], x.R_L_B_true))
                           for n, x in streams.items()])


def test_rig_capture_accuracy(capture):
    """Random mounting up to 40 deg, random psi, the performer off the x axis: bone error <= 2 deg."""
    cal = calibrate(capture.streams, capture.points)
    err = bone_errors_deg(cal, capture.streams)
    assert err.mean() <= 2.0 and err.max() <= 5.0
    truth = capture.session.imu_truth
    for spec in truth.specs:
        assert deg(geodesic_angle(cal.R_B_S[spec.name], spec.R_B_S)) <= 2.5
    assert abs(wrap_deg(cal.psi - truth.psi)) <= 1.5
    assert cal.heading_source == "cloud" and abs(wrap_deg(cal.heading - capture.heading)) <= 1.0
    for pose in POSES:  # detected inside the true still phases
        (a, b), (ta, tb) = cal.windows[pose], capture.phases[pose]
        assert ta <= a < b <= tb and b - a >= 1.5e9
    acc_err = np.concatenate([np.linalg.norm(cal.apply(n, x.quat, x.accel)[1] - x.acc_L_true, axis=-1)
                              for n, x in capture.streams.items()])
    assert acc_err.mean() <= 0.3  # m/s^2: gravity removed, in L
    assert max(cal.residual_deg.values()) <= 3.0 and cal.tilt_deg <= 2.0


def test_noise_free_capture_is_exact():
    """Exact readings: the calibration is exact, R_L_B and the free acceleration to rounding (no cloud:
    the rig's performer stands on +x facing the LiDAR, the default heading)."""
    session = CaptureSession(CaptureConfig(scenario="jump", seconds=12.0, seed=4, imu_noise=False))
    streams = session.imu_streams()
    cal = calibrate(streams)
    assert cal.heading_source == "assumed"
    assert bone_errors_deg(cal, streams).max() < 1e-5  # arccos resolves ~1e-6 deg
    for n, x in streams.items():
        np.testing.assert_allclose(cal.apply(n, x.quat, x.accel)[1], x.acc_L_true, atol=1e-9)
    np.testing.assert_allclose(cal.R_L_I, session.imu_truth.R_L_I, atol=1e-9)


def test_explicit_windows_agree_with_detection(one):
    auto = calibrate(one.streams, one.points)
    margin = 150 * MS
    windows = {p: (a + margin, b - margin) for p, (a, b) in one.phases.items() if p in POSES}
    given = calibrate(one.streams, one.points, windows=windows)
    assert given.windows == windows
    assert abs(wrap_deg(given.psi - auto.psi)) < 0.3
    for n in auto.R_B_S:
        assert deg(geodesic_angle(given.R_B_S[n], auto.R_B_S[n])) < 0.5
    assert detect_pose_windows(one.streams) == auto.windows
    with pytest.raises(CalibrationError, match="A-pose first"):
        calibrate(one.streams, windows={"a_pose": windows["t_pose"], "t_pose": windows["a_pose"]})


class TwoPoses:
    """A-pose still for 2.5 s, arms raised into the T-pose over 1 s, T-pose still; standing at ``pos`` facing
    ``heading`` (a Trajectory for the rig's IMU and LiDAR simulators)."""

    def __init__(self, skeleton: Skeleton, pos: np.ndarray, heading: float) -> None:
        self.skeleton, self.pos, self.heading = skeleton, pos, heading
        a_pose = skeleton.pose_local_rotations("a_pose")
        self.turn = {j: matrix_to_axis_angle(a_pose[j]) for j in range(NUM_JOINTS) if not np.allclose(a_pose[j],
                                                                                                       np.eye(3))}

    def sample(self, t: np.ndarray) -> BodyPose:
        s = np.clip(np.atleast_1d(t) - 2.5, 0.0, 1.0)
        s = s * s * (3.0 - 2.0 * s)
        rot = np.tile(np.eye(3), (s.size, NUM_JOINTS, 1, 1))
        rot[:, 0] = rot_z(self.heading) @ R_L_M_FACING_X
        for j, aa in self.turn.items():
            rot[:, j] = axis_angle_to_matrix(np.outer(1.0 - s, aa))
        return BodyPose(np.tile(self.pos, (s.size, 1)), rot)


@pytest.mark.parametrize("off_deg", [-50.0, 35.0])
def test_heading_from_tpose_cloud_when_not_facing_the_lidar(off_deg):
    """Rendered with the rig's LiDAR (self-occlusion and all): the performer turned away from the sensor."""
    skeleton = load_skeleton()
    pos = np.array([6.0, -2.5, -1.2 + skeleton.pelvis_height])
    heading = float(np.arctan2(-pos[1], -pos[0]) + np.deg2rad(off_deg))
    motion = TwoPoses(skeleton, pos, heading)
    rng = np.random.default_rng(7)
    truth = make_imu_truth(skeleton, ImuRigConfig.lip(skeleton), rng)
    streams = simulate_imus(motion, truth, 0.0, 6.0, ImuNoise(), rng)
    lidar = OusterModel.os1_128()
    actor = [Actor(BodyModel(skeleton), motion)]
    points = np.concatenate([xyz(lidar.scan(k * lidar.period_ns, None, actor, rng)) for k in range(40, 56, 3)])
    cal = calibrate(streams, points)
    assert abs(wrap_deg(cal.heading - heading)) <= 1.5
    assert abs(wrap_deg(cal.psi - truth.psi)) <= 2.0
    assert bone_errors_deg(cal, streams).mean() <= 2.0
    assumed = calibrate(streams, windows=cal.windows, config=CalibrationConfig(default_heading=heading - np.deg2rad(
        off_deg)))  # the paper's assumption (facing the LiDAR) is off by the turn
    assert abs(wrap_deg(assumed.psi - truth.psi) + off_deg) <= 2.0


def test_heading_from_tpose_cloud_geometry(one):
    """Turning the cloud about the performer's vertical axis turns the heading; a cloud that is not a
    T-pose (a column, a handful of points) is an error."""
    points = one.points
    base, elongation = heading_from_tpose(points)
    assert elongation > 3.0
    middle = np.median(points, axis=0)
    for turn in (-25.0, 40.0):
        turned = (points - middle) @ rot_z(np.deg2rad(turn)).T + middle
        assert wrap_deg(heading_from_tpose(turned)[0] - base) == pytest.approx(turn, abs=0.5)
    rng = np.random.default_rng(3)
    column = np.column_stack([rng.normal(0, 0.15, (500, 2)) + [5.0, 1.0], rng.uniform(-1.2, 0.6, 500)])
    with pytest.raises(CalibrationError, match="not elongated"):
        heading_from_tpose(column)
    with pytest.raises(CalibrationError, match="T-pose points"):
        heading_from_tpose(points[:20])


def swayed(streams: dict[str, ImuStream], amp_deg: float, hz: float) -> dict[str, ImuStream]:
    """Every sensor rocking about its own x axis: R_I_S @ Rx(amp sin(2 pi hz t)), the gyro to match."""
    out = {}
    for name, x in streams.items():
        w = 2.0 * np.pi * hz
        angle = np.deg2rad(amp_deg) * np.sin(w * x.t_true)
        rate = np.deg2rad(amp_deg) * w * np.cos(w * x.t_true)
        rx = rot_x(angle)
        gyro = np.einsum("nba,nb->na", rx, x.gyro) + rate[:, None] * [1.0, 0.0, 0.0]
        out[name] = replace(x, quat=matrix_to_quat(quat_to_matrix(x.quat) @ rx), gyro=gyro)
    return out


def test_poses_not_held_still_is_an_error(one):
    streams = swayed(one.streams, amp_deg=6.0, hz=0.5)
    with pytest.raises(CalibrationError, match="no window of >= 1 s in which all of"):
        calibrate(streams)
    windows = {p: one.phases[p] for p in POSES}
    with pytest.raises(CalibrationError, match="was not held still in the a_pose window"):
        calibrate(streams, windows=windows)
    after = one.phases["to_motion"][1]  # windows over free motion
    with pytest.raises(CalibrationError, match="not held still"):
        calibrate(one.streams, windows={"a_pose": (after, after + 1_000 * MS),
                                             "t_pose": (after + 2_000 * MS, after + 3_000 * MS)})


def test_inconsistent_poses_are_errors(one):
    windows = {p: one.phases[p] for p in POSES}
    slipped = dict(one.streams)  # the left wrist sensor turns 20 deg on its strap between the poses
    x = slipped["left_wrist"]
    later = (x.stamp_ns > windows["a_pose"][1])[:, None, None]
    turn = axis_angle_to_matrix(np.array([0.0, np.deg2rad(20.0), 0.0]))
    slipped["left_wrist"] = replace(x, quat=matrix_to_quat(np.where(later, quat_to_matrix(x.quat) @ turn,
                                                                    quat_to_matrix(x.quat))))
    with pytest.raises(CalibrationError, match=r"disagree \(equation 11\).*left_wrist"):
        calibrate(slipped, windows=windows)
    # the whole body leaning forward by 25 deg: its up is no longer I's z
    truth = one.session.imu_truth
    R_L_M = one.session.motion.sample(np.zeros(1)).local_rot[0, 0]
    left_in_i = (truth.R_L_I.T @ R_L_M)[:, 0]
    lean = axis_angle_to_matrix(np.deg2rad(25.0) * left_in_i)
    leaning = {n: replace(x, quat=matrix_to_quat(lean @ quat_to_matrix(x.quat))) for n, x in one.streams.items()}
    with pytest.raises(CalibrationError, match="from vertical"):
        calibrate(leaning, windows=windows)


def test_missing_or_invalid_sensor_is_an_error(one):
    streams = {n: x for n, x in one.streams.items() if n != "right_ankle"}
    with pytest.raises(CalibrationError, match="no valid data from right_ankle"):
        calibrate(streams)
    x = one.streams["left_wrist"]
    streams = dict(one.streams, left_wrist=replace(x, quat=np.full_like(x.quat, np.nan)))
    with pytest.raises(CalibrationError, match="no valid data from left_wrist"):
        calibrate(streams)


def test_yaml_round_trip(one, tmp_path):
    cal = calibrate(one.streams, one.points)
    path = tmp_path / "calibration.yaml"
    save_calibration(cal, path)
    text = path.read_text()
    assert text.startswith("version: 1\n") and "R_B_S" in text and "!!" not in text  # plain YAML types
    loaded = load_calibration(path)
    np.testing.assert_allclose(loaded.R_L_I, cal.R_L_I, atol=1e-12)
    np.testing.assert_allclose(loaded.R_I_M, cal.R_I_M, atol=1e-12)
    assert loaded.psi == pytest.approx(cal.psi, abs=1e-12) and loaded.windows == cal.windows
    assert loaded.residual_deg == cal.residual_deg and loaded.heading_source == cal.heading_source
    x = one.streams["right_wrist"]
    for a, b in zip(loaded.apply("right_wrist", x.quat, x.accel), cal.apply("right_wrist", x.quat, x.accel)):
        np.testing.assert_allclose(a, b, atol=1e-12)
    path.write_text(text.replace("version: 1", "version: 99"))
    with pytest.raises(ValueError, match="version 99"):
        load_calibration(path)


def test_online_detector(one):
    """Samples and clouds fed as they come: no calibration until the T-pose was held, then the batch one."""
    detector = CalibrationDetector()
    t_pose = one.phases["t_pose"]
    done_at, statuses = None, set()
    for stamp in feed_detector(detector, one.streams, one.clouds):
        statuses.add(detector.status)
        done_at = stamp
    assert "1 still pose(s) found, but no A-pose followed by a T-pose" in " ".join(statuses)  # the A-pose alone
    assert detector.calibration is not None and t_pose[0] + 1e9 <= done_at <= t_pose[1]
    cal = detector.calibration
    assert cal.heading_source == "cloud" and detector.status.startswith("calibrated")
    batch = calibrate(one.streams, one.points)
    assert abs(wrap_deg(cal.psi - batch.psi)) < 0.5
    assert bone_errors_deg(cal, one.streams).mean() <= 2.0
