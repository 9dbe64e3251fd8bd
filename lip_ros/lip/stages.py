"""The stages of the LIP graph after segmentation, ROS-free: the IMU stage and the pose stage.

The node graph runs them in separate nodes (``calibration_node``, ``pose_node``)
and :class:`lip_ros.lip.pipeline.LipPipeline` chains them in one object for the
batch tools; both call the same code, so a bag gives the same poses either way.

* :class:`ImuStage` (IMU synchronisation + calibration): performer frames wait
  until the four DOTs cover their pose time (``ImuSynchronizer.ready``), then,
  in the order they came in, either feed the automatic A/T-pose calibration
  (until it is solved) or come out as calibrated bone orientations and free
  accelerations in L at the pose time (paper equations 13 and 16), or with the
  reason they cannot. A new calibration can be started (the current one stays
  in use until the new one is solved) or the calibration reset.
* :class:`PoseStage`: the streaming LIP network and the forward kinematics.

Both stages take and give everything in the LiDAR frame L, and work inside in
its level frame P (:func:`lip_ros.core.frames.level_rotation`: gravity-up z,
L's heading), which their ``level`` attribute gives as R_L_P once the ground
is known (None: L is taken as level). So a tilted sensor needs nothing else:
the calibration (and its file) is in P, gravity is P's -z, and the network
sees the level world it was trained on.
"""

from __future__ import annotations

import dataclasses
import enum
import itertools
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import wraps
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from lip_ros.core.clock import stepped_back
from lip_ros.core.frame_period import FramePeriod
from lip_ros.core.imu_sync import FrameStatus, ImuSampleLike, ImuSynchronizer, SensorStatus, SyncConfig, SyncResult
from lip_ros.core.rotations import matrix_to_quat, rot_z
from lip_ros.core.skeleton import Skeleton, forward_kinematics, load_skeleton
from lip_ros.lip.calibration import (
    Calibration,
    CalibrationConfig,
    CalibrationDetector,
    load_calibration,
    save_calibration,
)
from lip_ros.lip.dot_latency import LatencyConfig, LatencyEstimator
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.sensors import IMU_NAMES

__all__ = ["Outcome", "BoneFrame", "LipPose", "ImuStage", "PoseStage", "MAX_PENDING_FRAMES", "MAX_POSE_GAP_NS",
           "MAX_SILENT_NS", "CLOCKS_REASON", "CLOCK_STEP_REASON"]

#: Default of how many frames may wait for IMU data (``ImuStage.max_pending``); older ones are skipped.
MAX_PENDING_FRAMES = 20
#: Default of how long without a pose before the network starts a new sequence (``PoseStage.max_gap_ns``).
MAX_POSE_GAP_NS = 2_000_000_000
#: Default of how long one silent DOT's bone is held while the other three pose the frame (``ImuStage.max_silent_ns``).
MAX_SILENT_NS = 1_000_000_000

#: The start of the reason of a frame skipped because the clock stepped back while it waited.
CLOCK_STEP_REASON = "clock stepped back"
#: Why a frame gave up waiting for IMU data (more than ``max_pending`` frames behind it).
LATE_IMU_REASON = "IMU data did not arrive in time"
#: The start of the reason of a frame stamped on another clock than the IMU data (``SyncConfig.max_clock_gap_ns``).
CLOCKS_REASON = "clocks"


class Outcome(str, enum.Enum):
    """What became of a LiDAR frame."""

    POSE = "pose"  # a pose was estimated (possibly with held IMU values, see the reason)
    CALIBRATING = "calibrating"  # no calibration yet: the frame fed the calibration
    SKIPPED = "skipped"  # no pose: see the reason


