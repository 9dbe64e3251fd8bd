"""DOTs with inertial headings of their own (not reset together): the wrists' headings from the A/T poses, the
ankles' from walking (lip_ros.lip.gait_heading), against the rig's truth (``imu_heading_spread_deg``)."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pytest
from helpers import feed_detector

from lip_ros.core.rotations import geodesic_angle
from lip_ros.core.skeleton import load_skeleton
from lip_ros.lip.calibration import POSES, CalibrationDetector, calibrate, load_calibration, save_calibration
from lip_ros.lip.gait_heading import stride_heading
from lip_ros.lip.stages import ImuStage
from lip_ros.rig.capture import CaptureConfig, CaptureSession
from lip_ros.rig.imu import ImuStream

WRISTS, ANKLES = ("left_wrist", "right_wrist"), ("left_ankle", "right_ankle")
WALK_SEEDS = (0, 1, 2, 3)


@dataclass
class Walk:
    session: CaptureSession
    streams: dict[str, ImuStream]
    clouds: list[tuple[int, np.ndarray]]  # (effective stamp, performer points in L) of every frame with some

    def true_heading(self, name: str) -> float:
        """The sensor's own inertial heading in L."""
        truth = self.session.imu_truth
        return truth.psi + next(s.heading_offset for s in truth.specs if s.name == name)

    def track(self, after_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """The performer's track from the LiDAR: stamps and the points' median xy, after ``after_ns``."""
        kept = [(t, np.median(p[:, :2], axis=0)) for t, p in self.clouds if t > after_ns]
        return np.array([t for t, _ in kept]), np.array([c for _, c in kept])


@functools.cache
def walk(seed: int, scenario: str = "walk", spread_deg: float = 90.0) -> Walk:
    session = CaptureSession(CaptureConfig(scenario=scenario, seconds=20.0, seed=seed, columns=512,
                                           imu_heading_spread_deg=spread_deg))
    clouds = []
    for f in session.frames():
        p = f.frame.points[f.frame.labels == 0]
        if len(p):
            clouds.append((f.truth.stamp_ns, np.stack([p["x"], p["y"], p["z"]], axis=-1).astype(np.float64)))
    return Walk(session, session.imu_streams(), clouds)


def wrap_deg(a: float) -> float:
    return float(np.degrees(np.angle(np.exp(1j * a))))


def bone_error_deg(cal, walk_: Walk, name: str) -> float:
    x = walk_.streams[name]
    return float(np.degrees(geodesic_angle(cal.apply(name, x.quat, x.accel)[0], x.R_L_B_true)).mean())


def t_pose_points(walk_: Walk, cal) -> np.ndarray:
    t0, t1 = cal.windows["t_pose"]
    return np.concatenate([p for t, p in walk_.clouds if t0 <= t <= t1])


@pytest.mark.parametrize("spread_deg", [30.0, 90.0])
def test_wrists_are_calibrated_each_in_its_own_frame_and_the_ankles_wait(spread_deg):
    """Each wrist fixes its own heading from the poses; the ankles' cannot be told from them and are pending."""
    w = walk(4, spread_deg=spread_deg)
    poses = calibrate(w.streams)
    cal = calibrate(w.streams, t_pose_points(w, poses), poses.windows)
    assert cal.heading_pending == ANKLES and not cal.complete
    assert set(cal.heading_offset) == {"right_wrist"}  # the left wrist's frame is I
    for name in WRISTS:
        assert bone_error_deg(cal, w, name) <= 2.0
        sensor_heading = cal.psi + cal.heading_offset.get(name, 0.0)
        assert abs(wrap_deg(sensor_heading - w.true_heading(name))) <= 2.0
    with pytest.raises(ValueError, match="does not know the inertial headings of left_ankle, right_ankle"):
        ImuStage(calibration=cal)  # never used before it is complete
    reset = walk(4, spread_deg=0.0)  # the same capture after a heading reset: one frame, nothing pending
    shared = calibrate(reset.streams)
    assert shared.complete and not shared.heading_offset


@pytest.mark.parametrize("seed", WALK_SEEDS)
def test_ankle_heading_from_walking_strides(seed):
    """A few strides of walking, seen by the ankle DOT and by the LiDAR (the segmented points' median), give the
    DOT's heading within 8 deg (measured: 0-6 deg), and the calibration's ankle bones within 3 deg."""
    w = walk(seed)
    poses = calibrate(w.streams)
    cal = calibrate(w.streams, t_pose_points(w, poses), poses.windows)
    track_ns, track_xy = w.track(cal.windows["t_pose"][1])
    for name in ANKLES:
        x = w.streams[name]
        found = stride_heading(x.stamp_ns, x.quat, x.gyro, x.accel, track_ns, track_xy)
        assert found.heading is not None, found.reason
        assert found.strides >= 3 and found.agreement >= 0.9
        assert abs(wrap_deg(found.heading - w.true_heading(name))) <= 8.0
        cal = cal.with_heading(name, found.heading, load_skeleton())
    assert cal.complete
    for name in ANKLES:
        assert bone_error_deg(cal, w, name) <= 3.0


def test_no_walking_no_ankle_heading_saying_why():
    """Motion without walking strides (the 'mixed' set: squats, arm work, turns on the spot) gives no heading."""
    w = walk(0, scenario="mixed")
    t_pose_end = next(b for n, _, b in w.session.phases_ns() if n == "t_pose")
    track_ns, track_xy = w.track(t_pose_end)
    x = w.streams["left_ankle"]
    found = stride_heading(x.stamp_ns, x.quat, x.gyro, x.accel, track_ns, track_xy)
    assert found.heading is None and "walking strides seen" in found.reason


def test_online_detector_asks_for_walking_then_calibrates(tmp_path):
    """Fed as the data comes: the poses solved, then 'walk a few steps forward' with the strides seen so far, then
    calibrated within 10 s of walking with every bone within 2.5 deg; the file keeps the headings."""
    w = walk(1)
    detector = CalibrationDetector()
    statuses, done_at = [], None
    for stamp in feed_detector(detector, w.streams, w.clouds):
        statuses.append(detector.status)
        done_at = stamp
    walking = [s for s in statuses if "walk a few steps forward" in s]
    assert walking and any("of 3 walking strides seen" in s for s in walking)
    walk_start = next(a for n, a, _ in w.session.phases_ns() if n == "walk")
    assert detector.calibration is not None and done_at - walk_start <= 10e9
    cal = detector.calibration
    assert cal.complete and "DOT headings: each its own" in detector.status
    assert max(bone_error_deg(cal, w, n) for n in (*WRISTS, *ANKLES)) <= 2.5
    path = tmp_path / "calibration.yaml"
    save_calibration(cal, path)
    loaded = load_calibration(path)
    assert loaded.heading_offset == pytest.approx(cal.heading_offset) and loaded.complete
    for name in ANKLES:
        x = w.streams[name]
        np.testing.assert_allclose(loaded.apply(name, x.quat, x.accel)[0], cal.apply(name, x.quat, x.accel)[0],
                                   atol=1e-9)
    assert set(cal.windows) == set(POSES)
