"""The graph's stages without DDS: exact-stamp join, the IMU stage's calibration control, the pose stage's
sequences (the parameter file and its checks: test/nodes/test_lip_params.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers import DEMO_BAG

from lip_msgs_py import imu_sample
from lip_ros.core.exact_sync import ExactTimeJoiner
from lip_ros.core.rotations import rot_x, rot_z
from lip_ros.lip.batch import replay_bag
from lip_ros.lip.calibration import MAX_FRAME_RATE_HZ, MAX_SAMPLE_RATE_HZ, CalibrationDetector
from lip_ros.lip.dot_latency import LatencyConfig
from lip_ros.lip.nets.config import LipConfig
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.nets.models import LipNet
from lip_ros.lip.pipeline import LipPipeline, PipelineConfig
from lip_ros.lip.sensors import IMU_NAMES
from lip_ros.lip.stages import ImuStage, PoseStage

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_joiner_emits_complete_sets_in_order_and_gives_up_older_ones():
    j = ExactTimeJoiner(("points", "a", "b"))
    assert j.add("points", 10, "p10") == ([], [])
    assert j.add("points", 20, "p20") == ([], [])
    assert j.add("a", 20, "a20") == ([], [])
    done, dropped = j.add("b", 20, "b20")
    assert done == [{"points": "p20", "a": "a20", "b": "b20"}]
    assert [(d.stamp_ns, d.items, d.missing(j.names)) for d in dropped] == [(10, {"points": "p10"}, ["a", "b"])]
    assert j.open_stamps == 0
    with pytest.raises(KeyError):
        j.add("c", 30, None)


def test_joiner_bounds_what_waits():
    j = ExactTimeJoiner(("x", "y"), max_stamps=3)
    dropped = [d for t in range(5) for d in j.add("x", t, t)[1]]
    assert [d.stamp_ns for d in dropped] == [0, 1] and j.open_stamps == 3


@pytest.fixture(scope="module")
def calibrated_file(tmp_path_factory):
    """The demo bag through the batch pipeline, which saves the calibration it finds."""
    path = tmp_path_factory.mktemp("cal") / "calibration.yaml"
    pipeline = LipPipeline(LipModel.load(), PipelineConfig(calibration_file=path))
    for _ in replay_bag(pipeline, DEMO_BAG):
        pass
    assert pipeline.calibrated and path.is_file()
    return path


def test_imu_stage_resumes_recalibrates_and_resets(calibrated_file, tmp_path):
    file = tmp_path / "cal.yaml"
    file.write_bytes(calibrated_file.read_bytes())
    stage = ImuStage(calibration_file=file)
    assert stage.calibrated and not stage.calibrating and stage.status.startswith("calibrated")
    stage.start_calibration()  # the old calibration stays in use meanwhile
    assert stage.calibrated and stage.calibrating and "recalibrating" in stage.status
    count = stage.calibration_count
    stage.reset()
    assert not stage.calibrated and stage.calibrating and not file.exists()
    assert stage.calibration_count == count + 1
    assert ImuStage(calibration_file=file).calibrating  # a restart after a reset does not resume


def test_a_frame_is_scored_for_the_dot_latency_after_its_bones_came_out(calibrated_file, tmp_path):
    """The latency estimate's work on a frame waits until the stage is called again (or score_latency), so that
    a node can publish the frame's bones first; the next call scores it before anything else."""
    file = tmp_path / "cal.yaml"
    file.write_bytes(calibrated_file.read_bytes())
    stage = ImuStage(calibration_file=file)
    scored = []
    observe = stage.latency.observe
    stage.latency.observe = lambda t_ns, points: (scored.append(t_ns), observe(t_ns, points))
    samples = [((k + 1) * 10_000_000, n) for k in range(100) for n in IMU_NAMES]  # 1 s of the four DOTs, 100 Hz

    def add(stamp_ns, name):
        assert stage.add_imu(name, imu_sample(stamp_ns, name, [0.0, 0.0, 0.0, 1.0], [0.0] * 3, [0.0, 0.0, 9.81])) \
            is None

    for stamp, name in samples[:200]:
        add(stamp, name)
    assert stage.add_frame(300_000_000, 300_000_000, np.ones((50, 3))) == []
    out = stage.poll()
    assert [f.outcome.value for f in out] == ["pose"] and scored == []  # out, not yet scored
    add(*samples[200])
    assert scored == [300_000_000]  # the next call scored it first
    stage.add_frame(400_000_000, 400_000_000, np.ones((50, 3)))
    assert [f.outcome.value for f in stage.poll()] == ["pose"] and scored == [300_000_000]
    stage.score_latency()
    stage.score_latency()
    assert scored == [300_000_000, 400_000_000]  # once each