@dataclass(frozen=True)
class BoneFrame:
    """The IMU side of one frame: bone orientations and free accelerations in L at its pose time, or why not.

    ``outcome`` is POSE when ``bone_rot`` / ``free_acc`` are there (order
    ``IMU_NAMES``); ``tag`` is whatever the caller queued with the frame. A
    bone whose DOT is silent (:attr:`ImuStage.max_silent_ns`) is held, not
    measured: its free acceleration is NaN (:attr:`held`).
    """

    frame_stamp_ns: int
    pose_stamp_ns: int | None
    outcome: Outcome
    reason: str
    points: np.ndarray | None = None  # (N, 3) performer points, as queued
    sync: SyncResult | None = None
    bone_rot: np.ndarray | None = None  # (4, 3, 3) R_L_B
    free_acc: np.ndarray | None = None  # (4, 3) m/s^2 in L, gravity removed
    seconds: float = 0.0  # synchronisation and calibration time
    tag: Any = None

    @property
    def held(self) -> np.ndarray:
        """(4,) bool: the bones held for a silent DOT rather than measured (none unless POSE)."""
        if self.free_acc is None:
            return np.zeros(len(IMU_NAMES), dtype=bool)
        return ~np.isfinite(self.free_acc).all(axis=-1)


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
class _Waiting:
    frame_stamp_ns: int
    pose_stamp_ns: int | None  # None: unusable frame, passing through in order (see reason)
    points: np.ndarray | None
    reason: str
    tag: Any


_Method = TypeVar("_Method", bound=Callable[..., Any])


def _scored_first(method: _Method) -> _Method:
    """An :class:`ImuStage` method that first scores the frames that came out before it (their DOT latency)."""
    @wraps(method)
    def scored_first(self: ImuStage, *args: Any, **kwargs: Any) -> Any:
        self.score_latency()
        return method(self, *args, **kwargs)
    return scored_first  # type: ignore[return-value]


