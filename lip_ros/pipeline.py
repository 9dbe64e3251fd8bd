"""The LIP pipeline, ROS-free: Ouster frames and DOT samples in, poses in L out, frame by frame.

One object chains the core stages for the nodes and the batch tools alike:
performer segmentation -> (until calibrated) the online A/T-pose calibration ->
IMU synchronisation at the moment the performer was scanned -> calibrated bone
orientations and free accelerations in L -> the streaming LIP network ->
forward kinematics. Every LiDAR frame comes out as a :class:`FrameResult`: a
pose, or the reason it has none (calibrating, no performer, IMUs missing).

Timing: a frame is processed once the IMUs cover its pose time
(``ImuSynchronizer.ready``), so ``poll(now)`` is called with the receive time of
each message (the node's clock, or a bag's log time) and ``flush()`` at the end.
Results come out in the order the frames came in, frames without a pose
included. Processing a frame uses only data up to its pose time (the
calibration sees the IMU samples stamped up to it), so the results do not
depend on when ``poll`` is called: fed the same messages in the same order, a
bag and a live graph give the same results, and so does one ``flush()`` after
all messages (given room to wait: ``max_pending_frames``), as long as no frame
was forced out by ``SyncConfig.wait_ns`` while its IMU data was still on its way.
"""

from __future__ import annotations

import enum
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from lip_ros.core.calibration import (
    Calibration,
    CalibrationConfig,
    CalibrationDetector,
    load_calibration,
    save_calibration,
)
from lip_ros.core.imu_sync import FrameStatus, ImuSampleLike, ImuSynchronizer, SyncConfig, SyncResult
from lip_ros.core.segmentation import PerformerSegmenter, SegmentationConfig, SegmentationResult, SegmentationStatus
from lip_ros.core.skeleton import Skeleton, forward_kinematics, load_skeleton
from lip_ros.nets.config import IMU_NAMES
from lip_ros.nets.lip_model import LipModel

__all__ = ["PipelineConfig", "Outcome", "LipPose", "StageTimes", "FrameResult", "Segmenter", "LipPipeline"]


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of every stage; ``calibration_file`` is loaded at start if it exists and written when calibrated."""

    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    sync: SyncConfig = field(default_factory=SyncConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    calibration_file: Path | None = None
    max_pending_frames: int = 20  # frames waiting for IMU data; older ones are skipped with a reason


class Outcome(str, enum.Enum):
    """What became of a LiDAR frame."""

    POSE = "pose"  # a pose was estimated (possibly with held IMU values, see the reason)
    CALIBRATING = "calibrating"  # no calibration yet: the frame fed the calibration
    SKIPPED = "skipped"  # no pose: see the reason


@dataclass(frozen=True)
class LipPose:
    """The body in L at ``stamp_ns`` (frame stamp + mean point time)."""

    stamp_ns: int
    root_pos: np.ndarray  # (3,) pelvis position
    local_rot: np.ndarray  # (24, 3, 3), [0] = pelvis orientation
    glob_rot: np.ndarray  # (24, 3, 3) bone orientations
    joint_pos: np.ndarray  # (24, 3) joint positions (forward kinematics of the contract skeleton times body_scale)
    body_scale: float  # the network's estimate of the performer's size (contract skeleton = 1)


@dataclass(frozen=True)
class StageTimes:
    """Processing time of one frame per stage (seconds of wall time)."""

    segmentation: float = 0.0
    sync_calibration: float = 0.0  # IMU interpolation, calibration attempts, equation 13
    network: float = 0.0
    kinematics: float = 0.0

    @property
    def total(self) -> float:
        """All stages."""
        return self.segmentation + self.sync_calibration + self.network + self.kinematics


@dataclass(frozen=True)
class FrameResult:
    """One LiDAR frame's outcome."""

    frame_stamp_ns: int
    outcome: Outcome
    reason: str
    segmentation: SegmentationResult | None  # None when the message itself was unusable
    sync: SyncResult | None = None
    pose: LipPose | None = None
    timing: StageTimes = field(default_factory=StageTimes)


class Segmenter(Protocol):
    """What finds the performer in a frame (:class:`PerformerSegmenter`, or ground-truth labels in evaluation)."""

    def process(self, points: np.ndarray, stamp_ns: int) -> SegmentationResult:
        """The performer in one organized frame."""


@dataclass(frozen=True)
class _Waiting:
    """A frame waiting its turn: segmented (``seg``), or unusable (``seg`` None or not OK, see ``reason``)."""

    stamp_ns: int
    seg: SegmentationResult | None
    reason: str
    seconds: float  # segmentation time

    @property
    def pose_stamp_ns(self) -> int | None:
        return None if self.seg is None else self.seg.pose_stamp_ns