def test_pose_stage_starts_a_new_sequence_after_a_gap():
    torch_model = LipModel(LipNet(LipConfig.tiny()))
    stage = PoseStage(torch_model, max_gap_ns=1_000_000_000)
    rng = np.random.default_rng(0)
    rot = np.broadcast_to(np.eye(3), (4, 3, 3)).copy()
    pts = rng.normal([5.0, 0.0, 0.0], 0.2, (200, 3)).astype(np.float32)
    outs = [stage.estimate(t, pts, rot, np.zeros((4, 3)))[0] for t in (0, 100_000_000, 200_000_000)]
    assert stage.sequences == 1
    again = stage.estimate(3_000_000_000, pts, rot, np.zeros((4, 3)))[0]
    assert stage.sequences == 2
    np.testing.assert_allclose(again.local_rot, outs[0].local_rot, atol=1e-6)  # fresh state: as the first frame
    assert not np.allclose(outs[1].local_rot, outs[0].local_rot, atol=1e-6)


@pytest.mark.parametrize(("configured_hz", "frames_hz", "interleave"), [(10.0, 20.0, 2), (20.0, 10.0, 1),
                                                                       (10.0, 10.0, 1)])
def test_pose_stage_feeds_the_network_at_the_rate_the_stamps_show(configured_hz, frames_hz, interleave):
    """A LiDAR at another rate than the model was set for (``lidar_rate_hz``; an OS1 in a 20 Hz mode): once five
    intervals are known the model is set for the measured rate and a new sequence starts, the same frame by frame
    as in one batch; a frame dropped now and then does not move the rate. The same up to float32 rounding through
    the recurrent network, which an untrained network's 6D rotations can amplify: up to 2e-5 for most random
    initialisations (100 tried), 1.6e-4 for one unseeded in a suite run, against 1e-5 allowed then; seeded now."""
    torch.manual_seed(0)
    net = LipNet(LipConfig.tiny())
    period_ns = round(1e9 / frames_hz)
    stamps = [k * period_ns for k in range(12) if k != 7]  # one frame dropped
    rng = np.random.default_rng(0)
    rot = np.broadcast_to(np.eye(3), (len(stamps), 4, 3, 3)).copy()
    pts = [rng.normal([5.0, 0.0, 0.0], 0.2, (200, 3)).astype(np.float32) for _ in stamps]
    stage = PoseStage(LipModel(net, surface_fit=None, lidar_rate_hz=configured_hz))
    one_by_one = [stage.estimate(t, p, r, np.zeros((4, 3)))[0] for t, p, r in zip(stamps, pts, rot, strict=True)]
    assert stage.model.interleave == interleave and stage.period.rate_hz == pytest.approx(frames_hz)
    switched = interleave != LipModel(net, lidar_rate_hz=configured_hz).interleave
    assert stage.sequences == 1 + switched  # the switch at the sixth frame (five intervals)
    batch = PoseStage(LipModel(net, surface_fit=None, lidar_rate_hz=configured_hz))
    together = batch.estimate_sequence(stamps, pts, rot, np.zeros((len(stamps), 4, 3)))
    assert batch.sequences == stage.sequences and batch.model.interleave == interleave
    np.testing.assert_allclose([o.local_rot for o, _, _ in together], [o.local_rot for o in one_by_one], atol=1e-4)
    if switched:  # the sixth frame starts afresh, as a model set for the measured rate would
        fresh = PoseStage(LipModel(net, surface_fit=None, lidar_rate_hz=frames_hz))
        np.testing.assert_allclose(fresh.estimate(stamps[5], pts[5], rot[5], np.zeros((4, 3)))[0].local_rot,
                                   one_by_one[5].local_rot, atol=1e-4)


