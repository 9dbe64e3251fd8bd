"""Record a synthetic capture as a rosbag2 MCAP bag, with the contract's topics and a ground-truth sidecar.

Topics: ``/ouster/points`` (PointCloud2, Ouster ``original``), ``/dot/<imu>/imu``
(Imu), ``/gt/root_pose``, ``/gt/joint_poses``, ``/gt/joint_states``. Messages
are CDR-serialised with the rosbags Jazzy typestore and written in receive
(log) time order: a cloud is received when its sweep ends, an IMU sample a
Bluetooth latency after its measurement, ground truth at its own stamp.

Sidecars in the bag directory (ignored by ``ros2 bag``):
``rig_truth.yaml`` (configuration, calibration truth, phases) and
``rig_labels.npz`` (per frame: stamps and which pixels are the performer or another person).
"""

from __future__ import annotations

import heapq
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from lip_msgs_py import RosbagsBackend, array_to_cloud, imu_to_msg
from lip_ros.bagio import RELIABLE_QOS, SENSOR_QOS, mcap_writer
from lip_ros.lip.sensors import LIDAR_TOPIC
from lip_ros.outputs import GT_TOPICS, pose_messages
from lip_ros.rig.capture import CaptureFrame, CaptureSession

__all__ = ["write_capture_bag", "LogOrderWriter", "Progress", "TRUTH_FILE", "LABELS_FILE"]

TRUTH_FILE = "rig_truth.yaml"
LABELS_FILE = "rig_labels.npz"
LIDAR_FRAME = "os_lidar"
IMU_LATENCY_NS = 20_000_000  # Bluetooth LE delivery of a DOT sample
CLOUD_LATENCY_NS = 2_000_000  # driver time after the sweep ends


def _truth_sidecar(session: CaptureSession) -> dict[str, Any]:
    m = session.motion
    return {
        "generator": "lip_ros.rig",
        "config": session.config.as_dict(),
        "epoch_ns": session.epoch_ns,
        "lidar": {"frame_id": LIDAR_FRAME, "beams": session.lidar.beams, "columns": session.lidar.columns,
                  "rate_hz": session.lidar.rate_hz, "height_m": session.config.lidar_height_m,
                  "R_S_L": session.lidar_rotation.tolist()},  # L in the level world S (tilt)
        "performer": {"scenario": m.scenario,
                      "body_scale": m.skeleton.scale,
                      "proportions": dict(session.draw.proportions),
                      "girth": session.girth, "torso_girth": session.body.torso_girth,
                      "limb_girth": session.body.limb_girth, "pelvis_height_m": float(m.skeleton.pelvis_height)},
        "phases": [{"name": n, "start_ns": a, "end_ns": b} for n, a, b in session.phases_ns()],
        "imu_calibration": session.imu_calibration(),
    }


class Progress:
    """A one-line progress counter on stderr."""

    def __init__(self, total: int, label: str, enabled: bool) -> None:
        self.total, self.label, self.enabled = total, label, enabled

    def __call__(self, done: int) -> None:
        if self.enabled and (done == self.total or done % 10 == 0):
            end = "\n" if done == self.total else ""
            print(f"\r{self.label}: {done}/{self.total} frames", end=end, file=sys.stderr, flush=True)


