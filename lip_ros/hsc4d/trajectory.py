"""The HSC4D branch's pelvis trajectory, live: jump sync, LiDAR odometry with the suit, the ``map`` frame and the
pose graph, in one object the nodes and the batch tools share (ROS-free).

:class:`TrajectoryPipeline` takes the suit's pelvis IMU
(:meth:`~TrajectoryPipeline.add_pelvis_imu`), the suit's own odometry
(:meth:`~TrajectoryPipeline.add_suit_odometry`) and the hip LiDAR's sweeps
(:meth:`~TrajectoryPipeline.add_sweep`), each on its own clock, and:

1. **until the jump** has been seen by both (:mod:`~lip_ros.hsc4d.jump_sync`;
   the LiDAR's height from each sweep's ground alone,
   :mod:`~lip_ros.hsc4d.sweep_height`), holds the sweeps (at most ``hold_s``;
   older ones are dropped and counted) and outputs nothing;
2. once the suit's clock offset is known, registers the held sweeps and then
   each new one (:mod:`~lip_ros.hsc4d.lidar_odometry` with the pelvis IMU's
   rotation and the suit's motion, whose speed rule marks the registrations not
   believed);
3. after ``map_after_s`` of registered capture (the still A-pose), fixes the
   ``map`` frame from the ground under the wearer (:mod:`~lip_ros.hsc4d.map_frame`),
   levels the mounting with it (:func:`~lip_ros.hsc4d.mount.levelled_mount_rotation`:
   the ground's up in the LiDAR against the suit's in the pelvis) and from then
   on keeps the odometry's tilt on the suit's gravity; while walking, turns the
   mounting about the body's axis as the LiDAR's steps show
   (:class:`~lip_ros.hsc4d.mount.MountYawEstimator`) and moves its lever arm
   as the LiDAR's motion over the body's turns shows
   (:class:`~lip_ros.hsc4d.mount.LeverArmEstimator`), and checks the
   levelled mounting against the walk's turns
   (:class:`~lip_ros.hsc4d.mount.MountRotationEstimator`; :attr:`~TrajectoryPipeline.status`
   says when they disagree);
4. fuses each sweep in the live pose graph (:mod:`~lip_ros.hsc4d.pose_graph`):
   the believed registrations as landmarks, the suit's motion between sweeps
   as between factors, with the odometry's vertical (the suit knows no
   stairs) and its horizontal scaled by the suit's stride-scale error
   (:class:`StrideScale`: the believed registrations' horizontal motion along
   the suit's steps over the suit's path, on the level, over the last
   ``scale_window_s``).

Every output is the pelvis pose at the sweep's reference time (the middle of
its points' times) on the LiDAR's clock, in ``map``. The caller puts each
output's points in the map of the whole site (:meth:`~TrajectoryPipeline.add_to_map`,
a :class:`~lip_ros.hsc4d.site_map.SiteMap` placed by the live odometry: S_live),
after it used the output, off its latency. :meth:`~TrajectoryPipeline.refine`
solves the whole capture's graph at once (the offline refinement's trajectory).
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from lip_ros.core.frames import UP_M
from lip_ros.core.imu_sync import ImuSampleLike
from lip_ros.core.metrics import align_yaw_translation
from lip_ros.core.rotations import axis_angle_to_matrix
from lip_ros.hsc4d.gyro_bias import GyroBiasConfig
from lip_ros.hsc4d.jump_sync import JumpSync, JumpSyncConfig
from lip_ros.hsc4d.lidar_odometry import LidarOdometry, OdometryConfig, WearerFilter
from lip_ros.hsc4d.map_frame import MapFrame, MapFrameConfig, estimate_map_frame
from lip_ros.hsc4d.mount import (
    HipMountPrior,
    LeverArmEstimator,
    MountRotationEstimator,
    MountYawEstimator,
    SideCheck,
    SideCheckConfig,
    SpinCheck,
    SpinCheckConfig,
    levelled_mount_rotation,
)
from lip_ros.hsc4d.pelvis_rotation import PelvisRotation
from lip_ros.hsc4d.pose_graph import LiveTrajectoryGraph, PoseGraphConfig, fuse_batch
from lip_ros.hsc4d.resume import TrajectoryResume
from lip_ros.hsc4d.sensors import SUIT_RATE_HZ
from lip_ros.hsc4d.site_map import SiteMap, SiteMapConfig
from lip_ros.hsc4d.suit_track import SuitTrack, axes_columns, odometry_axes
from lip_ros.hsc4d.sweep_height import SweepHeightConfig, sweep_height

__all__ = ["TrajectoryConfig", "TrajectoryStep", "StrideScale", "TrajectoryPipeline", "RATE_CAPPED", "RESUME_WAITS",
           "PINNED"]

#: :attr:`TrajectoryPipeline.counts` key of the sweeps the odometry posed by the suit's motion under its rate cap
RATE_CAPPED = "sweeps posed by the suit's motion (registration rate cap)"
#: ... and of the sweeps a resumed trajectory dropped before the suit's samples covered one (no prediction)
RESUME_WAITS = "sweeps dropped: resumed, before the suit's pose"
#: ... and of the registrations (believed or not) that kept the prediction's shift along a direction the sweep does
#: not pin down at all (OdometryStep.least_shift_information under OdometryConfig.pinned_information[0]: an open
#: field's, or a sweep of too few points to tell)
PINNED = "registrations that kept the prediction's shift along a direction the sweep does not pin down"
#: the suit world's heading in map (for a resume) is fitted on the paths of the last this many seconds of outputs
_HEADING_FIT_S = 3.0
#: ... if the suit walked this far in them (else from the pelvis orientations)
_HEADING_MIN_PATH_M = 0.5


@dataclass(frozen=True)
class TrajectoryConfig:
    """Every stage's settings."""

    mount: HipMountPrior = HipMountPrior()
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    graph: PoseGraphConfig = field(default_factory=PoseGraphConfig)
    map_frame: MapFrameConfig = field(default_factory=MapFrameConfig)
    sweep_height: SweepHeightConfig = field(default_factory=SweepHeightConfig)
    jump: JumpSyncConfig = field(default_factory=JumpSyncConfig)
    site_map: SiteMapConfig = field(default_factory=SiteMapConfig)
    spin_check: SpinCheckConfig = field(default_factory=SpinCheckConfig)
    side_check: SideCheckConfig = field(default_factory=SideCheckConfig)
    gyro_bias: GyroBiasConfig = field(default_factory=GyroBiasConfig)  # the pelvis gyro's, from still runs
    check_mount: bool = True  # find the sensor's spin from the first sweeps (False: the mounting as given)
    check_hip: bool = True  # ... and, with check_mount, its hip from the wearer's body in them (docs/hsc4d/
    #                         trajectory.md "Rig variants: the other hip")
    hold_s: float = 15.0  # sweeps held while waiting for the jump (about 0.8 MB each at 1024 x 64)
    map_after_s: float = 1.0  # registered capture before the map frame is fixed (the wearer stands still)
    scale_window_s: float = 20.0  # the suit's stride scale is measured over this much level walking whose
    #                               registrations were believed and kept their shifts
    scale_min_path_m: float = 5.0  # ... once the suit has walked this far in it (1 before)
    max_scale_error: float = 0.2  # the scale is kept within 1 -+ this
    scale_max_grade: float = 0.04  # ... from the steps where the pelvis rose or fell less than this of the path (rig:
    #   the suit strides 3 % longer on its stairs than on the level)
    scale_grade_window_s: float = 1.0  # ... over this long, centred on the step (a stride: the pelvis's bob cancels)
    record_s: float = 3600.0  # each sweep's factors kept this long for the offline refinement (256 B a sweep)
    seed: int = 0  # of the RANSAC fits
    suit_rate_hz: float = SUIT_RATE_HZ  # samples per second of each suit stream, to size its buffers
    # the walk's turns (hand-eye rotations) putting the body's axis farther than this from the levelled mounting's
    # say the ground at the start was not level (or the mounting moved): the status says so (measured 0.1-1.2 deg
    # on rig captures whose start is level)
    max_mount_disagreement_deg: float = 3.0
    # fewer than this share of the registrations of the last ``believed_window_s`` believed says the LiDAR's motion
    # disagrees with the suit's through the mounting (a spin or tilt far from the nominal) or the scene holds ICP
    # badly: the status says so (rig captures: all but a few in a capture believed; a sensor spun 180 deg about its
    # axis with the spin check off: under half)
    min_believed_share: float = 0.5
    believed_window_s: float = 5.0
    # the suit's odometry putting the pelvis's up farther than this from its pelvis IMU's at the start says its
    # orientation is not the pelvis segment's in the contract's model axes: the status says so (the rig's: under 1
    # deg, the IMU's tilt error)
    max_odometry_tilt_deg: float = 10.0

    @property
    def suit_capacity(self) -> int:
        """Suit samples to keep per stream: the sweeps held until the jump need theirs, across the clock offset."""
        return int(np.ceil((self.hold_s + self.jump.max_offset_s + 5.0) * self.suit_rate_hz))

    def __post_init__(self) -> None:
        if not (self.hold_s > 0.0 and self.map_after_s >= 0.0 and self.record_s > 0.0 and self.scale_window_s > 0.0
                and self.scale_min_path_m > 0.0 and 0.0 <= self.max_scale_error < 1.0 and self.scale_max_grade > 0.0
                and self.scale_grade_window_s > 0.0 and self.suit_rate_hz > 0.0
                and self.max_mount_disagreement_deg > 0.0 and 0.0 <= self.min_believed_share <= 1.0
                and self.believed_window_s > 0.0 and self.max_odometry_tilt_deg > 0.0):
            raise ValueError(f"invalid {self}")