class ImuStage:
    """IMU synchronisation and A/T-pose calibration for the performer frames, in their order.

    ``calibration_file``: loaded at start if it exists, written whenever a
    calibration is solved, removed by :meth:`reset`.

    The online DOT latency estimate scores each frame after its bones came out:
    that work waits until :meth:`score_latency`, which every method that takes
    data or frames calls first, so a caller can publish a frame's bones before
    it (off the frame's latency) and the results stay the same either way.

    One DOT silent (no sample within ``SyncConfig.max_hold_ns``) for at most
    ``max_silent_ns`` since it was last measured in a frame: the frame is
    posed with the other three, that bone held at its last measured
    orientation, turned about the vertical as the other bones turned since
    (the performer's heading), its acceleration unknown (NaN). Two or more
    silent, or one for longer (0: never held): the frame is skipped.
    """

    def __init__(
        self,
        sync: SyncConfig | None = None,
        calibration_config: CalibrationConfig | None = None,
        skeleton: Skeleton | None = None,
        calibration: Calibration | None = None,
        calibration_file: Path | None = None,
        max_pending: int = MAX_PENDING_FRAMES,
        latency: LatencyConfig | None = None,
        max_silent_ns: int = MAX_SILENT_NS,
    ) -> None:
        self.skeleton = skeleton or load_skeleton()
        if max_silent_ns < 0:
            raise ValueError(f"max_silent_ns must be >= 0, not {max_silent_ns}")
        self.max_silent_ns = max_silent_ns
        self.sync = ImuSynchronizer(IMU_NAMES, sync or SyncConfig())
        #: the DOT latencies' online estimate (None: the configured ones are kept), see :mod:`lip_ros.lip.dot_latency`
        latency = latency or LatencyConfig()
        self.latency = LatencyEstimator(config=latency) if latency.enabled else None
        self._bone_axis_in_b = {n: self._child_direction(self.skeleton.lip_imus[n]["bone_joint"]) for n in IMU_NAMES}
        self._calibration_config = calibration_config or CalibrationConfig()
        self.calibration_file = calibration_file
        self.max_pending = max_pending
        if calibration is None and calibration_file is not None and calibration_file.is_file():
            calibration = load_calibration(calibration_file)
        if calibration is not None and not calibration.complete:
            raise ValueError(f"the calibration does not know the inertial headings of "
                             f"{', '.join(calibration.heading_pending)} (it needs walking after the poses)")
        self.calibration = calibration
        self.level: np.ndarray | None = None  # R_L_P (3, 3), the level frame in L (None: L is level)
        #: Increases whenever the calibration changes (solved, reset): poses before and after do not chain.
        self.calibration_count = 0
        self._detector: CalibrationDetector | None = None
        # kept for the calibration, not yet shown to the detector (bounded like the detector's own buffers)
        self._calibration_samples: deque[tuple[str, ImuSampleLike]] = deque()  # (name, sample)
        self._pending: deque[_Waiting] = deque()
        self._last_pose_ns: int | None = None  # pose time of the newest frame
        self.clock_steps = 0  # how often the frames' stamps stepped back (lip_ros.core.clock)
        #: per DOT, the last frame it was interpolated in: (pose time, the bones (4, 3, 3) in P, which were measured)
        self._last_measured: dict[int, tuple[int, np.ndarray, np.ndarray]] = {}
        self._unscored: list[tuple[int, np.ndarray]] = []  # frames out, not yet scored for the DOT latency (pose
        #                                                    time, points in P): one, or a few of one poll
        if calibration is None:
            self.start_calibration()

    def _child_direction(self, joint: str) -> np.ndarray:
        """The unit direction of ``joint``'s bone (to its child) in the bone's own frame."""
        offset = self.skeleton.offsets[self.skeleton.children(self.skeleton.index(joint))[0]]
        return offset / np.linalg.norm(offset)

    @property
    def calibrated(self) -> bool:
        """Whether measurements can be turned into bone orientations in L."""
        return self.calibration is not None

    @property
    def latency_status(self) -> str:
        """Each DOT's latency taken off its stamps (ms), and whether it was estimated."""
        est = self.latency

        def one(name: str) -> str:
            ms = f"{name} {self.sync.latency_ns(name) * 1e-6:.0f}"
            if est is None:
                return ms
            if est.estimate_ns[name] is not None:
                return f"{ms} (estimated)"
            if est.frames[name] < est.config.min_frames:
                return f"{ms} (not estimated: {est.frames[name]} of {est.config.min_frames} frames scored)"
            return f"{ms} (not estimated: the limb has not moved enough)"

        return ", ".join(map(one, IMU_NAMES))

    @property
    def calibrating(self) -> bool:
        """Whether an A/T-pose calibration is being looked for (also while an older one is in use)."""
        return self._detector is not None

    @property
    def pending(self) -> int:
        """Frames waiting for IMU data that covers their pose time."""
        return len(self._pending)

    @property
    def calibration_samples(self) -> int:
        """IMU samples held for the calibration (not yet shown to its detector)."""
        return len(self._calibration_samples)

    @property
    def status(self) -> str:
        """A one-line description of the calibration state."""
        parts = []
        if self.calibration is not None:
            parts.append(f"calibrated (heading from {self.calibration.heading_source}; DOT headings: "
                         f"{self.calibration.headings})")
        if self._detector is not None:
            parts.append(("recalibrating: " if self.calibration is not None else "") + self._detector.status)
        return "; ".join(parts)

    @_scored_first
    def start_calibration(self) -> None:
        """Look for a new A-pose / T-pose from now on; a current calibration stays in use until it is solved."""
        self._detector = CalibrationDetector(self.skeleton, self._calibration_config)
        self._calibration_samples = deque(maxlen=len(IMU_NAMES) * self._detector.max_buffered)

    @_scored_first
    def reset(self) -> None:
        """Forget the calibration (and remove its file, so a restart does not resume it) and look for a new one."""
        self.calibration = None
        self.calibration_count += 1
        if self.calibration_file is not None:
            self.calibration_file.unlink(missing_ok=True)
        self.start_calibration()

    @_scored_first
    def add_imu(self, name: str, sample: ImuSampleLike) -> str | None:
        """One DOT sample (R_I_S, rate and specific force in S); why it was rejected, None if kept."""
        return self._keep(name, sample, self.sync.add(name, sample))

    @_scored_first
    def add_imus(self, names: Sequence[str], samples: Sequence[ImuSampleLike]
                 ) -> tuple[list[str | None], list[BoneFrame]]:
        """Samples in arrival order, each as :meth:`add_imu` followed by :meth:`poll` (the same results), validated
        together, which is cheaper; why each was rejected (None if kept), and the frames that came out."""
        rows, codes = self.sync.validate(samples)
        reasons, done = [], []
        for name, sample, row, code in zip(names, samples, rows, codes.tolist(), strict=True):
            self.score_latency()  # the frames the last sample let out, before this sample is kept
            reason = self._keep(name, sample, self.sync.insert(name, int(sample.stamp_ns), row, code))
            reasons.append(reason)
            if reason is None:  # a rejected sample changes nothing that makes a frame ready
                done += self.poll()
        return reasons, done

    def _keep(self, name: str, sample: ImuSampleLike, reason: str | None) -> str | None:
        """Remember a sample the synchroniser kept for the calibration, while one is being looked for; samples
        older than the detector's horizon are dropped (without performer frames nothing else would drop them)."""
        if reason is None and self._detector is not None:
            samples = self._calibration_samples
            samples.append((name, sample))
            oldest_ns = self.sync.measured_ns(name, int(sample.stamp_ns)) - int(self._detector.horizon_s * 1e9)
            while self.sync.measured_ns(samples[0][0], int(samples[0][1].stamp_ns)) < oldest_ns:
                samples.popleft()
        return reason

    @_scored_first
    def add_frame(self, frame_stamp_ns: int, pose_stamp_ns: int, points: np.ndarray, tag: Any = None
                  ) -> list[BoneFrame]:
        """Queue a frame with the performer's points (N, 3) in L; frames that cannot wait any longer come back now."""
        done = self._clock_stepped(pose_stamp_ns)
        if self._detector is not None:
            self._detector.add_cloud(pose_stamp_ns, points if self.level is None else points @ self.level)
        return done + self._enqueue(_Waiting(frame_stamp_ns, pose_stamp_ns, points, "", tag))

    def _clock_stepped(self, pose_stamp_ns: int) -> list[BoneFrame]:
        """If the frames' clock stepped back (:mod:`lip_ros.core.clock`): the frames waiting on the old time line,
        skipped, and a calibration being looked for started again (a solved one stays); else nothing."""
        step = stepped_back(pose_stamp_ns, self._last_pose_ns)
        self._last_pose_ns = pose_stamp_ns
        if not step:
            return []
        self.clock_steps += 1
        self._last_measured.clear()  # times of the old time line
        reason = f"{CLOCK_STEP_REASON} {step * 1e-9:.1f} s: the frame waited on the old time line"
        done = [BoneFrame(w.frame_stamp_ns, w.pose_stamp_ns, Outcome.SKIPPED, reason if w.pose_stamp_ns else w.reason,
                          w.points, tag=w.tag) for w in self._pending]
        self._pending.clear()
        if self._detector is not None:
            self.start_calibration()
        return done

    @_scored_first
    def add_unusable(self, frame_stamp_ns: int, reason: str, tag: Any = None) -> list[BoneFrame]:
        """Queue a frame without a performer, so that it comes out (SKIPPED) in order with the others."""
        return self._enqueue(_Waiting(frame_stamp_ns, None, None, reason, tag))

    @property
    def data_time_ns(self) -> int | None:
        """Stamp of the newest IMU sample of any sensor: how far the data has come."""
        newest = [t for t in map(self.sync.newest_ns, self.sync.names) if t is not None]
        return max(newest) if newest else None

    @_scored_first
    def poll(self, now_ns: int | None = None) -> list[BoneFrame]:
        """The waiting frames whose IMU data is complete, or waited for long enough, in order.

        How long a frame has waited is measured at ``now_ns``, by default the
        data time (:attr:`data_time_ns`): a sensor that lags behind the others
        by more than ``SyncConfig.wait_ns`` is given up on, while data that is
        late as a whole (transport, a busy machine) is waited for, up to
        ``max_pending`` frames; and the outcome depends on the data alone, not
        on when it is processed, live or from a bag.
        """
        if not self._pending:  # nothing waits: no need for the data time
            return []
        now_ns = self.data_time_ns if now_ns is None else now_ns
        if now_ns is None:
            return []
        done = []
        while self._pending:
            self.score_latency()  # the frame before may set a latency that this frame's readiness depends on
            if not self._ready(self._pending[0], now_ns):
                break
            done.append(self._process(self._pending.popleft()))
        return done

    @_scored_first
    def flush(self) -> list[BoneFrame]:
        """Every waiting frame (end of a bag), all scored."""
        done = []
        while self._pending:
            done.append(self._process(self._pending.popleft()))
            self.score_latency()
        return done

    def score_latency(self) -> None:
        """Score the frames that came out since the last call for the DOT latency estimate, and take each new
        estimate off its DOT's stamps (nothing without the estimate)."""
        while self._unscored:
            self._estimate_latency(*self._unscored.pop(0))

    def _enqueue(self, waiting: _Waiting) -> list[BoneFrame]:
        self._pending.append(waiting)
        done = []
        while len(self._pending) > self.max_pending:
            old = self._pending.popleft()
            if old.pose_stamp_ns is None:
                done.append(self._process(old))
            else:
                reason = self._clock_gap(old.pose_stamp_ns) or LATE_IMU_REASON
                done.append(BoneFrame(old.frame_stamp_ns, old.pose_stamp_ns, Outcome.SKIPPED, reason, old.points,
                                      tag=old.tag))
        return done

    def _ready(self, waiting: _Waiting, now_ns: int) -> bool:
        return waiting.pose_stamp_ns is None or self.sync.ready(waiting.pose_stamp_ns, now_ns)

    def _try_calibrate(self, t_ns: int) -> None:
        """Show the detector the IMU samples measured up to ``t_ns`` (stamps less latencies) and try to calibrate."""
        later = deque(maxlen=self._calibration_samples.maxlen)
        for name, sample in self._calibration_samples:
            measured_ns = self.sync.measured_ns(name, int(sample.stamp_ns))  # with the latency known now
            if measured_ns <= t_ns:
                self._detector.add_imu(name, measured_ns, sample.quat, sample.gyro, sample.accel)
            else:
                later.append((name, sample))
        self._calibration_samples = later
        cal = self._detector.update()
        if cal is not None:
            self.calibration = cal
            self.calibration_count += 1
            self._last_measured.clear()  # bones of another calibration
            self._detector = None
            self._calibration_samples.clear()
            if self.calibration_file is not None:
                save_calibration(cal, self.calibration_file)

    def _clock_gap(self, t_ns: int) -> str | None:
        """Why ``t_ns`` cannot be on the IMU data's clock (None if it can): too far outside the buffered samples."""
        span = self.sync.span_ns()
        if span is None:
            return None
        gap = min(t_ns - span[0], 0) + max(t_ns - span[1], 0)  # 0 inside the span, signed outside it
        if abs(gap) <= self.sync.config.max_clock_gap_ns:
            return None
        side = "newest" if gap > 0 else "oldest"
        return (f"{CLOCKS_REASON}: the LiDAR frame is stamped {gap * 1e-9:+.1f} s from the {side} DOT sample: the "
                "LiDAR and the DOTs stamp on different clocks (ouster-ros: timestamp_mode TIME_FROM_ROS_TIME, or PTP "
                "on both), or every DOT has been silent that long")

    def _process(self, w: _Waiting) -> BoneFrame:
        if w.pose_stamp_ns is None:
            return BoneFrame(w.frame_stamp_ns, None, Outcome.SKIPPED, w.reason, tag=w.tag)
        t = w.pose_stamp_ns
        start = time.perf_counter()
        clocks = self._clock_gap(t)
        if clocks is not None:  # before the calibration, which would wait for samples of this time for ever
            return BoneFrame(w.frame_stamp_ns, t, Outcome.SKIPPED, clocks, w.points,
                             seconds=time.perf_counter() - start, tag=w.tag)
        if self._detector is not None:
            self._try_calibrate(t)
        out = self._bones(w, t)
        if self.latency is not None and w.points is not None:  # after this frame's bones: it used the data as is
            self._unscored.append((t, w.points if self.level is None else w.points @ self.level))
        return dataclasses.replace(out, seconds=time.perf_counter() - start)

    def _bones(self, w: _Waiting, t: int) -> BoneFrame:
        """The calibrated bones of a frame at its pose time ``t``, or why not."""
        if self.calibration is None:
            return BoneFrame(w.frame_stamp_ns, t, Outcome.CALIBRATING, self._detector.status, w.points, tag=w.tag)
        synced = self.sync.query(t)
        measured = np.array([s != SensorStatus.MISSING for s in synced.status])
        silent = [IMU_NAMES[i] for i in np.flatnonzero(~measured)]
        if synced.frame_status == FrameStatus.SKIP and not self._holds(silent, t):
            return BoneFrame(w.frame_stamp_ns, t, Outcome.SKIPPED, f"IMU: {synced.reason}", w.points, synced,
                             tag=w.tag)
        rot, acc = np.full((len(IMU_NAMES), 3, 3), np.nan), np.full((len(IMU_NAMES), 3), np.nan)
        for i in np.flatnonzero(measured):  # in P, the calibration's frame
            rot[i], acc[i] = self.calibration.apply(IMU_NAMES[i], synced.quat[i], synced.accel[i])
        reason = synced.reason
        for name in silent:
            i = IMU_NAMES.index(name)
            rot[i] = self._held_bone(i, rot, measured)
            reason = f"{reason}; {name} silent {(t - self._last_measured[i][0]) * 1e-9:.1f} s: its bone held"
        for i, status in enumerate(synced.status):  # not a sample held by the synchroniser: it is older than t
            if status == SensorStatus.OK:
                self._last_measured[i] = (t, rot.copy(), measured)
        if self.level is not None:
            rot, acc = self.level @ rot, acc @ self.level.T
        return BoneFrame(w.frame_stamp_ns, t, Outcome.POSE, reason, w.points, synced, rot, acc, tag=w.tag)

    def _holds(self, silent: list[str], t: int) -> bool:
        """Whether a frame at ``t`` without ``silent`` DOTs is posed with their bones held: one DOT, measured in a
        frame at most ``max_silent_ns`` before."""
        if len(silent) != 1:
            return False
        last = self._last_measured.get(IMU_NAMES.index(silent[0]))
        return last is not None and 0 <= t - last[0] <= self.max_silent_ns

    def _held_bone(self, i: int, rot: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """Bone ``i``'s orientation in P as last measured, turned about the vertical by the mean turn of the bones
        measured both then and now (``rot`` (4, 3, 3), ``measured`` (4,))."""
        _, then, then_measured = self._last_measured[i]
        others = np.flatnonzero(measured & then_measured)
        if not others.size:
            return then[i]
        turn = matrix_to_quat(rot[others] @ np.swapaxes(then[others], -1, -2))
        yaw = 2.0 * np.arctan2(turn[:, 2], turn[:, 3])  # each bone's turn about z (swing-twist)
        return rot_z(np.arctan2(np.sin(yaw).sum(), np.cos(yaw).sum())) @ then[i]

    def _estimate_latency(self, t_ns: int, points: np.ndarray) -> None:
        """Once calibrated, score the frames up to ``t_ns`` (those seen while calibrating too, as far as the DOT
        data is still buffered) and take each new latency estimate off its DOT's stamps; then observe this frame's
        points (in P)."""
        if self.calibration is not None:
            for name, latency_ns in self.latency.update(t_ns, self._bone_axis).items():
                self.sync.set_latency(name, latency_ns)
        self.latency.observe(t_ns, points)

    def _bone_axis(self, name: str, stamps_ns: np.ndarray) -> np.ndarray:
        """The direction (T, 3) in P of ``name``'s bone at the DOT stamps ``stamps_ns``; all NaN unless all covered."""
        quat = self.sync.orientations(name, stamps_ns)
        if not np.isfinite(quat).all():
            return np.full((len(quat), 3), np.nan)
        rot, _ = self.calibration.apply(name, quat, np.zeros((len(quat), 3)))
        return rot @ self._bone_axis_in_b[name]


class PoseStage:
    """The streaming LIP network and forward kinematics: one frame's points and bones in, its pose out.

    After more than ``max_gap_ns`` without a pose (a calibration reset, the
    performer lost, IMUs missing), or when the stamps go back (a clock step),
    the network starts a new sequence: its recurrent state would describe a body
    long gone. The frames' period is measured from their stamps
    (:class:`lip_ros.core.frame_period.FramePeriod`): where it calls for another
    interleave than the model's (:meth:`LipModel.interleave_for`: a LiDAR at 20
    Hz given a model set for 10, or the reverse), the model is set for the
    measured rate (:meth:`LipModel.for_rate`) and a new sequence starts.
    """

    def __init__(self, model: LipModel, skeleton: Skeleton | None = None, max_gap_ns: int = MAX_POSE_GAP_NS) -> None:
        self.model = model
        self.skeleton = skeleton or load_skeleton()
        self.max_gap_ns = max_gap_ns
        self.level: np.ndarray | None = None  # R_L_P (3, 3), the level frame in L (None: L is level)
        self.sequences = 0  # sequences started (the first pose, then after each gap)
        self.period = FramePeriod()  # of the frames posed
        self._last_ns: int | None = None
        self.model.reset()

    def estimate(self, stamp_ns: int, points: np.ndarray, bone_rot: np.ndarray, free_acc: np.ndarray
                 ) -> tuple[LipPose, float, float]:
        """The pose at ``stamp_ns``, and the seconds spent in the network and in the kinematics; a bone whose
        free acceleration is NaN is held for a silent DOT (:class:`BoneFrame`): the network's input, not a
        measurement the output is kept near."""
        return self.estimate_sequence([stamp_ns], [points], bone_rot[None], free_acc[None])[0]

    def estimate_sequence(self, stamps_ns: Sequence[int], points: Sequence[np.ndarray], bone_rot: np.ndarray,
                          free_acc: np.ndarray) -> list[tuple[LipPose, float, float]]:
        """The poses of several frames in turn (as :meth:`estimate` of each, up to float rounding, with the same
        new sequences), with one network forward per run of frames without a gap and the kinematics of all
        frames at once; the seconds are each frame's share."""
        if not len(stamps_ns):
            return []
        start = time.perf_counter()
        new = set()  # frames that start a new sequence
        rates = {}  # frame -> the measured rate the model is set for from that frame on
        last, interleave = self._last_ns, self.model.interleave
        for k, stamp_ns in enumerate(stamps_ns):
            if last is None or not 0 < stamp_ns - last <= self.max_gap_ns:  # a gap, or the clock stepped back
                new.add(k)
            last = stamp_ns
            self.period.add(stamp_ns)
            rate = self.period.rate_hz
            if rate is not None and (measured := self.model.interleave_for(rate)) != interleave:
                rates[k], interleave = rate, measured
                new.add(k)
        level = self.level
        if level is not None:  # into P, where the network works
            points = [(p @ level).astype(p.dtype) for p in points]
            bone_rot, free_acc = level.T @ bone_rot, free_acc @ level
        outs = []
        for a, b in itertools.pairwise(sorted({0, *new, len(stamps_ns)})):
            if a in rates:
                self.model = self.model.for_rate(rates[a])
            if a in new:
                self.model.reset()
                self.sequences += 1
            outs.append(self.model.stream(points[a:b], bone_rot[a:b], free_acc[a:b]))
        self._last_ns = stamps_ns[-1]
        rot, trans, scale = (np.concatenate([getattr(o, k) for o in outs]) for k in ("local_rot", "translation",
                                                                                      "body_scale"))
        if level is not None:  # the root back into L; the kinematics then give every joint in L
            rot[:, 0], trans = level @ rot[:, 0], trans @ level.T
        t_fk = time.perf_counter()
        glob, pos = forward_kinematics(self.skeleton, rot, trans, self.skeleton.offsets * scale[:, None, None])
        net_s, fk_s = (t_fk - start) / len(rot), (time.perf_counter() - t_fk) / len(rot)
        return [(LipPose(int(t), trans[k], rot[k], glob[k], pos[k], float(scale[k])), net_s, fk_s)
                for k, t in enumerate(stamps_ns)]