class LogOrderWriter:
    """Messages pushed with their receive (log) time, written to an open MCAP writer in log-time order once
    :meth:`flush` says nothing earlier can come; ``/gt/`` topics reliable, the others sensor QoS."""

    def __init__(self, writer: Any, backend: RosbagsBackend) -> None:
        self._writer, self._backend = writer, backend
        self._pending: list[tuple[int, int, str, Any, str]] = []  # (log time, sequence, topic, message, type)
        self._seq = 0
        self._conns: dict[str, Any] = {}
        #: messages written, per topic
        self.counts: dict[str, int] = {}

    def push(self, log_ns: int, topic: str, msg: Any, msgtype: str) -> None:
        """Queue one message."""
        heapq.heappush(self._pending, (log_ns, self._seq, topic, msg, msgtype))
        self._seq += 1

    def flush(self, before_ns: int | None = None) -> None:
        """Write the queued messages logged before ``before_ns`` (all of them if None)."""
        while self._pending and (before_ns is None or self._pending[0][0] < before_ns):
            log_ns, _, topic, msg, msgtype = heapq.heappop(self._pending)
            if topic not in self._conns:
                qos = RELIABLE_QOS if topic.startswith("/gt/") else SENSOR_QOS
                self._conns[topic] = self._writer.add_connection(topic, msgtype, typestore=self._backend.typestore,
                                                                 offered_qos_profiles=[qos])
            self._writer.write(self._conns[topic], log_ns, self._backend.serialize(msg, msgtype))
            self.counts[topic] = self.counts.get(topic, 0) + 1


def write_capture_bag(
    session: CaptureSession,
    out: Path,
    progress: bool = True,
    on_frame: Callable[[CaptureFrame], None] | None = None,
) -> dict[str, int]:
    """Simulate ``session`` and record it to the bag directory ``out`` (must not exist); message counts per topic."""
    out = Path(out)
    backend = RosbagsBackend()
    skeleton = session.motion.skeleton
    labels_idx: list[np.ndarray] = []
    labels_actor: list[np.ndarray] = []
    stamps: list[int] = []
    truth_stamps: list[int] = []
    report = Progress(session.num_frames, f"lip_rig {out.name}", progress)
    with mcap_writer(out, zstd=True) as writer:
        log = LogOrderWriter(writer, backend)
        for s in session.imu_streams().values():
            for sample in s.samples(f"dot_{s.name}"):
                log.push(sample.stamp_ns + IMU_LATENCY_NS, s.topic, imu_to_msg(backend, sample), "sensor_msgs/msg/Imu")
        period = session.lidar.period_ns
        for cf in session.frames():
            stamp = cf.stamp_ns
            cloud = array_to_cloud(backend, cf.frame.points, stamp, LIDAR_FRAME)
            log.push(stamp + period + CLOUD_LATENCY_NS, LIDAR_TOPIC, cloud, "sensor_msgs/msg/PointCloud2")
            gt = cf.truth
            for topic, (msgtype, msg) in pose_messages(backend, GT_TOPICS, skeleton, gt.stamp_ns, LIDAR_FRAME,
                                                       gt.local_rot, gt.glob_rot, gt.joint_pos).items():
                log.push(gt.stamp_ns, topic, msg, msgtype)
            flat = np.flatnonzero(cf.frame.labels.ravel() >= 0)
            labels_idx.append(flat.astype(np.int32))
            labels_actor.append(cf.frame.labels.ravel()[flat].astype(np.int8))
            stamps.append(stamp)
            truth_stamps.append(cf.truth.stamp_ns)
            log.flush(stamp + period)  # everything of later frames is logged after the next frame starts
            report(cf.index + 1)
            if on_frame is not None:
                on_frame(cf)
        log.flush()
        counts = log.counts

    offsets = np.concatenate([[0], np.cumsum([len(i) for i in labels_idx])]).astype(np.int64)
    np.savez_compressed(
        out / LABELS_FILE,
        frame_stamp_ns=np.array(stamps, dtype=np.int64),
        truth_stamp_ns=np.array(truth_stamps, dtype=np.int64),
        shape=np.array(session.lidar.shape, dtype=np.int64),
        offsets=offsets,
        pixel=np.concatenate(labels_idx) if labels_idx else np.zeros(0, np.int32),
        actor=np.concatenate(labels_actor) if labels_actor else np.zeros(0, np.int8),
    )
    with open(out / TRUTH_FILE, "w", encoding="utf-8") as f:
        yaml.safe_dump(_truth_sidecar(session), f, sort_keys=False)
    return counts