@dataclass(frozen=True)
class TrajectoryStep:
    """One sweep's output: its reference time (LiDAR clock), the fused pelvis pose T_map_P, the odometry's sensor
    pose T_map_L and the pelvis the odometry alone places through the mounting as it then stood (4, 4) each, why
    the sweep has no LiDAR pose of its own ("" if registered and believed; ``NOT_REGISTERED`` if posed by the suit's
    motion under the odometry's rate cap), how far the registration moved the
    initial guess (m), how many points it registered, the stamp the sweep was given to
    :meth:`TrajectoryPipeline.add_sweep` with, and its points deskewed to the reference time in L (M, 3), the
    wearer's removed."""

    stamp_ns: int
    pelvis: np.ndarray
    lidar: np.ndarray
    lidar_pelvis: np.ndarray
    rejected: str
    correction_m: float
    source_points: int
    sweep_ns: int
    points: np.ndarray


class _Step(NamedTuple):
    """One believed step, for :class:`StrideScale`."""

    stamp_ns: int
    along_m: float  # the LiDAR's horizontal motion along the suit's step
    suit_m: float  # the suit's horizontal step
    path_m: float  # the LiDAR's horizontal step
    rise_m: float  # the pelvis's rise, along gravity
    kept: bool  # the registration kept its own shifts


