"""The fast batch path, ``lip_ros.lip.batch.process_bag_batch``, gives ``replay_bag``'s results: on the bundled demo
bag (512 columns, 13 s) and on a copy with odd messages; and its parts match what they replace: ``stream_raw`` ==
``read_raw``, the CDR decoders == rosbags + lip_msgs_py, ``PoseStage.estimate_sequence`` == ``estimate``."""

from __future__ import annotations

import dataclasses
import struct
import zlib
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from helpers import DEMO_BAG
from mcap.reader import make_reader
from rosbags.rosbag2 import StoragePlugin, Writer

from lip_msgs_py import MalformedMessageError, cloud_to_array, msg_to_imu, read_header
from lip_msgs_py.cdr import cloud_msg, imu_samples
from lip_ros.bagio import BagError, bag_span, bag_topics, jazzy_typestore, mcap_writer, read_raw
from lip_ros.bagstream import stream_raw
from lip_ros.lip.batch import POSE_BATCH, process_bag_batch, replay_bag
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.pipeline import FrameResult, LipPipeline
from lip_ros.lip.sensors import IMU_TOPICS, LIDAR_TOPIC
from lip_ros.lip.stages import PoseStage

TOPICS = [LIDAR_TOPIC, *IMU_TOPICS.values()]
POSE_TOLERANCE = 1e-4  # m, and rotation matrix entries (about rad): float32 network outputs, batched vs per frame
IMU_FIELDS = ("quat", "gyro", "accel", "quat_cov", "gyro_cov", "accel_cov")

pytestmark = pytest.mark.usefixtures("one_torch_thread")

Run = tuple[LipPipeline, list[FrameResult]]


@pytest.fixture(scope="module")
def model() -> LipModel:
    return LipModel.load()


def _runs(model: LipModel, bag: Path) -> tuple[Run, Run]:
    reference, fast = LipPipeline(model), LipPipeline(model, pose_batch=POSE_BATCH)
    return (reference, list(replay_bag(reference, bag))), (fast, list(process_bag_batch(fast, bag)))


def _assert_same(reference: Run, fast: Run) -> None:
    (p, want), (q, got) = reference, fast
    assert [(r.frame_stamp_ns, r.outcome, r.reason) for r in got] == [(r.frame_stamp_ns, r.outcome, r.reason)
                                                                     for r in want]
    for a, b in zip(want, got, strict=True):
        assert (a.sync is None) == (b.sync is None) and (a.sync is None or a.sync.same_as(b.sync))
        assert (a.pose is None) == (b.pose is None)
        if a.pose is not None:
            assert a.pose.stamp_ns == b.pose.stamp_ns
            for k in ("root_pos", "local_rot", "glob_rot", "joint_pos"):
                np.testing.assert_allclose(getattr(b.pose, k), getattr(a.pose, k), rtol=0, atol=POSE_TOLERANCE)
            assert b.pose.body_scale == pytest.approx(a.pose.body_scale, abs=POSE_TOLERANCE)
    assert q.imu_rejections == p.imu_rejections
    assert q.poser.sequences == p.poser.sequences
    assert q.calibrated == p.calibrated
    if p.calibrated:  # the same samples in the same order: the same calibration, bit for bit
        np.testing.assert_array_equal(q.calibration.R_L_I, p.calibration.R_L_I)


def test_batch_gives_replay_bags_results(model):
    reference, fast = _runs(model, DEMO_BAG)
    assert sum(r.pose is not None for r in reference[1]) > 50 and reference[0].calibrated
    _assert_same(reference, fast)


def _not_provided(imu: object, covariance: str) -> object:
    """An Imu message with one component marked not provided (REP-145: covariance[0] = -1)."""
    return dataclasses.replace(imu, **{covariance: np.r_[-1.0, getattr(imu, covariance)[1:]]})