def test_without_the_calibration_poses_every_buffer_stays_bounded():
    """Three minutes of the four DOTs and no performer frame (no calibration poses): the samples kept for the
    calibration stay within the detector's horizon, and the state says what it waits for."""
    stage = ImuStage()
    rate_hz, minutes = 60.0, 3
    for k in range(int(minutes * 60 * rate_hz)):
        stamp = 1_000_000_000 + int(k * 1e9 / rate_hz)
        for name in IMU_NAMES:
            sample = imu_sample(stamp, name, [0.0, 0.0, 0.0, 1.0], [0.0] * 3, [0.0, 0.0, 9.81])
            assert stage.add_imu(name, sample) is None
    horizon_s = 60.0  # CalibrationDetector's default
    assert stage.calibration_samples <= len(IMU_NAMES) * (horizon_s * rate_hz + 1)
    assert stage.calibration_samples >= len(IMU_NAMES) * (horizon_s * rate_hz - 1)
    assert not stage.calibrated and "waiting for the calibration poses" in stage.status


def test_calibration_detector_stays_bounded_when_stamps_jump_back():
    detector = CalibrationDetector(horizon_s=1.0)
    for k in range(5000):
        stamp = (k % 50) * 10_000_000  # the clock jumps back 0.5 s every 50 samples, for ever
        detector.add_imu("left_wrist", stamp, np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3))
        detector.add_cloud(stamp, np.zeros((5, 3)))
    assert len(detector._samples["left_wrist"]) <= detector.max_buffered == int(1.0 * MAX_SAMPLE_RATE_HZ)
    assert len(detector._clouds) <= int(1.0 * MAX_FRAME_RATE_HZ)


@pytest.mark.parametrize("lidar_offset_s", [-1.7e9, 3600.0])
def test_frames_on_another_clock_are_skipped_with_the_reason(lidar_offset_s):
    """DOTs on ROS time and a LiDAR on its own oscillator (or an hour ahead): every frame is skipped saying the
    clocks disagree, none waits for a calibration that cannot come; without the offset the same frames calibrate."""
    outcomes = {}
    for offset in (0.0, lidar_offset_s):
        stage, done = ImuStage(), []
        for k in range(600):  # 10 s of DOT data at 60 Hz, a frame every 6th sample (10 Hz)
            stamp = 1_700_000_000_000_000_000 + int(k * 1e9 / 60.0)
            for name in IMU_NAMES:
                stage.add_imu(name, imu_sample(stamp, name, [0.0, 0.0, 0.0, 1.0], [0.0] * 3, [0.0, 0.0, 9.81]))
                done += stage.poll()
            if k % 6 == 0:
                done += stage.add_frame(stamp + int(offset * 1e9), stamp + int(offset * 1e9), np.zeros((50, 3)))
        done += stage.flush()
        outcomes[offset] = done
    assert {f.outcome.value for f in outcomes[0.0]} == {"calibrating"}  # still data: no poses, nothing wrong
    other = outcomes[lidar_offset_s]
    assert len(other) == 100 and {f.outcome.value for f in other} == {"skipped"}
    prefix = "clocks: the LiDAR frame is stamped "
    assert all(f.reason.startswith(prefix) for f in other), other[0].reason
    gaps = [float(f.reason[len(prefix):].split(" s ")[0]) for f in other]
    assert max(abs(g - lidar_offset_s) for g in gaps) < 10.0  # the offset, within the data's 10 s


def _turning_stage(calibrated_file, tmp_path, max_silent_ns: int, silent: dict[str, tuple[float, float]]
                   ) -> list:
    """Four DOTs turning together about the vertical at 0.5 rad/s (a performer turning), 100 Hz for 4 s, each
    silent in its ``silent`` window (s); frames every 100 ms from 0.5 s; the frames out."""
    file = tmp_path / "cal.yaml"
    file.write_bytes(calibrated_file.read_bytes())
    stage = ImuStage(calibration_file=file, latency=LatencyConfig(enabled=False), max_silent_ns=max_silent_ns)
    out = []
    for k in range(1, 401):
        t = k * 0.01
        for name in IMU_NAMES:
            a, b = silent.get(name, (np.inf, np.inf))
            if not a <= t < b:
                quat = [0.0, 0.0, np.sin(0.25 * t), np.cos(0.25 * t)]
                assert stage.add_imu(name, imu_sample(round(t * 1e9), name, quat, [0.0, 0.0, 0.5], [0.0, 0.0, 9.81])) \
                    is None
        if k >= 50 and k % 10 == 0:
            out += stage.add_frame(round(t * 1e9), round(t * 1e9), np.ones((50, 3)))
        out += stage.poll()
    return out + stage.flush()