class LipPipeline:
    """Segmentation, calibration, sync and the network, for one performer."""

    def __init__(
        self,
        model: LipModel,
        config: PipelineConfig | None = None,
        calibration: Calibration | None = None,
        skeleton: Skeleton | None = None,
        segmenter: Segmenter | None = None,
    ) -> None:
        self.config = config or PipelineConfig()
        self.model = model
        self.skeleton = skeleton or load_skeleton()
        self.segmenter = segmenter or PerformerSegmenter(self.config.segmentation)
        self.sync = ImuSynchronizer(IMU_NAMES, self.config.sync)
        if calibration is None and self.config.calibration_file is not None and self.config.calibration_file.is_file():
            calibration = load_calibration(self.config.calibration_file)
        self.calibration = calibration
        self._detector = CalibrationDetector(self.skeleton, self.config.calibration)
        self._calibration_samples: list[tuple[str, ImuSampleLike]] = []  # kept, not yet shown to the detector
        self._pending: deque[_Waiting] = deque()
        self.imu_rejections: Counter[tuple[str, str]] = Counter()  # (sensor, reason) -> count
        self.model.reset()

    @property
    def calibrated(self) -> bool:
        """Whether measurements can be turned into bone orientations in L."""
        return self.calibration is not None

    @property
    def pending(self) -> int:
        """Frames segmented and waiting for IMU data that covers their pose time."""
        return len(self._pending)

    @property
    def calibration_status(self) -> str:
        """A one-line description of the calibration state."""
        if self.calibration is not None:
            return f"calibrated (heading from {self.calibration.heading_source})"
        return self._detector.status

    def add_imu(self, name: str, sample: ImuSampleLike) -> str | None:
        """One DOT sample (R_I_S, rate and specific force in S); why it was rejected, None if kept."""
        reason = self.sync.add(name, sample)
        if reason is not None:
            self.imu_rejections[name, reason] += 1
        elif self.calibration is None:
            self._calibration_samples.append((name, sample))
        return reason

    def reject_imu(self, name: str, reason: str) -> None:
        """Account for an IMU message that could not be read at all."""
        self.imu_rejections[name, reason] += 1

    def skip(self, stamp_ns: int, reason: str) -> list[FrameResult]:
        """Account for a frame whose message could not be read at all; frames forced out now (as ``add_cloud``)."""
        return self._enqueue(_Waiting(stamp_ns, None, reason, 0.0))

    def add_cloud(self, points: np.ndarray, stamp_ns: int) -> list[FrameResult]:
        """One organized Ouster frame (H, W) ``original`` array; frames that cannot wait for IMU data come back now."""
        start = time.perf_counter()
        seg = self.segmenter.process(points, stamp_ns)
        seconds = time.perf_counter() - start
        if seg.status != SegmentationStatus.OK:
            return self._enqueue(_Waiting(stamp_ns, seg, f"{seg.status.value}: {seg.reason}", seconds))
        if self.calibration is None:
            self._detector.add_cloud(seg.pose_stamp_ns, seg.points)
        return self._enqueue(_Waiting(stamp_ns, seg, "", seconds))

    def poll(self, now_ns: int) -> list[FrameResult]:
        """Process the waiting frames whose IMU data is complete (or waited for long enough), in order."""
        done = []
        while self._pending and self._ready(self._pending[0], now_ns):
            done.append(self._process(self._pending.popleft()))
        return done

    def flush(self) -> list[FrameResult]:
        """Process every waiting frame (end of a bag)."""
        done = [self._process(w) for w in self._pending]
        self._pending.clear()
        return done

    def _enqueue(self, waiting: _Waiting) -> list[FrameResult]:
        """Queue a frame behind the ones waiting for IMU data; the oldest beyond ``max_pending_frames`` give up."""
        self._pending.append(waiting)
        done = []
        while len(self._pending) > self.config.max_pending_frames:
            old = self._pending.popleft()
            if old.reason:
                done.append(self._process(old))
            else:
                done.append(FrameResult(old.stamp_ns, Outcome.SKIPPED, "IMU data did not arrive in time", old.seg,
                                        timing=StageTimes(segmentation=old.seconds)))
        return done

    def _ready(self, waiting: _Waiting, now_ns: int) -> bool:
        return bool(waiting.reason) or self.sync.ready(waiting.pose_stamp_ns, now_ns)

    def _try_calibrate(self, t_ns: int) -> None:
        """Show the detector the IMU samples stamped up to ``t_ns`` and try to calibrate."""
        later = []
        for name, sample in self._calibration_samples:
            if sample.stamp_ns <= t_ns:
                self._detector.add_imu(name, sample.stamp_ns, sample.quat, sample.gyro, sample.accel)
            else:
                later.append((name, sample))
        self._calibration_samples = later
        cal = self._detector.update()
        if cal is not None:
            self.calibration = cal
            self._calibration_samples = []
            if self.config.calibration_file is not None:
                save_calibration(cal, self.config.calibration_file)

    def _process(self, waiting: _Waiting) -> FrameResult:
        seg = waiting.seg
        if waiting.reason:
            return FrameResult(waiting.stamp_ns, Outcome.SKIPPED, waiting.reason, seg,
                               timing=StageTimes(segmentation=waiting.seconds))
        t = seg.pose_stamp_ns
        start = time.perf_counter()
        if self.calibration is None:
            self._try_calibrate(t)
            if self.calibration is None:
                timing = StageTimes(waiting.seconds, time.perf_counter() - start)
                return FrameResult(seg.stamp_ns, Outcome.CALIBRATING, self._detector.status, seg, timing=timing)
        synced = self.sync.query(t)
        if synced.frame_status == FrameStatus.SKIP:
            timing = StageTimes(waiting.seconds, time.perf_counter() - start)
            return FrameResult(seg.stamp_ns, Outcome.SKIPPED, f"IMU: {synced.reason}", seg, synced, timing=timing)
        rot, acc = zip(*(self.calibration.apply(n, synced.quat[i], synced.accel[i]) for i, n in enumerate(IMU_NAMES)))
        t_net = time.perf_counter()
        out = self.model.step(seg.points, np.stack(rot), np.stack(acc))
        t_fk = time.perf_counter()
        glob, pos = forward_kinematics(self.skeleton, out.local_rot, out.translation,
                                       self.skeleton.offsets * out.body_scale)
        pose = LipPose(t, out.translation, out.local_rot, glob, pos, float(out.body_scale))
        timing = StageTimes(waiting.seconds, t_net - start, t_fk - t_net, time.perf_counter() - t_fk)
        return FrameResult(seg.stamp_ns, Outcome.POSE, synced.reason, seg, synced, pose, timing)