def _odd_copy(out: Path) -> Counter[str]:
    """The demo bag's LiDAR and IMU topics with odd messages: a truncated and a big-endian cloud; left wrist
    samples with a NaN orientation, angular velocity not provided, big-endian, repeated, a quaternion off unit
    norm, swapped with the next one. Returns the changes made, by topic."""
    store = jazzy_typestore()
    wrist = IMU_TOPICS["left_wrist"]
    seen: Counter[str] = Counter()
    changed: Counter[str] = Counter()
    swapped = None
    with mcap_writer(out, zstd=True) as writer:
        conns = {t: writer.add_connection(t, info.msgtype, typestore=store)
                 for t, info in bag_topics(DEMO_BAG).items() if t in TOPICS}
        for m in read_raw(DEMO_BAG, TOPICS):
            k = seen[m.topic]
            seen[m.topic] += 1
            data = m.data
            if (m.topic, k) in ((LIDAR_TOPIC, 90), (LIDAR_TOPIC, 95)):
                msg = store.deserialize_cdr(m.data, m.msgtype)
                if k == 90:
                    msg = dataclasses.replace(msg, data=msg.data[:4096])
                data = store.serialize_cdr(msg, m.msgtype, little_endian=k == 90)
                changed[m.topic] += 1
            elif m.topic == wrist and k in range(500, 530, 5):
                msg = store.deserialize_cdr(m.data, m.msgtype)
                if k == 500:
                    msg.orientation.x = float("nan")
                elif k == 505:
                    msg = _not_provided(msg, "angular_velocity_covariance")
                elif k == 520:
                    msg.orientation.w *= 1.01
                data = store.serialize_cdr(msg, m.msgtype, little_endian=k != 510)
                changed[m.topic] += 1
                if k == 515:
                    writer.write(conns[m.topic], m.log_ns, data)
                elif k == 525:
                    swapped = (m.log_ns, data)
                    continue
            elif swapped is not None and m.topic == wrist:  # the next sample first, each at the other's log time
                writer.write(conns[m.topic], swapped[0], data)
                data, swapped = swapped[1], None
            writer.write(conns[m.topic], m.log_ns, data)
    return changed


def test_batch_gives_replay_bags_results_with_odd_messages(model, tmp_path):
    bag = tmp_path / "odd"
    assert _odd_copy(bag) == {LIDAR_TOPIC: 2, IMU_TOPICS["left_wrist"]: 6}
    reference, fast = _runs(model, bag)
    reasons = Counter(reason for _, reason in reference[0].imu_rejections.elements())
    assert reasons["duplicate stamp"] == 1 and reasons["angular velocity not finite"] == 1
    assert sum(1 for r in reasons if r.startswith("malformed")) == 2  # the NaN and the one off unit norm
    assert any(r.reason.startswith("malformed cloud") for r in reference[1])
    _assert_same(reference, fast)


def _write_raw(out: Path, messages: list, storage: StoragePlugin) -> None:
    store = jazzy_typestore()
    with Writer(out, version=9, storage_plugin=storage) as writer:
        conns = {}
        for m in messages:
            if m.topic not in conns:
                conns[m.topic] = writer.add_connection(m.topic, m.msgtype, typestore=store)
            writer.write(conns[m.topic], m.log_ns, m.data)


@pytest.mark.parametrize("storage", [StoragePlugin.MCAP, StoragePlugin.SQLITE3], ids=["mcap", "sqlite3"])
def test_stream_raw_equals_read_raw(tmp_path, storage):
    """The demo bag (zstd chunks) and its last second uncompressed (MCAP) or in sqlite3 (read by rosbags)."""
    tail = tmp_path / "tail"
    _write_raw(tail, list(read_raw(DEMO_BAG, start_ns=bag_span(DEMO_BAG)[1] - 1_000_000_000)), storage)
    for bag, topics in ((DEMO_BAG, TOPICS), (tail, None), (tail, TOPICS[1:])):
        kept = [(m.topic, m.log_ns, m.msgtype, np.frombuffer(m.data, np.uint8)) for m in stream_raw(bag, topics)]
        want = list(read_raw(bag, topics))
        assert len(kept) == len(want) > 0
        # arrays made from the views were never overwritten by later chunks
        assert all((t, n, ty, a.tobytes()) == (w.topic, w.log_ns, w.msgtype, w.data)
                   for (t, n, ty, a), w in zip(kept, want, strict=True))


def test_stream_raw_checks_chunk_crcs(tmp_path):
    """rosbags writes uncompressed chunks without a CRC (0); with the right one set the bag reads, with one
    byte of the records flipped it fails."""
    bag = tmp_path / "bag"
    _write_raw(bag, list(read_raw(DEMO_BAG, TOPICS[1:], start_ns=bag_span(DEMO_BAG)[1] - 1_000_000_000)),
               StoragePlugin.MCAP)
    path = next(bag.glob("*.mcap"))
    with path.open("rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[-1]
    assert chunk.compression == ""
    data = bytearray(path.read_bytes())
    end = chunk.chunk_start_offset + chunk.chunk_length
    crc_at = chunk.chunk_start_offset + 9 + 24  # opcode and length, then start and end time, uncompressed size
    assert struct.unpack_from("<I", data, crc_at) == (0,)
    struct.pack_into("<I", data, crc_at, zlib.crc32(data[end - chunk.compressed_size : end]))
    path.write_bytes(bytes(data))
    want = [(m.topic, m.log_ns, bytes(m.data)) for m in read_raw(bag, TOPICS[1:])]
    assert [(m.topic, m.log_ns, bytes(m.data)) for m in stream_raw(bag, TOPICS[1:])] == want
    data[end - 8] ^= 0xFF  # inside the last message's data
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match="fails its checksum"):
        list(stream_raw(bag, TOPICS[1:]))


