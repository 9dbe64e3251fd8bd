"""The LIP pipeline end to end on the bundled demo bag (512 columns, 13 s: calibration poses, then walking)
with the shipped weights: frame accounting, calibration, stamps, accuracy, bad input, online == batch."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from helpers import DEMO_BAG

from lip_msgs_py import RosbagsBackend, array_to_cloud, cloud_to_array, read_header
from lip_ros.bagio import bag_topics, jazzy_typestore, mcap_writer, read_raw
from lip_ros.core import metrics
from lip_ros.core.imu_sync import FrameStatus
from lip_ros.lip.batch import replay_bag
from lip_ros.lip.evaluation.captures import load_capture
from lip_ros.lip.nets.lip_model import SHIPPED_WEIGHTS, LipModel
from lip_ros.lip.pipeline import FrameResult, LipPipeline, Outcome, PipelineConfig
from lip_ros.lip.sensors import IMU_TOPICS, LIDAR_TOPIC
from lip_ros.resources import params_dir
from lip_ros.rig.faults import FaultSpec, write_faulty_bag

WEIGHTS = params_dir() / "weights" / SHIPPED_WEIGHTS
# Bounds on the posed frames after the calibration poses. The shipped weights of 2026-11-27 (float16
# lip_small.pt, sha256 e27e2b53...) measured 10.0 mm MPJPE of the published joints on this bag, and with the
# surface fit 0.63 cm translation error (1.91 cm without it; the held-out set: 0.92 cm, docs/lip/transfer.md);
# the bounds leave 1.3x for retraining.
MAX_MPJPE_MM = 13.0
MAX_TRANSLATION_CM = 0.8

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def model() -> LipModel:
    return LipModel.load(WEIGHTS)


@pytest.fixture(scope="module")
def replayed(model) -> tuple[LipPipeline, list[FrameResult]]:
    pipeline = LipPipeline(model)
    return pipeline, list(replay_bag(pipeline, DEMO_BAG))


@pytest.fixture(scope="module")
def capture():
    return load_capture(DEMO_BAG)


def test_every_frame_is_accounted_for_in_order(replayed, capture):
    pipeline, results = replayed
    assert len(results) == bag_topics(DEMO_BAG)[LIDAR_TOPIC].count == len(capture.frame_stamp_ns)
    np.testing.assert_array_equal([r.frame_stamp_ns for r in results], capture.frame_stamp_ns)
    for r in results:
        assert (r.pose is not None) == (r.outcome == Outcome.POSE)
        assert r.outcome == Outcome.POSE or r.reason, r
    assert all(r.timing.network > 0.0 and r.timing.segmentation > 0.0 for r in results if r.pose is not None)
    assert not pipeline.imu_rejections


def test_calibration_succeeds_during_the_bag(replayed, capture):
    pipeline, results = replayed
    assert pipeline.calibrated, pipeline.calibration_status
    outcomes = [r.outcome for r in results]
    first_pose = outcomes.index(Outcome.POSE)
    assert Outcome.CALIBRATING in outcomes[:first_pose]
    assert Outcome.CALIBRATING not in outcomes[first_pose:]
    # posing starts by the end of the calibration poses, and every frame after them has a pose
    motion = capture.truth_stamp_ns >= capture.motion_start_ns
    assert all(o == Outcome.POSE for o, m in zip(outcomes, motion) if m)
    true_psi = capture.truth["imu_calibration"]["psi"]
    assert abs(np.angle(np.exp(1j * (pipeline.calibration.psi - true_psi)))) < np.deg2rad(10.0)


def test_pose_stamps_are_the_ground_truth_stamps(replayed, capture):
    _, results = replayed
    stamps = np.array([r.pose.stamp_ns for r in results if r.pose is not None])
    nearest = capture.gt_stamp_ns[np.abs(capture.gt_stamp_ns[None] - stamps[:, None]).argmin(axis=1)]
    assert np.abs(stamps - nearest).max() < 1_000_000


def test_accuracy_after_calibration(replayed, capture):
    _, results = replayed
    posed = [r for r in results if r.pose is not None and r.pose.stamp_ns >= capture.motion_start_ns]
    assert len(posed) > 50
    gt = np.array([np.abs(capture.gt_stamp_ns - r.pose.stamp_ns).argmin() for r in posed])
    joints = np.stack([r.pose.joint_pos for r in posed])
    mpjpe_mm = 1000.0 * metrics.mpjpe(joints, capture.gt_joint_pos[gt]).mean()
    trans_cm = 100.0 * metrics.translation_error(joints[:, 0], capture.gt_joint_pos[gt, 0]).mean()
    assert mpjpe_mm < MAX_MPJPE_MM, f"MPJPE {mpjpe_mm:.1f} mm"
    assert trans_cm < MAX_TRANSLATION_CM, f"translation error {trans_cm:.2f} cm"


class _FlushOnly(LipPipeline):
    """Never processes before the end: every frame waits for ``flush``."""

    def poll(self, now_ns: int | None = None) -> list[FrameResult]:
        return []


def _same(a: FrameResult, b: FrameResult) -> bool:
    if (a.frame_stamp_ns, a.outcome, a.reason) != (b.frame_stamp_ns, b.outcome, b.reason):
        return False
    if a.pose is None or b.pose is None:
        return a.pose is b.pose
    return a.pose.stamp_ns == b.pose.stamp_ns and all(
        np.array_equal(getattr(a.pose, k), getattr(b.pose, k)) for k in ("root_pos", "local_rot", "joint_pos"))


def test_online_equals_flush_only_batch(model):
    config = PipelineConfig(max_pending_frames=10_000)
    online = list(replay_bag(LipPipeline(model, config), DEMO_BAG))
    batch = list(replay_bag(_FlushOnly(model, config), DEMO_BAG))
    assert len(online) == len(batch)
    assert sum(r.outcome == Outcome.POSE for r in online) > 50
    assert all(_same(a, b) for a, b in zip(online, batch))


def _corrupted_bag(out, broken_cloud: int, narrow_cloud: int, nan_imu: range) -> None:
    """The demo bag with cloud ``broken_cloud`` truncated, cloud ``narrow_cloud`` cut to half its width and
    the left wrist's IMU samples ``nan_imu`` with a NaN orientation."""
    store = jazzy_typestore()
    backend = RosbagsBackend(store)
    types = {t: info.msgtype for t, info in bag_topics(DEMO_BAG).items()}
    counters = {LIDAR_TOPIC: 0, IMU_TOPICS["left_wrist"]: 0}
    with mcap_writer(out) as writer:
        conns = {t: writer.add_connection(t, m, typestore=store) for t, m in types.items()}
        for raw in read_raw(DEMO_BAG):
            data = raw.data
            k = counters.get(raw.topic)
            if k is not None:
                counters[raw.topic] += 1
                msg = store.deserialize_cdr(raw.data, types[raw.topic])
                if raw.topic == LIDAR_TOPIC and k == broken_cloud:
                    data = store.serialize_cdr(dataclasses.replace(msg, data=msg.data[:4096]), types[raw.topic])
                elif raw.topic == LIDAR_TOPIC and k == narrow_cloud:
                    half = np.ascontiguousarray(cloud_to_array(msg)[:, : msg.width // 2])
                    data = backend.serialize(array_to_cloud(backend, half, read_header(msg)[0], "os_lidar"),
                                             types[raw.topic])
                elif raw.topic != LIDAR_TOPIC and k in nan_imu:
                    msg.orientation.x = float("nan")
                    data = store.serialize_cdr(msg, types[raw.topic])
            writer.write(conns[raw.topic], raw.log_ns, data)


def test_bad_clouds_and_imu_samples_are_accounted_for(model, replayed, tmp_path):
    bag = tmp_path / "corrupted"
    nan_imu = range(520, 532)  # 0.2 s of the left wrist, in the walk
    _corrupted_bag(bag, broken_cloud=100, narrow_cloud=110, nan_imu=nan_imu)
    pipeline = LipPipeline(model)
    results = list(replay_bag(pipeline, bag))
    clean = replayed[1]
    assert len(results) == len(clean)
    assert results[100].outcome == Outcome.SKIPPED and results[100].reason.startswith("malformed cloud")
    assert results[110].outcome == Outcome.SKIPPED and "differs from the first frame" in results[110].reason
    assert sum(pipeline.imu_rejections.values()) == len(nan_imu)
    assert all(name == "left_wrist" for name, _ in pipeline.imu_rejections)
    # the IMU gap: frames in it have the wrist's sample held or, once that is too old, its bone held (posed with
    # the other three: 0.2 s is well within max_silent_ns); the reason names it
    gap = [r for r in results if r.sync is not None and r.sync.frame_status != FrameStatus.OK]
    assert gap and all("left_wrist" in r.reason and r.outcome == Outcome.POSE for r in gap)
    assert [r.sync.frame_status == FrameStatus.SKIP for r in gap] == ["its bone held" in r.reason for r in gap]
    assert any(r.sync.frame_status == FrameStatus.SKIP for r in gap)
    assert sum(r.outcome == Outcome.POSE for r in results) >= sum(r.outcome == Outcome.POSE for r in clean) - 6
    # a NaN sample handed over directly (not from a message) is rejected with its reason too
    nan_sample = SimpleNamespace(stamp_ns=results[-1].frame_stamp_ns, quat=np.array([np.nan, 0.0, 0.0, 1.0]),
                                 gyro=np.zeros(3), accel=np.array([0.0, 0.0, 9.8]))
    assert pipeline.add_imu("right_ankle", nan_sample) == "orientation not finite"
    assert pipeline.imu_rejections["right_ankle", "orientation not finite"] == 1


@pytest.mark.parametrize("kind", ["clock_back", "clock_forward"])
def test_a_clock_step_keeps_the_calibration_and_the_poses_resume_at_once(model, replayed, tmp_path, kind):
    """Every stamp 5 s back (a bag looped, a PTP step) or ahead from 7 s on, after the calibration: no frame is
    lost, the calibration is kept, the network starts a new sequence, and the poses are as good as before."""
    bag = tmp_path / kind
    write_faulty_bag(DEMO_BAG, bag, [FaultSpec(kind, 7.0, 100.0)])
    pipeline = LipPipeline(model)
    results = list(replay_bag(pipeline, bag))
    clean = replayed[1]
    assert len(results) == len(clean)
    assert [r.outcome for r in results] == [r.outcome for r in clean]
    assert pipeline.imu.calibration_count == 1 and pipeline.poser.sequences == 2
    step = int(np.sign(np.diff([r.frame_stamp_ns for r in results])).min() < 0)
    assert step == (kind == "clock_back") and pipeline.imu.clock_steps == step
    shift = [a.pose.stamp_ns - b.pose.stamp_ns for a, b in zip(results, clean) if a.pose is not None]
    assert set(shift) == {0, 5_000_000_000 * (-1 if kind == "clock_back" else 1)}
    err = [np.linalg.norm(a.pose.joint_pos - b.pose.joint_pos, axis=-1).mean()
           for a, b in zip(results, clean) if a.pose is not None and a.pose.stamp_ns != b.pose.stamp_ns]
    assert np.mean(err) < 0.01  # m: the same poses but for the new sequence's first frames