class StrideScale:
    """The suit's stride scale against the LiDAR, over the level walking of a sliding window of ``window_s``
    seconds: the registered steps' horizontal motion (in the pelvis frame: its x and z) along the suit's steps,
    over the suit's path; 1 until the suit first walked ``min_path_m`` in it, then the last value while it has
    less; kept within 1 -+ ``max_error``.

    A step counts once the ``grade_window_s`` centred on it is known, if the wearer rose or fell less than
    ``max_grade`` of the horizontal path over it (a suit that knows no stairs or slopes strides differently on
    them, docs/hsc4d/trajectory.md) and its registration kept its own shifts (one held to the prediction only
    repeats the scale in use). The motion along the suit's step, not its length: the length of each sweep's
    noisy step is biased long. Steps with a non-finite value are left out."""

    def __init__(self, window_s: float, min_path_m: float, max_error: float, max_grade: float,
                 grade_window_s: float) -> None:
        self.window_ns, self.min_path_m, self.max_error = int(window_s * 1e9), min_path_m, max_error
        self.max_grade, self.grade_half_ns = max_grade, int(grade_window_s * 0.5e9)
        self._past: deque[_Step] = deque()  # judged steps of the last half window
        self._recent: deque[_Step] = deque()  # steps waiting for the half window after them
        self._counted: deque[_Step] = deque()
        self._lidar = self._suit = 0.0
        self.value = 1.0

    def add(self, stamp_ns: int, lidar_step: np.ndarray, suit_step: np.ndarray, rise_m: float, kept: bool
            ) -> float:
        """One believed step's T_Pprev_P by the LiDAR and by the suit, the pelvis's rise over it along gravity,
        whether its registration ``kept`` its own shifts; the scale now (LiDAR per suit)."""
        suit = float(np.hypot(suit_step[0, 3], suit_step[2, 3]))
        along = float(lidar_step[0, 3] * suit_step[0, 3] + lidar_step[2, 3] * suit_step[2, 3]) / max(suit, 1e-9)
        step = _Step(int(stamp_ns), along, suit, float(np.hypot(lidar_step[0, 3], lidar_step[2, 3])), float(rise_m),
                     kept)
        if not np.isfinite(step[1:5]).all():
            return self.value
        self._recent.append(step)
        while self._recent[-1].stamp_ns - self._recent[0].stamp_ns > self.grade_half_ns:
            self._judge(self._recent.popleft())
        return self.value

    def _judge(self, step: _Step) -> None:
        """Count ``step``, whose half windows before and after are known, if it was level and kept."""
        while self._past and self._past[0].stamp_ns < step.stamp_ns - self.grade_half_ns:
            self._past.popleft()
        near = [*self._past, step, *(s for s in self._recent if s.stamp_ns - step.stamp_ns <= self.grade_half_ns)]
        self._past.append(step)
        rise, path = abs(sum(s.rise_m for s in near)), sum(s.path_m for s in near)
        if not step.kept or rise > self.max_grade * path:
            return
        self._counted.append(step)
        self._lidar += step.along_m
        self._suit += step.suit_m
        while self._counted[0].stamp_ns < step.stamp_ns - self.window_ns:
            old = self._counted.popleft()
            self._lidar -= old.along_m
            self._suit -= old.suit_m
        if self._suit >= self.min_path_m:
            self.value = float(np.clip(self._lidar / self._suit, 1.0 - self.max_error, 1.0 + self.max_error))


@dataclass(frozen=True)
class _Registered:
    stamp_ns: int
    T_O_L: np.ndarray
    T_O_P: np.ndarray
    fused_T_O_P: np.ndarray
    rejected: str
    correction_m: float
    source_points: int
    sweep_ns: int
    points: np.ndarray