def test_cdr_decoders_match_rosbags_and_lip_msgs_py():
    store = jazzy_typestore()
    imu_raw, imu_want = [], []
    for m in read_raw(DEMO_BAG, TOPICS):
        msg = store.deserialize_cdr(m.data, m.msgtype)
        if m.topic != LIDAR_TOPIC:
            imu_raw.append(m.data)
            imu_want.append(msg_to_imu(msg))
        elif len(imu_raw) % 7 == 0:
            fast = cloud_msg(m.data)
            assert read_header(fast) == read_header(msg)
            got, want = cloud_to_array(fast), cloud_to_array(msg)
            assert got.dtype == want.dtype and got.shape == want.shape and got.tobytes() == want.tobytes()
    # components not provided (REP-145), one or several: NaN, as msg_to_imu gives them
    imu = store.deserialize_cdr(imu_raw[0], "sensor_msgs/msg/Imu")
    for covs in (("orientation_covariance",), ("angular_velocity_covariance",), ("linear_acceleration_covariance",),
                 ("angular_velocity_covariance", "linear_acceleration_covariance")):
        msg = imu
        for cov in covs:
            msg = _not_provided(msg, cov)
        imu_raw.append(store.serialize_cdr(msg, "sensor_msgs/msg/Imu"))
        imu_want.append(msg_to_imu(msg))
    assert any(np.isnan(want.quat).all() for want in imu_want) and any(np.isnan(w.accel).all() for w in imu_want)
    for got, want in zip(imu_samples(imu_raw), imu_want, strict=True):
        assert (got.stamp_ns, got.frame_id) == (want.stamp_ns, want.frame_id)
        assert all(np.array_equal(getattr(got, k), getattr(want, k), equal_nan=True) for k in IMU_FIELDS)  # bitwise
    # what they leave to rosbags and msg_to_imu: other byte orders and sizes, values msg_to_imu refuses
    nan_gyro = dataclasses.replace(imu, angular_velocity=dataclasses.replace(imu.angular_velocity, x=np.nan))
    odd = [store.serialize_cdr(imu, "sensor_msgs/msg/Imu", little_endian=False), imu_raw[0][:-8],
           imu_raw[0] + bytes(8), store.serialize_cdr(nan_gyro, "sensor_msgs/msg/Imu")]
    assert imu_samples(odd) == [None] * len(odd)
    with pytest.raises(MalformedMessageError):
        msg_to_imu(nan_gyro)
    cloud = next(m.data for m in read_raw(DEMO_BAG, [LIDAR_TOPIC]))
    big = store.serialize_cdr(store.deserialize_cdr(cloud, "sensor_msgs/msg/PointCloud2"),
                              "sensor_msgs/msg/PointCloud2", little_endian=False)
    assert [cloud_msg(c) for c in (big, cloud[:-8], cloud + bytes(8))] == [None] * 3


def test_estimate_sequence_is_estimate_frame_by_frame(model):
    rng = np.random.default_rng(7)
    stamps = [k * 100_000_000 for k in range(12)] + [3_500_000_000 + k * 100_000_000 for k in range(9)]  # a gap
    points = [rng.normal([8.0, 2.0, 1.0], 0.3, (int(rng.integers(0, 400)), 3)) for _ in stamps]
    rot = np.tile(np.eye(3), (len(stamps), 4, 1, 1))
    acc = rng.normal(0.0, 1.0, (len(stamps), 4, 3))
    one, many = PoseStage(model), PoseStage(model)
    want = [one.estimate(*frame)[0] for frame in zip(stamps, points, rot, acc, strict=True)]
    got = [p for cut in (slice(0, 5), slice(5, 15), slice(15, None))  # runs across calls and across the gap
           for p, _, _ in many.estimate_sequence(stamps[cut], points[cut], rot[cut], acc[cut])]
    assert one.sequences == many.sequences == 2
    for a, b in zip(want, got, strict=True):
        assert a.stamp_ns == b.stamp_ns
        for k in ("root_pos", "local_rot", "joint_pos"):
            np.testing.assert_allclose(getattr(b, k), getattr(a, k), rtol=0, atol=POSE_TOLERANCE)
    with pytest.raises(ValueError, match="pose_batch"):
        LipPipeline(model, pose_batch=0)
