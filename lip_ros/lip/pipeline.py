"""The LIP pipeline, ROS-free: Ouster frames and DOT samples in, poses in L out, frame by frame.

One object chains the stages for the batch tools and the evaluation (the node
graph runs the same stages, :mod:`lip_ros.lip.stages`, in separate nodes):
performer segmentation -> (until calibrated) the online A/T-pose calibration ->
IMU synchronisation at the moment the performer was scanned -> calibrated bone
orientations and free accelerations in L -> the streaming LIP network ->
forward kinematics. Every LiDAR frame comes out as a :class:`FrameResult`: a
pose, or the reason it has none (calibrating, no performer, IMUs missing).

Timing: a frame is processed once the IMUs cover its pose time
(``ImuSynchronizer.ready``), or once the other IMUs' data has gone
``SyncConfig.wait_ns`` past it (data time, :meth:`lip_ros.lip.stages.ImuStage.poll`),
or when ``max_pending_frames`` newer frames wait behind it; ``poll()`` is
called after each message and ``flush()`` at the end. Results come out in the
order the frames came in, frames without a pose included. Processing a frame
uses only data up to its pose time (the calibration sees the IMU samples
stamped up to it), so the results depend on the messages and their order
alone: a bag through this object and the live node graph
(``lip_ros.nodes``, which runs the same stages) give the same poses.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from lip_ros.core.imu_sync import ImuSampleLike, SyncConfig, SyncResult
from lip_ros.core.skeleton import Skeleton, load_skeleton
from lip_ros.lip.calibration import Calibration, CalibrationConfig
from lip_ros.lip.dot_latency import LatencyConfig
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.segmentation import PerformerSegmenter, SegmentationConfig, SegmentationResult, SegmentationStatus
from lip_ros.lip.stages import MAX_PENDING_FRAMES, MAX_SILENT_NS, BoneFrame, ImuStage, LipPose, Outcome, PoseStage

__all__ = ["PipelineConfig", "Outcome", "LipPose", "StageTimes", "FrameResult", "Segmenter", "LipPipeline"]


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of every stage; ``calibration_file`` is loaded at start if it exists and written when calibrated."""

    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    sync: SyncConfig = field(default_factory=SyncConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    calibration_file: Path | None = None
    max_pending_frames: int = MAX_PENDING_FRAMES  # frames waiting for IMU data; older ones are skipped with a reason
    latency: LatencyConfig = field(default_factory=LatencyConfig)  # the DOT latencies' online estimate
    max_silent_ns: int = MAX_SILENT_NS  # one silent DOT's bone held this long while the other three pose (0: skip)


@dataclass(frozen=True)
class StageTimes:
    """Processing time of one frame per stage (seconds of wall time)."""

    segmentation: float = 0.0
    sync_calibration: float = 0.0  # IMU interpolation, calibration attempts, equation 13
    network: float = 0.0  # with LipPipeline.pose_batch > 1: the frame's share of its group's forward
    kinematics: float = 0.0  # likewise

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

    @property
    def level(self) -> np.ndarray | None:
        """R_L_P: the gravity-aligned level frame in the LiDAR frame, None if not known (L taken as level)."""

    def process(self, points: np.ndarray, stamp_ns: int) -> SegmentationResult:
        """The performer in one organized frame."""


class LipPipeline:
    """Segmentation, then :class:`~lip_ros.lip.stages.ImuStage` and :class:`~lip_ros.lip.stages.PoseStage`, for one
    performer.

    ``pose_batch``: with 1 (live) every frame comes out as soon as it is processed; with more, frames from the
    first one with a pose on are held until ``pose_batch`` of them have a pose (or ``flush``), then go through
    the network in one forward (:meth:`~lip_ros.lip.stages.PoseStage.estimate_sequence`): the same results, in
    groups, for a fraction of the network's time (batch tools).
    """

    def __init__(
        self,
        model: LipModel,
        config: PipelineConfig | None = None,
        calibration: Calibration | None = None,
        skeleton: Skeleton | None = None,
        segmenter: Segmenter | None = None,
        pose_batch: int = 1,
    ) -> None:
        if pose_batch < 1:
            raise ValueError(f"pose_batch must be at least 1, not {pose_batch}")
        self.config = config or PipelineConfig()
        self.pose_batch = pose_batch
        self.skeleton = skeleton or load_skeleton()
        self.segmenter = segmenter or PerformerSegmenter(self.config.segmentation)
        self.imu = ImuStage(self.config.sync, self.config.calibration, self.skeleton, calibration,
                            self.config.calibration_file, self.config.max_pending_frames, self.config.latency,
                            self.config.max_silent_ns)
        self.poser = PoseStage(model, self.skeleton)
        self.imu_rejections: Counter[tuple[str, str]] = Counter()  # (sensor, reason) -> count
        self._held: list[BoneFrame] = []  # processed frames waiting for the network (pose_batch > 1)

    @property
    def model(self) -> LipModel:
        """The LIP network."""
        return self.poser.model

    @property
    def calibration(self) -> Calibration | None:
        """The calibration in use."""
        return self.imu.calibration

    @property
    def calibrated(self) -> bool:
        """Whether measurements can be turned into bone orientations in L."""
        return self.imu.calibrated

    @property
    def pending(self) -> int:
        """Frames segmented and waiting for IMU data that covers their pose time, or for the network."""
        return self.imu.pending + len(self._held)

    @property
    def calibration_status(self) -> str:
        """A one-line description of the calibration state."""
        return self.imu.status

    def add_imu(self, name: str, sample: ImuSampleLike) -> str | None:
        """One DOT sample (R_I_S, rate and specific force in S); why it was rejected, None if kept."""
        reason = self.imu.add_imu(name, sample)
        if reason is not None:
            self.imu_rejections[name, reason] += 1
        return reason

    def add_imus(self, names: Sequence[str], samples: Sequence[ImuSampleLike]) -> list[FrameResult]:
        """Samples in arrival order, each as ``add_imu`` followed by ``poll`` (the same results), validated
        together, which is cheaper; the frames that came out."""
        reasons, frames = self.imu.add_imus(names, samples)
        self.imu_rejections.update((name, reason) for name, reason in zip(names, reasons, strict=True)
                                   if reason is not None)
        return self._results(frames)

    def reject_imu(self, name: str, reason: str) -> None:
        """Account for an IMU message that could not be read at all."""
        self.imu_rejections[name, reason] += 1

    def skip(self, stamp_ns: int, reason: str) -> list[FrameResult]:
        """Account for a frame whose message could not be read at all; frames forced out now (as ``add_cloud``)."""
        return self._results(self.imu.add_unusable(stamp_ns, reason, (None, 0.0)))

    def add_cloud(self, points: np.ndarray, stamp_ns: int) -> list[FrameResult]:
        """One organized Ouster frame (H, W) ``original`` array; frames that cannot wait for IMU data come back now."""
        start = time.perf_counter()
        seg = self.segmenter.process(points, stamp_ns)
        self.imu.level = self.poser.level = self.segmenter.level
        tag = (seg, time.perf_counter() - start)
        if seg.status != SegmentationStatus.OK:
            return self._results(self.imu.add_unusable(stamp_ns, f"{seg.status.value}: {seg.reason}", tag))
        return self._results(self.imu.add_frame(stamp_ns, seg.pose_stamp_ns, seg.points, tag))

    def poll(self, now_ns: int | None = None) -> list[FrameResult]:
        """Process the waiting frames whose IMU data is complete (or waited for long enough, by default in data
        time: :meth:`lip_ros.lip.stages.ImuStage.poll`), in order."""
        return self._results(self.imu.poll(now_ns))

    def flush(self) -> list[FrameResult]:
        """Process every waiting frame (end of a bag)."""
        return self._results(self.imu.flush(), final=True)

    def _results(self, frames: list[BoneFrame], final: bool = False) -> list[FrameResult]:
        if self.pose_batch == 1:
            return [self._result(f, self._estimate(f)) for f in frames]
        self._held += frames
        first = next((k for k, f in enumerate(self._held) if f.outcome == Outcome.POSE), len(self._held))
        if not final and sum(f.outcome == Outcome.POSE for f in self._held) < self.pose_batch:
            out, self._held = self._held[:first], self._held[first:]  # the frames before the first pose go
            return [self._result(f) for f in out]
        out, self._held = self._held, []
        posed = [f for f in out if f.outcome == Outcome.POSE]
        poses = iter(self.poser.estimate_sequence([f.pose_stamp_ns for f in posed], [f.points for f in posed],
                                                  np.array([f.bone_rot for f in posed]),
                                                  np.array([f.free_acc for f in posed])))
        return [self._result(f, next(poses) if f.outcome == Outcome.POSE else None) for f in out]

    def _estimate(self, f: BoneFrame) -> tuple[LipPose, float, float] | None:
        if f.outcome != Outcome.POSE:
            return None
        return self.poser.estimate(f.pose_stamp_ns, f.points, f.bone_rot, f.free_acc)

    @staticmethod
    def _result(f: BoneFrame, estimate: tuple[LipPose, float, float] | None = None) -> FrameResult:
        seg, seg_s = f.tag
        if estimate is None:
            return FrameResult(f.frame_stamp_ns, f.outcome, f.reason, seg, f.sync,
                               timing=StageTimes(seg_s, f.seconds))
        pose, net_s, fk_s = estimate
        return FrameResult(f.frame_stamp_ns, Outcome.POSE, f.reason, seg, f.sync, pose,
                           StageTimes(seg_s, f.seconds, net_s, fk_s))