class TrajectoryPipeline:
    """The live trajectory; inputs in any interleaving, each stream in its own time order."""

    def __init__(self, config: TrajectoryConfig | None = None) -> None:
        c = self.config = config or TrajectoryConfig()
        capacity = c.suit_capacity
        self.rotation = PelvisRotation(c.mount.R_M_L, capacity=capacity, bias=c.gyro_bias)
        self.suit = SuitTrack(c.mount, capacity=capacity)
        self.jump = JumpSync(c.jump)
        self.odometry = LidarOdometry(c.odometry, WearerFilter(c.mount.T_M_L))
        self.graph = LiveTrajectoryGraph(c.graph)
        self.stride_scale = StrideScale(c.scale_window_s, c.scale_min_path_m, c.max_scale_error, c.scale_max_grade,
                                        c.scale_grade_window_s)
        self.map_frame: MapFrame | None = None
        self.mount_levelled_deg = float("nan")  #: how far levelling turned the nominal mounting
        self.odometry_tilt_deg = float("nan")  #: the suit odometry's pelvis up from its pelvis IMU's at the start
        self.odometry_axes: np.ndarray | None = None  #: the pelvis's axes in the odometry's, if it uses others
        self.mount_yaw = MountYawEstimator()
        self.mount_yaw_deg = 0.0  #: how far walking turned it since, about the body's axis
        self.lever = LeverArmEstimator(c.mount.lever_m)
        self.hand_eye = MountRotationEstimator()  #: the mounting from the walk's turns, a check on the levelled one
        self.spin = SpinCheck(c.mount, c.spin_check, c.seed)  #: the sensor's spin from the ground of the first sweeps
        self.side = SideCheck(c.mount, c.side_check)  #: the hip it is worn on from the wearer's body in them
        if not c.check_mount:
            self.spin.skip("as configured (not checked: check_mount false)")
        if not (c.check_mount and c.check_hip):
            self.side.skip(f"as configured (not checked: check_mount{'_hip' if c.check_mount else ''} false)")
        self.site = SiteMap(c.site_map)  #: the whole site, placed by the live odometry (S_live)
        self.mapped = 0  #: steps put in the site map
        self.counts: Counter[str] = Counter()
        self._rng = np.random.default_rng(c.seed)
        self._held: deque[tuple[np.ndarray, np.ndarray, int]] = deque()
        self._pending: deque[_Registered] = deque()  # registered before the map frame was fixed
        self._recent: deque[tuple[int, bool]] = deque()  # (stamp, believed) of the registrations of the last
        #   believed_window_s
        self._first: _Registered | None = None
        self._last_ns: int | None = None
        self._last_out: tuple[int, np.ndarray] | None = None  # the last output's stamp and fused T_map_P
        self._resume: TrajectoryResume | None = None  # to start from at the first sweep
        self._paths: deque[tuple[int, np.ndarray, np.ndarray]] = deque(maxlen=int(_HEADING_FIT_S * 20.0))  # the
        #   outputs' (stamp, pelvis position in map, the suit's own in its world), at up to 20 Hz
        self._T_M_L, self._T_L_M = c.mount.T_M_L, c.mount.T_L_M
        records = int(c.record_s * 20.0)  # at up to 20 Hz
        self._landmarks: deque[np.ndarray | None] = deque(maxlen=records)  # T_O_L (the mounting applied in refine())
        self._between: deque[np.ndarray | None] = deque(maxlen=records)
        self._stamps: deque[int] = deque(maxlen=records)

    @property
    def offset_ns(self) -> int | None:
        """The suit's clock offset (suit stamp = LiDAR stamp + offset), once the jump gave it."""
        return self.jump.offset_ns

    @property
    def T_L_M(self) -> np.ndarray:
        """(4, 4) the pelvis in the LiDAR frame as the mounting now stands (nominal, then levelled, turned and its
        lever arm moved)."""
        return self._T_L_M

    @property
    def lever_m(self) -> np.ndarray:
        """(3,) the lever arm in use: the sensor's origin in the pelvis frame (m)."""
        return self._T_M_L[:3, 3].copy()

    @property
    def status(self) -> str:
        """What the trajectory waits for, or where it stands."""
        if self.offset_ns is None:
            return f"{self.jump.status}; {len(self._held)} sweeps held"
        if self._resume is not None:
            return "resuming the saved trajectory: waiting for the suit's pose at a sweep"
        if self.odometry_tilt_deg > self.config.max_odometry_tilt_deg:
            where = "synced" if self.map_frame is None else "tracking"
            said = (f"the suit's odometry put the pelvis's up {self.odometry_tilt_deg:.0f} deg from its pelvis IMU's "
                    "at the start: /mocap/odometry's orientation should be the pelvis segment's, in the contract's "
                    "model axes (x left, y up, z forward) and the suit IMUs' world")
            if self.odometry_axes is None:
                return f"{where}; {said}"
            return f"{where}; {said}; its axes taken for the segment's x, y, z: {axes_columns(self.odometry_axes)}"
        if self.map_frame is None:
            return f"synced; fixing the map frame from the first sweeps; {len(self._held)} sweeps to register"
        check = self.mount_disagreement_deg
        if check is not None and check > self.config.max_mount_disagreement_deg:
            return (f"tracking; the walk's turns put the body's axis {check:.1f} deg from the mounting levelled on "
                    "the ground at the start: that ground was not level, or the mounting moved")
        said = [check.status for check, used in ((self.spin, self.spin.correction_deg), (self.side,
                                                                                         self.side.mirrored)) if used]
        share = self.believed_share
        if share is not None and share < self.config.min_believed_share:
            said.append(f"only {100 * share:.0f} % of the last {self.config.believed_window_s:.0f} s' registrations "
                        "believed: the LiDAR moves otherwise than the suit through the mounting (is mount_spin_deg, "
                        "where the LiDAR's +x points, right?), or the scene gives ICP little to hold")
        if said:
            return f"tracking; {'; '.join(said)}"
        return f"tracking; catching up with {len(self._held)} sweeps" if self._held else "tracking"

    @property
    def mount_disagreement_deg(self) -> float | None:
        """How far the body's axis in L by the walk's turns (:attr:`hand_eye`) is from the mounting's in use (deg);
        None until the turns give it."""
        R = self.hand_eye.R_M_L
        if R is None:
            return None
        return float(np.degrees(np.arccos(np.clip((R.T @ UP_M) @ (self._T_L_M[:3, :3] @ UP_M), -1.0, 1.0))))

    @property
    def believed_share(self) -> float | None:
        """The share of the last ``believed_window_s``' registrations believed; None before the map frame or with
        fewer than 10 of them."""
        if self.map_frame is None or len(self._recent) < 10:
            return None
        return sum(b for _, b in self._recent) / len(self._recent)

    @property
    def backlog(self) -> int:
        """Sweeps taken but not registered yet (held until the jump, or taken since while they were)."""
        return len(self._held)

    @property
    def waiting(self) -> int:
        """Sweeps taken but not output yet: held for the jump, or registered before the map frame was fixed."""
        return len(self._held) + len(self._pending)

    def suit_covers(self, t0_ns: int, t1_ns: int) -> bool:
        """Whether the suit's samples cover the LiDAR-clock span [``t0_ns``, ``t1_ns``] (a sweep's points): the
        pelvis orientation known all along it (no gap wider than its buffer bridges: samples that arrive late or
        out of order may still fill one) and the suit's odometry at its end. True before the clock offset is known
        (the sweeps are held until then)."""
        if self.offset_ns is None:
            return True
        step_ns = self.rotation.max_gap_ns // 2  # any gap the buffer does not bridge holds one of these times
        t = np.linspace(t0_ns, t1_ns, max(2, int(np.ceil((t1_ns - t0_ns) / step_ns)) + 1)).astype(np.int64)
        return bool(np.isfinite(self.rotation.rotation_of_lidar(t)).all()) and self.suit.pelvis(int(t1_ns)) is not None

    def add_to_map(self, step: TrajectoryStep) -> int:
        """Put an output's deskewed points in the site map, placed by its odometry pose T_map_L; its index in the
        map (the sweep index of the points it placed, :meth:`SiteMap.shifted`)."""
        self.site.add(step.points, step.lidar, self.mapped)
        self.mapped += 1
        return self.mapped - 1

    def map_points(self) -> np.ndarray | None:
        """(M, 3) float32 the site map in ``map`` (the outputs put in it so far); None while it is empty."""
        return self.site.points() if self.site.size else None

    def resume_state(self) -> TrajectoryResume | None:
        """What a new pipeline needs to go on from the last output without another jump
        (:meth:`resume`); None before the first output, or without the suit's pose at it."""
        if self._last_out is None or self.map_frame is None:
            return None
        stamp_ns, T_map_P = self._last_out
        T_I_P = self.suit.pelvis(stamp_ns)
        if T_I_P is None:
            return None
        T = self.map_frame.T_map_O
        return TrajectoryResume(stamp_ns, int(self.offset_ns), self._T_M_L, T_map_P, T_I_P, self.stride_scale.value,
                                self.map_frame.pelvis_height_m, self.mount_levelled_deg, self.mount_yaw_deg,
                                self.odometry.map_points() @ T[:3, :3].T + T[:3, 3],
                                self._suit_yaw(stamp_ns, T_map_P, T_I_P), self.rotation.gyro_bias.value,
                                self.rotation.gyro_bias.still_s)

    def _suit_yaw(self, stamp_ns: int, T_map_P: np.ndarray, T_I_P: np.ndarray) -> float:
        """The suit world's heading in map (rad): the yaw that best turns the suit's path onto the fused one over
        the last ``_HEADING_FIT_S`` (the pelvis frames of the two differ by the mounting's error, a few degrees,
        which over a restart's seconds of walking is tens of centimetres); from the two pelvis orientations when
        the path is too short to tell (standing)."""
        recent = [(m, i) for t, m, i in self._paths if t >= stamp_ns - int(_HEADING_FIT_S * 1e9)]
        suit = np.array([i for _, i in recent]).reshape(-1, 3)
        if len(suit) >= 2 and np.sum(np.linalg.norm(np.diff(suit[:, :2], axis=0), axis=1)) >= _HEADING_MIN_PATH_M:
            T = align_yaw_translation(suit, np.array([m for m, _ in recent]))
        else:
            T = T_map_P @ np.linalg.inv(T_I_P)
        return float(np.arctan2(T[1, 0], T[0, 0]))

    def resume(self, state: TrajectoryResume) -> None:
        """Go on from ``state`` (:meth:`resume_state` of this capture's trajectory before its process stopped)
        instead of waiting for the jump: its clock offset, mounting and stride scale from now on, and the first
        sweep placed where the suit's motion since ``state``'s pose puts the pelvis, in the same ``map`` frame.
        Only before the first sweep (ValueError after)."""
        if self._last_ns is not None:
            raise ValueError("a trajectory resumes before its first sweep")
        self.jump.set_offset(state.offset_ns)
        self.rotation.set_offset(state.offset_ns)
        self.suit.set_offset(state.offset_ns)
        self._set_mount(state.T_M_L)
        self.lever = LeverArmEstimator(tuple(state.T_M_L[:3, 3]))  # the estimate goes on from the lever in use
        self.stride_scale.value = self.suit.stride_scale = state.stride_scale
        self.rotation.gyro_bias.start_from(state.gyro_bias_rad_s, state.gyro_bias_still_s)
        self.mount_levelled_deg, self.mount_yaw_deg = state.mount_levelled_deg, state.mount_yaw_deg
        self.spin.skip("as saved (resumed)")
        self.side.skip("as saved (resumed)")
        self._resume = state

    def _start_from(self, state: TrajectoryResume, ref: int) -> None:
        """The first sweep of a resumed trajectory, at ``ref`` (the suit's pose known there): the odometry starts on
        ``state``'s local map, from its pelvis pose turned as the suit's turned since and moved as the suit's moved,
        that path turned into ``map`` by the suit world's heading there (its horizontal part by the stride scale).
        The suit odometry's axes are checked first, as at a start (the state holds the pelvis in the segment's)."""
        self._check_odometry(ref)
        T_I_P = self.suit.pelvis(ref)
        T_map_P = np.eye(4)
        T_map_P[:3, :3] = state.T_map_P[:3, :3] @ state.T_I_P[:3, :3].T @ T_I_P[:3, :3]
        moved = axis_angle_to_matrix(np.array([0.0, 0.0, state.suit_yaw_rad])) @ (T_I_P[:3, 3] - state.T_I_P[:3, 3])
        moved[:2] *= state.stride_scale
        T_map_P[:3, 3] = state.T_map_P[:3, 3] + moved
        self.odometry.start_at(T_map_P @ self._T_M_L, state.map_points, (ref - state.stamp_ns) * 1e-9)
        self.odometry.set_gravity(np.array([0.0, 0.0, 1.0]))  # O is map
        self.map_frame = MapFrame(np.eye(4), "resumed", float("nan"), state.pelvis_height_m)

    def add_pelvis_imu(self, sample: ImuSampleLike) -> str | None:
        """One sample of the suit's pelvis IMU (suit clock); why it was rejected, None if kept."""
        reason = self.rotation.add(sample)
        if reason is None:
            self.jump.add_suit(int(sample.stamp_ns), np.asarray(sample.accel, dtype=np.float64))
        else:
            self.counts[f"pelvis imu rejected: {reason}"] += 1
        return reason

    def add_suit_odometry(self, stamp_ns: int, position: np.ndarray, quat: np.ndarray) -> str | None:
        """One sample of the suit's own odometry (suit clock); why it was rejected, None if kept."""
        reason = self.suit.add(stamp_ns, position, quat)
        if reason is not None:
            self.counts[f"suit odometry rejected: {reason}"] += 1
        return reason

    def add_sweep(self, points: np.ndarray, point_ns: np.ndarray, stamp_ns: int, max_register: int | None = None
                  ) -> list[TrajectoryStep]:
        """One sweep: ``points`` (N, 3) in the LiDAR frame (non-finite ones dropped), each seen at ``point_ns``
        (N,), the sweep stamped ``stamp_ns``; the steps that became ready (none while waiting for the jump or
        the map frame, several once they are found). At most ``max_register`` sweeps are registered in one call
        (None: every one waiting): a live caller works off the sweeps held until the jump a few at a time, with
        :meth:`catch_up` in between, rather than all in one long call. A sweep not after the last is refused
        (ValueError)."""
        if self._last_ns is not None and stamp_ns <= self._last_ns:
            raise ValueError(f"sweep at {stamp_ns} ns is not after the last one ({self._last_ns} ns)")
        self._last_ns = int(stamp_ns)
        points = np.asarray(points, dtype=np.float64)
        point_ns = np.asarray(point_ns, dtype=np.int64)
        finite = np.isfinite(points).all(axis=1)
        points, point_ns = points[finite], point_ns[finite]
        if self.offset_ns is None:
            self._wait_for_jump(points, point_ns, int(stamp_ns))
            if self.offset_ns is None:
                return []
            self.rotation.set_offset(self.offset_ns)
            self.suit.set_offset(self.offset_ns)
        else:
            self._held.append((points, point_ns, int(stamp_ns)))
            while self._held[-1][2] - self._held[0][2] > self.config.hold_s * 1e9:
                self._held.popleft()
                self.counts["sweeps dropped: registration fell behind"] += 1
        return self.catch_up(max_register)

    def catch_up(self, max_sweeps: int | None = None) -> list[TrajectoryStep]:
        """Register up to ``max_sweeps`` (None: all) of the sweeps waiting to be registered (those held until the
        jump, and any taken since while they were); the steps that became ready."""
        if self.offset_ns is None:
            return []
        out: list[TrajectoryStep] = []
        for _ in range(len(self._held) if max_sweeps is None else min(max_sweeps, len(self._held))):
            out += self._register(*self._held.popleft())
        return out

    def _wait_for_jump(self, points: np.ndarray, point_ns: np.ndarray, stamp_ns: int) -> None:
        """Hold the sweep; give the jump sync the sensor's height above the ground in it, once the mounting's spin
        and side are checked (the sweeps held until then, in order, when they are)."""
        if self.spin.decided:
            self._sweep_height(points, point_ns)
        elif self.spin.add(points):
            self._use_spin()
            self._use_side([held_points for held_points, _, _ in self._held] + [points])
            for held_points, held_ns, _ in self._held:
                self._sweep_height(held_points, held_ns)
            self._sweep_height(points, point_ns)
        self._held.append((points, point_ns, stamp_ns))
        while self._held[-1][2] - self._held[0][2] > self.config.hold_s * 1e9:
            self._held.popleft()
            self.counts["sweeps dropped waiting for the jump"] += 1

    def _sweep_height(self, points: np.ndarray, point_ns: np.ndarray) -> None:
        """Give the jump sync the sensor's height above the ground in one sweep before the jump."""
        keep = self.odometry.wearer.keep(points)
        height = sweep_height(points[keep], point_ns[keep], self._rng, self.config.mount, self.config.sweep_height)
        if height is None:
            self.counts["no ground in a sweep before the jump"] += 1
        else:
            self.jump.add_lidar(*height)

    def _use_spin(self) -> None:
        """Spin the nominal mounting by what the ground of the first sweeps showed, if it showed a spin."""
        if not self.spin.correction_deg:
            return
        mount = replace(self.config.mount, spin_deg=self.spin.spin_deg)
        self.config = replace(self.config, mount=mount)
        self._set_mount(mount.T_M_L)

    def _use_side(self, sweeps: list[np.ndarray]) -> None:
        """Put the nominal mounting on the hip the wearer's body in the first ``sweeps`` showed, if it is the other
        (the lever arm mirrored across the body's middle, its estimate starting from there), through the mounting's
        rotation levelled with the ground's up the spin check read (not read without it)."""
        self.side.check(sweeps, self.config.mount.R_M_L, self.spin.up_L)
        if not self.side.mirrored:
            return
        mount = replace(self.config.mount, lever_m=self.side.lever_m)
        self.config = replace(self.config, mount=mount)
        self._set_mount(mount.T_M_L)
        self.lever = LeverArmEstimator(mount.lever_m)

    def _register(self, points: np.ndarray, point_ns: np.ndarray, stamp_ns: int) -> list[TrajectoryStep]:
        """Register and fuse one sweep; the steps that became ready."""
        ref = (int(point_ns.min()) + int(point_ns.max())) // 2 if point_ns.size else stamp_ns
        resumed = self._resume is not None
        if resumed:
            if self.suit.pelvis(ref) is None:  # no prediction without the suit's motion since the saved pose
                self.counts[RESUME_WAITS] += 1
                return []
            self._start_from(self._resume, ref)
            self._resume = None
        previous_pose, previous_ns = self.odometry.pose, (self._stamps[-1] if self._stamps else None)
        anchor = self.odometry.last_registered  # the LiDAR's own motion is measured from there
        step = self.odometry.register(points, point_ns, ref, self.rotation, self.suit, self.rotation.vertical_shift,
                                      self.rotation.still)
        if not step.registered:
            self.counts[RATE_CAPPED] += 1
        else:
            if step.least_shift_information < self.odometry.config.pinned_information[0]:
                self.counts[PINNED] += 1
            if step.rejected:
                self.counts["registrations not believed"] += 1
            self._recent.append((ref, not step.rejected))
            while self._recent[0][0] < ref - self.config.believed_window_s * 1e9:
                self._recent.popleft()
        # a resumed trajectory's first sweep anchors the graph where it was predicted if its registration is not
        # believed (no other landmark, no suit factor to an earlier node)
        landmark = None if step.rejected and not resumed else step.pose
        if resumed and step.rejected:
            self.counts["resumed: first registration not believed, the prediction kept"] += 1
        T_O_P = step.pose @ self._T_L_M
        between = None
        if previous_ns is not None:
            suit = self.suit.pelvis(previous_ns), self.suit.pelvis(ref)
            if suit[0] is not None and suit[1] is not None:
                between = np.linalg.inv(suit[0]) @ suit[1]
                lidar = self._T_M_L @ np.linalg.inv(previous_pose) @ step.pose @ self._T_L_M
                if not step.rejected and anchor is not None:
                    # a shift held (wholly or in part) to the prediction says nothing of the stride scale (NaN:
                    # nothing held)
                    kept = not step.least_shift_information < self.odometry.config.pinned_information[1]
                    self._hand_eye(ref, step.pose, suit[1], *anchor, kept)
                between[[0, 2], 3] *= self.stride_scale.value
                between[1, 3] = lidar[1, 3]  # the vertical (P's y) the suit does not know: the odometry's
        self._stamps.append(ref)
        self._landmarks.append(landmark)
        self._between.append(between)
        fused = self.graph.add(ref, None if landmark is None else T_O_P, between)
        self._pending.append(_Registered(ref, step.pose, T_O_P, fused, step.rejected, step.correction_m,
                                         step.source_points, stamp_ns, step.points))
        if self._first is None:
            self._first = self._pending[0]
        if self.map_frame is None and not self._fix_map_frame(ref):
            while self._pending[-1].stamp_ns - self._pending[0].stamp_ns > self.config.hold_s * 1e9:
                self._pending.popleft()
                self.counts["sweeps dropped waiting for the map frame"] += 1
            return []
        T = self.map_frame.T_map_O
        out = [TrajectoryStep(r.stamp_ns, T @ r.fused_T_O_P, T @ r.T_O_L, T @ r.T_O_P, r.rejected, r.correction_m,
                              r.source_points, r.sweep_ns, r.points) for r in self._pending]
        self._pending.clear()
        self._last_out = out[-1].stamp_ns, out[-1].pelvis
        for step in out:  # the paths the suit world's heading in map is fitted on
            T_I_P = self.suit.pelvis(step.stamp_ns)
            if T_I_P is not None:
                self._paths.append((step.stamp_ns, step.pelvis[:3, 3], T_I_P[:3, 3]))
        return out

    def _fix_map_frame(self, ref: int) -> bool:
        """Once ``map_after_s`` of capture is registered, fix the map frame and level the mounting; whether the
        map frame is fixed."""
        first = self._first
        if ref - first.stamp_ns < self.config.map_after_s * 1e9:
            return False
        if not np.isfinite(self.odometry_tilt_deg):
            self._check_odometry(first.stamp_ns)
        up = self.suit.up_in_lidar(first.stamp_ns)
        if up is None:
            up = self.config.mount.R_M_L.T @ UP_M
            self.counts["map frame without the suit's gravity"] += 1
        try:
            self.map_frame = estimate_map_frame(self.odometry.map_points(), first.T_O_L @ self._T_L_M, up,
                                                self._rng, self.config.map_frame)
        except ValueError as error:  # tried again with the next sweep
            self.counts[f"map frame not found: {error}"] += 1
            return False
        self._level(first)
        return True

    def _check_odometry(self, t_ns: int) -> None:
        """How far the suit odometry's pelvis up is from the pelvis IMU's at ``t_ns`` (:attr:`odometry_tilt_deg`);
        if farther than ``max_odometry_tilt_deg`` and the two orientations differ by a turn of the axes (another
        axis convention: a ROS base_link's x forward, y left, z up, say), the odometry's orientations are read in
        the pelvis segment's axes from then on (:attr:`odometry_axes`)."""
        pelvis = self.suit.pelvis(t_ns)
        R_I_L = self.rotation.rotation_of_lidar(np.array([t_ns]))[0]  # R_I_P R_M_L, the mounting in use
        if pelvis is None or not np.isfinite(R_I_L).all():
            return
        R_I_P = R_I_L @ self.rotation.R_M_L.T  # the pelvis IMU's
        self.odometry_tilt_deg, axes = odometry_axes(pelvis[:3, :3], R_I_P, self.config.max_odometry_tilt_deg)
        if axes is not None:
            self.odometry_axes = axes
            self.suit.axes = axes

    def _level(self, first: _Registered) -> None:
        """Level the mounting with the map's up at the first sweep, give the odometry gravity, and put the map's
        origin and the sweeps so far through the levelled mounting."""
        up_O = np.linalg.inv(self.map_frame.T_map_O)[:3, 2]
        pelvis = self.suit.pelvis(first.stamp_ns)
        if pelvis is None:
            self.counts["mounting not levelled: no suit pose at the first sweep"] += 1
            return
        nominal = self._T_M_L[:3, :3]
        R_M_L = levelled_mount_rotation(nominal, pelvis[:3, :3].T @ [0.0, 0.0, 1.0], first.T_O_L[:3, :3].T @ up_O)
        self.mount_levelled_deg = float(np.degrees(np.arccos(np.clip((np.trace(nominal.T @ R_M_L) - 1.0) / 2.0,
                                                                     -1.0, 1.0))))
        self._set_mount_rotation(R_M_L)
        self.odometry.set_gravity(up_O)
        self.map_frame = self.map_frame.under(first.T_O_L @ self._T_L_M)
        self._replay_graph()

    def _replay_graph(self) -> None:
        """Rebuild the live graph through the mounting as it now stands from the sweeps waiting for the map frame
        (registered through the nominal mounting, before it was levelled) and the smoother's lag before them, and
        re-pose those sweeps."""
        self.graph = LiveTrajectoryGraph(self.config.graph)
        start_ns = self._pending[0].stamp_ns - int(self.config.graph.lag_s * 1e9)
        fused = {ns: self.graph.add(ns, None if T_O_L is None else T_O_L @ self._T_L_M, between)
                 for ns, T_O_L, between in zip(self._stamps, self._landmarks, self._between, strict=True)
                 if ns >= start_ns}
        self._pending = deque(replace(r, T_O_P=r.T_O_L @ self._T_L_M, fused_T_O_P=fused[r.stamp_ns])
                              for r in self._pending)

    def _turn_mount(self, registered: np.ndarray, predicted: np.ndarray) -> None:
        """Feed one believed sweep's registered and suit-predicted motion (T_Lprev_L) to the mounting's yaw."""
        axis = self._T_M_L[:3, :3].T @ UP_M  # the body's axis in L
        angle = self.mount_yaw.add(registered[:3, 3], predicted[:3, 3], axis)
        if angle is not None:
            self.mount_yaw_deg += float(np.degrees(angle))
            self._set_mount_rotation(self._T_M_L[:3, :3] @ axis_angle_to_matrix(-angle * axis))

    def _hand_eye(self, ref: int, T_O_L: np.ndarray, T_I_P: np.ndarray, anchor_ns: int, anchor_T_O_L: np.ndarray,
                  kept: bool) -> None:
        """A believed registration at ``ref``: its motion since the last registered sweep (``anchor_ns``; the
        previous sweep unless the odometry's rate cap posed that one by the suit) against the suit's, for the
        stride scale (if the registration ``kept`` its own shifts) and the mounting."""
        T_I_P0 = self.suit.pelvis(anchor_ns)
        if T_I_P0 is None:
            return
        registered = np.linalg.inv(anchor_T_O_L) @ T_O_L  # T_Lanchor_L
        suit = np.linalg.inv(T_I_P0) @ T_I_P
        lidar = self._T_M_L @ registered @ self._T_L_M  # T_Panchor_P
        # the pelvis's rise along gravity (before it is known, along the pelvis's up: the wearer stands still)
        up = self.odometry.gravity
        rise = lidar[1, 3] if up is None else float(up @ ((T_O_L - anchor_T_O_L) @ self._T_L_M)[:3, 3])
        self.suit.stride_scale = self.stride_scale.add(ref, lidar, suit, rise, kept)
        if self.odometry.gravity is not None:  # the suit's T_Lanchor_L, as SuitTrack's
            self._turn_mount(registered, self._T_L_M @ suit @ self._T_M_L)
            self._move_lever(ref, T_O_L, T_I_P)
            self.hand_eye.add(ref, T_O_L[:3, :3], T_I_P[:3, :3])

    def _move_lever(self, ref: int, T_O_L: np.ndarray, T_I_P: np.ndarray) -> None:
        """Feed one believed sweep to the lever arm's estimate; use the estimate when it moved."""
        lever = self.lever.add(ref, T_O_L, T_I_P, self._T_M_L[:3, :3])
        if lever is not None:
            T_M_L = self._T_M_L.copy()
            T_M_L[:3, 3] = lever
            self._set_mount(T_M_L)

    def _set_mount_rotation(self, R_M_L: np.ndarray) -> None:
        """Use this mounting rotation everywhere from now on."""
        T_M_L = self._T_M_L.copy()
        T_M_L[:3, :3] = R_M_L
        self._set_mount(T_M_L)

    def _set_mount(self, T_M_L: np.ndarray) -> None:
        """Use this mounting everywhere from now on."""
        self._T_M_L, self._T_L_M = T_M_L, np.linalg.inv(T_M_L)
        self.suit.set_mount(T_M_L)
        self.rotation.R_M_L = T_M_L[:3, :3]
        self.odometry.wearer = replace(self.odometry.wearer, T_M_L=T_M_L)

    def refine(self) -> tuple[np.ndarray, np.ndarray]:
        """The recorded sweeps' stamps (N,) and pelvis poses T_map_P (N, 4, 4) from the whole graph solved at
        once, its landmarks through the mounting as it stands at the end; empty before the map frame is fixed."""
        if self.map_frame is None or not self._stamps:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 4, 4))
        landmarks = [None if T is None else T @ self._T_L_M for T in self._landmarks]
        poses = fuse_batch(landmarks, list(self._between), self.config.graph)
        return np.array(self._stamps, dtype=np.int64), self.map_frame.T_map_O @ poses