def test_one_silent_dot_is_held_turning_with_the_others_for_up_to_max_silent(calibrated_file, tmp_path):
    """One DOT silent: its frames posed with its bone held (acceleration NaN) and turned as the others turned,
    which here is where it truly is; past ``max_silent_ns``, or two DOTs silent, or 0: skipped."""
    truth = {f.pose_stamp_ns: f.bone_rot for f in _turning_stage(calibrated_file, tmp_path, 0, {})}
    out = _turning_stage(calibrated_file, tmp_path, 1_000_000_000, {"left_ankle": (1.005, 3.0)})
    ankle = IMU_NAMES.index("left_ankle")
    held = [f for f in out if f.outcome.value == "pose" and f.held.any()]
    # its last sample (1.0 s) held by the synchroniser for the frame at 1.1 (max_hold 100 ms); then its bone held up
    # to 1 s after the last frame that interpolated it (1.0)
    assert [round(f.pose_stamp_ns * 1e-9, 1) for f in held] == [round(1.2 + 0.1 * k, 1) for k in range(9)]
    for f in held:
        assert f.held.tolist() == [n == "left_ankle" for n in IMU_NAMES]
        assert np.isnan(f.free_acc[ankle]).all() and np.isfinite(np.delete(f.free_acc, ankle, 0)).all()
        assert "left_ankle silent" in f.reason and "its bone held" in f.reason
        np.testing.assert_allclose(f.bone_rot, truth[f.pose_stamp_ns], atol=1e-6)  # turned with the performer
    skipped = [round(f.pose_stamp_ns * 1e-9, 1) for f in out if f.outcome.value == "skipped"]
    assert skipped == [round(2.1 + 0.1 * k, 1) for k in range(9)]
    after = [f for f in out if f.pose_stamp_ns >= 3.0e9]
    assert after and all(f.outcome.value == "pose" and not f.held.any() for f in after)
    two = _turning_stage(calibrated_file, tmp_path, 1_000_000_000,
                         {"left_ankle": (1.005, 3.0), "right_wrist": (1.005, 3.0)})
    never = _turning_stage(calibrated_file, tmp_path, 0, {"left_ankle": (1.005, 3.0)})
    for frames in (two, never):
        assert [round(f.pose_stamp_ns * 1e-9, 1) for f in frames if f.outcome.value == "skipped"] == \
            [round(1.2 + 0.1 * k, 1) for k in range(18)]


def test_a_held_bone_is_the_networks_input_not_a_measurement():
    """With the bones kept at their measurements (tolerance 0), a held bone (NaN acceleration) is the network's
    own estimate, the measured ones are exactly their measurements."""
    model = LipModel(LipNet(LipConfig.tiny()), bone_tolerance_deg=0.0, surface_fit=None)
    stage = PoseStage(model)
    rng = np.random.default_rng(1)
    rot = np.stack([rot_z(a) @ rot_x(b) for a, b in rng.uniform(-1.0, 1.0, (4, 2))])
    acc = np.zeros((4, 3))
    acc[2] = np.nan  # left ankle held
    pts = rng.normal([5.0, 0.0, 0.0], 0.2, (200, 3)).astype(np.float32)
    pose = stage.estimate(0, pts, rot, acc)[0]
    skeleton = stage.skeleton
    bones = [skeleton.index(skeleton.lip_imus[n]["bone_joint"]) for n in IMU_NAMES]
    for i, j in enumerate(bones):
        same = np.allclose(pose.glob_rot[j], rot[i], atol=1e-6)
        assert same == (i != 2), IMU_NAMES[i]
    assert np.isfinite(pose.joint_pos).all()
