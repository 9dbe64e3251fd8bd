"""LiDAR odometry and mapping of the hip-worn LiDAR on kiss-icp's registration core (the one module that imports
``kiss_icp``), ROS-free.

Per sweep (:meth:`LidarOdometry.register`):

1. the wearer's own returns are removed (:class:`WearerFilter`: a cylinder
   round the body's axis, placed with the hip mounting as it now stands), and points
   outside [``min_range_m``, ``max_range_m``];
2. deskewing: each point is moved to where it would be seen from the sensor at
   the sweep's reference time (its middle) using its own time (the cloud's
   per-point ``t``): the sensor's rotation over the sweep from the pelvis IMU
   when given (``rotation``: the hip swings and yaws within a sweep), else
   kiss-icp's constant-velocity model (the last frame-to-frame motion), and the
   translation at the last velocity;
3. voxel subsampling, then frame-to-map point-to-point ICP (kiss-icp's robust
   registration, here with a fixed threshold) from an initial guess that takes
   the rotation from the IMU when given and the horizontal translation from the
   suit's own odometry when given (``suit``: its relative motion over a sweep
   is good, its steps scaled by the stride scale the trajectory measured; it
   does not know stairs), the vertical from the last velocity
   carried on by the IMU's vertical acceleration when given (``vertical``: a
   jump's take-off and landing; after a registration not believed the velocity
   is fitted to the believed registrations of the last ``vertical_window_s``
   with the IMU's own height profile between them, so that the guesses do not
   carry on a climb of their own; while the IMU says the sensor has stood
   still for ``still_window_s`` (``still``), from no vertical velocity); a
   registration keeps its motion away from the guess only along the motions the
   sweep's flat surfaces pin down (:func:`pinned_motion`: an open field pins
   the height and the tilt, not the shifts across it nor the turn about the
   vertical; a tilt seen at long range is pinned weakly and kept the IMU's,
   ``pinned_tilt_information``, the rest under ``pinned_information``); a
   registration is not believed (the guess is kept, and the step says why)
   when it moves the guess farther than ``max_correction_m``, or when its
   horizontal motion since the newest believed registration differs from the
   suit's by more than ``speed_ratio - 1`` times the suit's plus
   ``speed_floor_mps`` (the paper's speed rule, online,
   before a sliding registration reaches the map), or, right after a believed
   one, when its height is farther from the IMU's vertical motion since the
   newest believed one than ``vertical_gate_m`` plus ``vertical_gate_mps`` per
   second since (:meth:`LidarOdometry._vertical_rule`); the map is kiss-icp's voxel
   hash map of deskewed points, bounded by ``max_range_m`` round the sensor.
   After a gap in the sweeps (a LiDAR outage, a resumed trajectory's first
   sweep) the guess can be farther off than one ICP pass reaches (3 sigma), so
   that sweep is registered again from each pass's result until it settles.

Sweeps are registered at most ``max_rate_hz`` times a second (10: at 20 Hz
every other one); a sweep in between keeps the initial guess of step 3
(:data:`NOT_REGISTERED`) and adds nothing to the map, and the speed rule,
the constant-velocity model and the caller's hand-eye measurements follow the
registered sweeps.

Poses are of the sensor frame L at the reference times, in the odometry frame
O (L at the first sweep's reference time).

:class:`KissIcpAlone` is kiss-icp's own pipeline as it ships, for the paper's
Baseline2 (LiDAR-only odometry): no IMU, no suit.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from kiss_icp.config import KISSConfig
from kiss_icp.config.config import AdaptiveThresholdConfig, DataConfig, MappingConfig, RegistrationConfig
from kiss_icp.kiss_icp import KissICP
from kiss_icp.mapping import get_voxel_hash_map
from kiss_icp.registration import get_registration
from kiss_icp.threshold import get_threshold_estimator
from kiss_icp.voxelization import voxel_down_sample

from lip_ros.core.frames import UP_M
from lip_ros.core.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from lip_ros.core.surface_constraint import registration_constraint
from lip_ros.hsc4d.mount import WEARER_NEAR_M, HipMountPrior, rotation_between
from lip_ros.hsc4d.suit_track import SuitTrack

__all__ = ["OdometryConfig", "WearerFilter", "SweepRotation", "VerticalShift", "StillDetector", "OdometryStep",
           "NOT_REGISTERED", "LidarOdometry", "pinned_motion", "fitted_vertical_velocity", "KissIcpAlone"]

#: ``rotation(t_ns, ref_ns)``: the sensor frame at times ``t_ns`` (N,) in the sensor frame at ``ref_ns``,
#: R_Lref_L (N, 3, 3); NaN where unknown.
SweepRotation = Callable[[np.ndarray, int], np.ndarray]

#: ``vertical(v_ns, v_mps, t0_ns, t1_ns)``: how far the sensor rises from ``t0_ns`` to ``t1_ns`` (m) if its
#: vertical velocity was ``v_mps`` at ``v_ns`` (e.g. the pelvis IMU's acceleration integrated); None if unknown.
VerticalShift = Callable[[int, float, int, int], "float | None"]

#: ``still(t_ns, window_s, max_accel_mps2, max_rate_rad_s)``: whether the sensor stood still over the ``window_s``
#: up to ``t_ns``, its acceleration under ``max_accel_mps2`` and its angular rate under ``max_rate_rad_s`` (e.g. the
#: pelvis IMU's); False if unknown.
StillDetector = Callable[[int, float, float, float], bool]


@dataclass(frozen=True)
class OdometryConfig:
    """Registration and map settings (kiss-icp's names in brackets)."""

    voxel_size_m: float = 0.5  # [mapping.voxel_size]
    max_range_m: float = 60.0  # [data.max_range] farther points are dropped; the map keeps this far round
    min_range_m: float = 0.5  # [data.min_range]
    max_points_per_voxel: int = 20  # [mapping.max_points_per_voxel]
    initial_threshold_m: float = 2.0  # [adaptive_threshold.initial_threshold]
    # [adaptive_threshold.fixed_threshold] None: kiss-icp's adaptive one, which measures how far each sweep is from
    # its constant-velocity prediction: a walker's sweeps are far from it, so it stays at 0.4-0.6 m and lets ICP
    # match wrong points (0.6 m off at a jump); with the IMU's rotation the guess is good to a few cm
    fixed_threshold_m: float | None = 0.1
    # a registration that moves the sensor farther than this from the prediction is not believed (the prediction
    # is kept): with the IMU's rotation a sweep's guess is good to a few cm, and a jump of decimetres is ICP
    # sliding along a direction the scene does not pin down
    max_correction_m: float = 0.3
    # with the suit: a registration whose horizontal motion since the newest believed one differs from the suit's
    # over that time by more than (speed_ratio - 1) times the suit's speed plus speed_floor_mps is not believed (the
    # paper marks LiDAR poses faster than 1.2-2x the IMU's as outliers; a difference also catches sliding backwards
    # or sideways)
    speed_ratio: float = 1.5
    speed_floor_mps: float = 0.3
    # with gravity known in O (set_gravity) and the suit: each pose's tilt is turned this fraction of the way to the
    # suit's gravity (ICP's attitude drifts by a degree over a walk; the suit's tilt is good to a few tenths)
    gravity_gain: float = 0.1
    min_motion_m: float = 0.1  # [adaptive_threshold.min_motion_th]
    # [registration.max_num_iterations], [registration.convergence_criterion]: kiss-icp's 500 and 1e-4 let ICP run on
    # along what a sweep pins down weakly (a stair flight at 20 Hz: the pose climbed 14 cm a sweep, ATE 38 cm on a 15 s
    # capture); from the suit's guess, good to a few cm, stopping once a step is under 1 mm gave 3.6 cm there, the
    # same or better ATE elsewhere and 30-45 % less time per sweep (docs/hsc4d/odometry.md)
    max_iterations: int = 30
    convergence: float = 1e-3
    threads: int = 0  # [registration.max_num_threads] 0: all cores
    # sweeps are registered at most this often (0: every sweep); one that comes sooner after the last registered
    # is posed by the suit's motion (the registration's initial guess) and adds nothing to the map. kiss-icp takes
    # 20-30 ms a sweep here, so registering every sweep of a 20 Hz LiDAR takes most of a core by itself and the live
    # graph fell behind on 2 cores (docs/hsc4d/graph.md)
    max_rate_hz: float = 10.0
    # with the IMU's vertical motion, after a registration not believed: the vertical velocity the guess carries on
    # is fitted over the believed registrations of this long (the IMU's height profile between them, an offset and a
    # velocity) instead of taken from the guesses: one registration 11 cm off in a jump's landing (a hip LiDAR
    # looking almost level) had launched the guesses after it at 1 m/s, 0.64 m up, with the registrations against
    # them not believed. After a believed one the last two registered sweeps' difference stays: fitted always, the
    # development captures' ATE went from 4.4 to 5.9 cm (docs/hsc4d/trajectory.md, "Rig variants")
    vertical_window_s: float = 0.5
    # with the IMU's vertical motion: a registration whose height is farther than vertical_gate_m plus
    # vertical_gate_mps times the time since the newest believed one from where the IMU puts the sensor (the velocity
    # fitted as above, carried on by its acceleration) is not believed. That prediction is 0.3 cm off at the median
    # and 2 cm at the 99th percentile 0.1 s on; a registration in a jump's landing went 10 cm high from a guess 2 cm
    # off and was believed (a hip LiDAR looking almost level), and the guesses after it climbed 0.36 m. Only right
    # after a believed one: in a landing the prediction itself was 9 cm off once (a suit 4 times noisier), and the
    # rule had gone on refusing right registrations for 0.7 s while the prediction sank 18 cm
    vertical_gate_m: float = 0.06
    vertical_gate_mps: float = 0.15
    # with the IMU's vertical motion and a still detector: a sensor whose acceleration stayed under still_accel_mps2
    # and angular rate under still_rate_rad_s for the last still_window_s is taken to have no vertical velocity (a
    # zero-velocity update). A standing wearer's sweeps were not believed 14 times in a row after a jump's landing (a
    # hip LiDAR tilted up 45 deg sees 180 points, ICP slides sideways) and the guesses sank at the velocity fitted
    # over the landing, 15 cm in 1.4 s. On the rig 0.3-0.6 m/s^2 and 0.1-0.4 rad/s find the same still times (a
    # standing person's sway is estimated at a few hundredths of either; docs/hsc4d/odometry.md)
    still_window_s: float = 0.3
    still_accel_mps2: float = 0.3
    still_rate_rad_s: float = 0.2
    # a registration's motion away from the prediction (the IMU's turn, the suit's step) is kept only along the
    # motions the sweep's flat surfaces pin down (core.surface_constraint: the eigen-directions of the point-to-plane
    # information per point, a turn scaled by the points' RMS range): along one whose information is under band[0]
    # the prediction stays, over band[1] the registration, linearly between; (0, 0) keeps the registration as it is.
    # pinned_tilt_information is the band of a motion that is mostly a tilt (a turn about a horizontal axis; the
    # IMU's turn over a sweep is good to hundredths of a degree), pinned_information that of the rest (the shifts and
    # the turn about the vertical, where the prediction is the suit's step and carries its stride and heading
    # errors). The rig's site reads (5th / 50th / 95th percentile) a tilt 0.003 / 0.013 / 0.17 (seen at long range),
    # the turn about the vertical 0.05 / 0.19 / 0.54, the least shift 0.016 / 0.025 / 0.27; an open field (terrain
    # "open") the turn about the vertical 0.000 / 0.001 / 0.002, the least shift 0.000 / 0.002 / 0.008 and the next
    # 0.000 / 0.007 / 0.030, where ICP slid 20-60 cm sideways in 30 s. Holding the site's shifts more (a band of
    # 0.01-0.05 for every motion) put a graph resumed from its saved state 10 cm off (docs/hsc4d/odometry.md "What a
    # sweep pins down")
    pinned_tilt_information: tuple[float, float] = (0.01, 0.05)
    pinned_information: tuple[float, float] = (0.01, 0.03)

    def __post_init__(self) -> None:
        if not (0.0 < self.voxel_size_m and 0.0 <= self.min_range_m < self.max_range_m
                and self.max_points_per_voxel > 0 and self.initial_threshold_m > 0.0 and self.max_iterations > 0
                and self.convergence > 0.0 and self.threads >= 0 and self.speed_ratio >= 1.0
                and self.speed_floor_mps >= 0.0 and 0.0 <= self.gravity_gain <= 1.0 and self.max_rate_hz >= 0.0
                and self.vertical_window_s >= 0.0 and self.still_window_s > 0.0 and self.still_accel_mps2 > 0.0
                and self.still_rate_rad_s > 0.0 and self.vertical_gate_m > 0.0 and self.vertical_gate_mps >= 0.0
                and _is_band(self.pinned_information) and _is_band(self.pinned_tilt_information)):
            raise ValueError(f"invalid {self}")

    def kiss(self) -> KISSConfig:
        """The same settings as kiss-icp's configuration."""
        return KISSConfig(
            data=DataConfig(max_range=self.max_range_m, min_range=self.min_range_m, deskew=False),
            mapping=MappingConfig(voxel_size=self.voxel_size_m, max_points_per_voxel=self.max_points_per_voxel),
            registration=RegistrationConfig(max_num_iterations=self.max_iterations,
                                            convergence_criterion=self.convergence,
                                            max_num_threads=self.threads),
            adaptive_threshold=AdaptiveThresholdConfig(fixed_threshold=self.fixed_threshold_m,
                                                       initial_threshold=self.initial_threshold_m,
                                                       min_motion_th=self.min_motion_m),
        )


@dataclass(frozen=True, eq=False)
class WearerFilter:
    """The wearer's own returns: points nearer the sensor than ``near_m``, and points within ``radius_m`` of the
    body's axis, from ``below_m`` under the pelvis (the feet and the ground they stand on) to ``above_m`` over it,
    the body placed with the mounting T_M_L (4, 4; the nominal one unless given: the trajectory gives it the
    mounting as levelled and turned, on the hip the start showed)."""

    T_M_L: np.ndarray = field(default_factory=lambda: HipMountPrior().T_M_L)
    near_m: float = WEARER_NEAR_M
    radius_m: float = 0.55
    below_m: float = 1.2
    above_m: float = 1.0

    def keep(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the points (N, 3) in L that are not the wearer."""
        R_M_L = self.T_M_L[:3, :3]
        up = R_M_L.T @ UP_M  # the body's axis in L
        d = points + R_M_L.T @ self.T_M_L[:3, 3]  # from the pelvis origin, at -R_M_L^T lever in L
        along = d @ up
        radial_sq = np.einsum("na,na->n", d, d) - along**2
        body = (radial_sq < self.radius_m**2) & (along > -self.below_m) & (along < self.above_m)
        return ~body & (np.einsum("na,na->n", points, points) >= self.near_m**2)


@dataclass(frozen=True)
class OdometryStep:
    """One registered sweep: its reference time, the pose T_O_L (4, 4), the deskewed points used (in L at the
    reference time), how many took part in the registration, the kiss-icp threshold (m), how far the
    registration moved the initial guess (m, rad), why the registration was not believed ("" if it was; the
    guess kept), how far the pose's up was from the suit's gravity before it was turned toward it (deg; NaN
    without gravity) and the least information of a shift in the sweep (per point, :func:`pinned_motion`; along a
    motion under ``OdometryConfig.pinned_information[1]`` the prediction was kept, in part or whole; 0 for a sweep
    of too few points to tell, all of it kept; NaN: not registered, or the prediction not measured, so nothing
    kept)."""

    stamp_ns: int
    pose: np.ndarray
    points: np.ndarray
    source_points: int
    threshold_m: float
    correction_m: float
    correction_rad: float
    rejected: str = ""
    tilt_deg: float = float("nan")
    least_shift_information: float = float("nan")

    @property
    def registered(self) -> bool:
        """Whether the sweep was registered (not posed by the suit's motion under the rate cap)."""
        return self.rejected != NOT_REGISTERED


#: :attr:`OdometryStep.rejected` of a sweep that came sooner than ``max_rate_hz`` allows after the last registered
NOT_REGISTERED = "not registered: posed by the suit's motion (registration rate cap)"
#: a sweep is registered once this share of the cap's period has passed since the last registered one (stamps jitter)
_RATE_SLACK = 0.8
#: the constant-velocity model carries the last motion this long at most: across a longer gap in the sweeps (a
#: LiDAR outage, the clock stepping ahead) the suit tells the horizontal motion and the rest is not guessed
_MAX_EXTRAPOLATION_S = 1.0
#: ... and the correction a registration may make grows at this speed beyond it (the motion nobody saw)
_GAP_DRIFT_MPS = 0.5
#: ... and the sweep after it is registered again from where each pass left it, until a pass moves it less than
#: _CONVERGED_M, at most _GAP_PASSES times: one pass pairs points only within 3 sigma (0.3 m) of its guess, and a
#: resume's prediction across 1.8 s of a stair climb was 0.65 m low (one pass went 0.44 m of it, and the sweeps
#: after it, led on by that step, settled 0.28 m high)
_GAP_PASSES = 5
_CONVERGED_M = 0.01
#: the believed registrations kept for the vertical velocity: the newest ``vertical_window_s`` of them, up to this many
_MAX_BELIEVED = 64


def _se3(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation, translation
    return out


class LidarOdometry:
    """Online LiDAR odometry and mapping; sweeps go to :meth:`register` in time order."""

    def __init__(self, config: OdometryConfig | None = None, wearer: WearerFilter | None = None) -> None:
        self.config = config or OdometryConfig()
        self.wearer = wearer or WearerFilter()
        kiss = self.config.kiss()
        self._registration = get_registration(kiss)
        self._map = get_voxel_hash_map(kiss)
        self._threshold = get_threshold_estimator(kiss)
        self.pose = np.eye(4)  #: T_O_L of the last sweep
        self._delta = np.eye(4)  # the motion between the last two registered sweeps, T_Lprev_L
        self._delta_s = 0.0  # ... how long it took
        self._stamp_ns: int | None = None
        self._registered_ns: int | None = None  # of the last sweep registered ...
        self._registered_pose = np.eye(4)  # ... and its pose
        self._believed: deque[tuple[int, np.ndarray]] = deque(maxlen=_MAX_BELIEVED)  # (stamp, position in O)
        self._believed_pose = np.eye(4)  # T_O_L of the newest believed registration
        self.gravity: np.ndarray | None = None  #: gravity's up in O, once known
        self._start_gap_s = 0.0  # how long the first sweep's pose was predicted for (start_at)

    def start_at(self, T_O_L: np.ndarray, map_points: np.ndarray, gap_s: float) -> None:
        """Start from a map and a predicted pose (a trajectory resumed): the local map seeded with ``map_points``
        (M, 3) in O, the first sweep registered from ``T_O_L`` (4, 4), a pose predicted over ``gap_s`` seconds
        without the LiDAR, and believed if the registration moved it no farther than a gap that long in the
        stamps allows. Only before the first sweep (ValueError after)."""
        if self._stamp_ns is not None:
            raise ValueError("the odometry has registered sweeps already")
        self.pose = np.array(T_O_L, dtype=np.float64)
        points = np.asarray(map_points, dtype=np.float64).reshape(-1, 3)
        if len(points):
            self._map.add_points(points)
        self._start_gap_s = float(gap_s)

    def set_gravity(self, up: np.ndarray) -> None:
        """Gravity's up (3,) in the odometry frame O: from now on each pose's tilt is pulled toward the suit's."""
        self.gravity = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)

    @property
    def last_registered(self) -> tuple[int, np.ndarray] | None:
        """The reference time (ns) and pose T_O_L of the last sweep registered (believed or not), None before."""
        return None if self._registered_ns is None else (self._registered_ns, self._registered_pose)

    def map_points(self) -> np.ndarray:
        """(M, 3) the local map's points in O."""
        return self._map.point_cloud()

    def _rotations(self, point_ns: np.ndarray, stamp_ns: int, rotation: SweepRotation | None,
                   suit: SuitTrack | None = None) -> np.ndarray:
        """R_Lref_L (N, 3, 3) at the points' times: from ``rotation`` where it knows them, else at a constant
        rate: the suit odometry's turn over the points' span where it knows it (the pelvis IMU silent), else
        the last sweep-to-sweep rotation's."""
        tau = (point_ns - stamp_ns) * 1e-9
        rate = matrix_to_axis_angle(self._delta[:3, :3]) / self._delta_s if self._delta_s > 0.0 else np.zeros(3)
        span = (int(point_ns.min()), int(point_ns.max())) if point_ns.size else (0, 0)
        turn = suit.lidar_motion(*span) if suit is not None and span[1] > span[0] else None
        if turn is not None:
            rate = matrix_to_axis_angle(turn[:3, :3]) / ((span[1] - span[0]) * 1e-9)
        out = axis_angle_to_matrix(tau[:, None] * rate)
        if rotation is not None:
            given = rotation(point_ns, stamp_ns)
            known = np.isfinite(given).all(axis=(1, 2))
            out[known] = given[known]
        return out

    def deskew(self, points: np.ndarray, point_ns: np.ndarray, stamp_ns: int,
               rotation: SweepRotation | None = None, suit: SuitTrack | None = None) -> np.ndarray:
        """(N, 3) points seen at their own times ``point_ns`` moved to the sensor frame at ``stamp_ns``: rotated
        as the sensor turned (``rotation``, else at the suit odometry's rate, else the constant-velocity model)
        and shifted at the last velocity.
        The rotations are found once per distinct time (a column fires all its beams at once)."""
        velocity = self._delta[:3, 3] / self._delta_s if self._delta_s > 0.0 else np.zeros(3)
        times, which = np.unique(point_ns, return_inverse=True)
        rot = self._rotations(times, stamp_ns, rotation, suit)
        moved = np.einsum("nab,nb->na", rot[which], points)
        return moved + ((times[which] - stamp_ns) * 1e-9)[:, None] * velocity

    def register(self, points: np.ndarray, point_ns: np.ndarray, stamp_ns: int,
                 rotation: SweepRotation | None = None, suit: SuitTrack | None = None,
                 vertical: VerticalShift | None = None, still: StillDetector | None = None) -> OdometryStep:
        """Register one sweep: ``points`` (N, 3) in L, each seen at ``point_ns`` (N,), posed at ``stamp_ns`` (the
        sweep's reference time); ``rotation`` the sensor's rotation over time from the IMU, ``suit`` the suit's
        own odometry, ``vertical`` the IMU's vertical motion and ``still`` whether it stands still, if known. A
        sweep with no points keeps the predicted pose, and so does one that comes sooner than ``max_rate_hz``
        allows after the last registered (:data:`NOT_REGISTERED`, its points neither registered nor mapped); one
        not after the last is refused (ValueError)."""
        if self._stamp_ns is not None and stamp_ns <= self._stamp_ns:
            raise ValueError(f"sweep at {stamp_ns} ns is not after the last one ({self._stamp_ns} ns)")
        c = self.config
        dt = 0.0 if self._stamp_ns is None else (stamp_ns - self._stamp_ns) * 1e-9
        guess, suit_motion = self._guess(stamp_ns, dt, rotation, suit, vertical, still)
        up = None if suit_motion is None else self.pose[:3, :3] @ suit_motion[1]  # in O
        sigma = float(self._threshold.get_threshold())
        if not self._due(stamp_ns):
            self.pose, tilt = self._level(guess, stamp_ns, suit)
            self._stamp_ns = stamp_ns
            return OdometryStep(stamp_ns, self.pose, np.empty((0, 3)), 0, sigma, 0.0, 0.0, NOT_REGISTERED, tilt)
        points = np.asarray(points, dtype=np.float64)
        point_ns = np.asarray(point_ns, dtype=np.int64)
        range_sq = np.einsum("na,na->n", points, points)
        keep = (range_sq >= c.min_range_m**2) & (range_sq <= c.max_range_m**2) & self.wearer.keep(points)
        frame = self.deskew(points[keep], point_ns[keep], stamp_ns, rotation, suit)
        frame_down = voxel_down_sample(frame, 0.5 * c.voxel_size_m)
        source = voxel_down_sample(frame_down, 1.5 * c.voxel_size_m)
        gap_s = dt if self._stamp_ns is not None else self._start_gap_s
        pose = guess
        for _ in range(0 if self._map.empty() else 1 if gap_s <= _MAX_EXTRAPOLATION_S else _GAP_PASSES):
            moved = np.asarray(self._registration.align_points_to_map(
                points=source, voxel_map=self._map, initial_guess=pose, max_correspondance_distance=3.0 * sigma,
                kernel=sigma))
            step_m, pose = float(np.linalg.norm(moved[:3, 3] - pose[:3, 3])), moved
            if step_m < _CONVERGED_M:
                break
        # the prediction is kept along what the sweep does not pin down only where it is measured: the suit's step and
        # the IMU's turn over one sweep; not an extrapolation without the suit, nor one over a gap of seconds
        if up is not None and gap_s <= _MAX_EXTRAPOLATION_S:
            pose, least = pinned_motion(pose, guess, source, guess[:3, :3].T @ up, c.pinned_information,
                                        c.pinned_tilt_information)
        else:
            least = float("nan")
        deviation = np.linalg.inv(guess) @ pose
        correction_m = float(np.linalg.norm(deviation[:3, 3]))
        rejected = ""
        max_correction_m = c.max_correction_m + _GAP_DRIFT_MPS * max(0.0, gap_s - _MAX_EXTRAPOLATION_S)
        if correction_m > max_correction_m:
            rejected = f"correction {correction_m:.2f} m > {max_correction_m:.2f} m"
        elif suit_motion is not None:  # the motion since the newest believed registration (_speed_reference)
            since_ns, since_pose = self._speed_reference()
            if since_ns != self._stamp_ns:
                suit_motion = suit.horizontal_motion(since_ns, stamp_ns)
            if suit_motion is not None:
                rejected = self._speed_rule(np.linalg.inv(since_pose) @ pose, *suit_motion,
                                            (stamp_ns - since_ns) * 1e-9)
        if not rejected and vertical is not None and up is not None and self._last_believed:
            rejected = self._vertical_rule(pose[:3, 3] @ up, vertical, up, stamp_ns)
        if rejected:
            pose = guess
        pose, tilt = self._level(pose, stamp_ns, suit)
        self._threshold.update_model_deviation(deviation)
        self._map.update(frame_down, pose)
        if self._registered_ns is not None:
            self._delta = np.linalg.inv(self._registered_pose) @ pose
            self._delta_s = (stamp_ns - self._registered_ns) * 1e-9
        self._registered_ns, self._registered_pose = stamp_ns, pose
        if not rejected:
            self._believed.append((stamp_ns, pose[:3, 3].copy()))
            self._believed_pose = pose
        self.pose, self._stamp_ns = pose, stamp_ns
        return OdometryStep(stamp_ns, pose, frame, len(source), sigma, correction_m,
                            float(np.linalg.norm(matrix_to_axis_angle(deviation[:3, :3]))), rejected, tilt, least)

    def _due(self, stamp_ns: int) -> bool:
        """Whether the sweep at ``stamp_ns`` is to be registered under ``max_rate_hz``."""
        rate = self.config.max_rate_hz
        return (rate == 0.0 or self._registered_ns is None
                or (stamp_ns - self._registered_ns) * 1e-9 >= _RATE_SLACK / rate)

    def _guess(self, stamp_ns: int, dt: float, rotation: SweepRotation | None, suit: SuitTrack | None,
               vertical: VerticalShift | None, still: StillDetector | None = None
               ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
        """The predicted pose T_O_L at ``stamp_ns``, ``dt`` s after the last sweep: the IMU's rotation (else the
        suit odometry's), the suit's horizontal motion and the IMU's vertical where known (from no vertical
        velocity now if ``still`` says so), else the motion between the last two registered sweeps at the same
        rate, for at most ``_MAX_EXTRAPOLATION_S``; and the suit's horizontal motion and up (None if unknown)."""
        turn = self._delta[:3, :3]
        scale = min(dt, _MAX_EXTRAPOLATION_S) / self._delta_s if self._delta_s > 0.0 else 0.0
        if self._delta_s > 0.0:  # constant velocity, scaled to this sweep's interval
            turn = axis_angle_to_matrix(matrix_to_axis_angle(turn) * scale)
        if rotation is not None and self._stamp_ns is not None:
            given = rotation(np.array([stamp_ns], dtype=np.int64), self._stamp_ns)[0]
            if np.isfinite(given).all():
                turn = given
            elif suit is not None and (motion := suit.lidar_motion(self._stamp_ns, stamp_ns)) is not None:
                turn = motion[:3, :3]  # the pelvis IMU silent: the suit odometry's turn
        shift = self._delta[:3, 3] * scale
        suit_motion = None
        if suit is not None and self._stamp_ns is not None:
            suit_motion = suit.horizontal_motion(self._stamp_ns, stamp_ns)
        if suit_motion is not None:  # the suit's horizontal motion, the last velocity's vertical
            horizontal, up = suit_motion
            rise = float(shift @ up)
            if vertical is not None:  # ... carried on by the IMU's acceleration
                known = None
                c = self.config
                if still is not None and still(stamp_ns, c.still_window_s, c.still_accel_mps2, c.still_rate_rad_s):
                    known = (stamp_ns, 0.0)
                elif self._believed and not self._last_believed:
                    known = self._vertical_velocity(vertical, self.pose[:3, :3] @ up, stamp_ns)
                if known is None and self._delta_s > 0.0:  # the last two registered sweeps' difference
                    known = (self._registered_ns - int(self._delta_s * 5e8),
                             float(self._delta[:3, :3].T @ self._delta[:3, 3] @ up) / self._delta_s)
                carried = None if known is None else vertical(*known, self._stamp_ns, stamp_ns)
                rise = rise if carried is None else carried
            shift = horizontal + rise * up
        return self.pose @ _se3(turn, shift), suit_motion

    def _speed_reference(self) -> tuple[int, np.ndarray]:
        """The sweep a registration's motion is measured from for the speed rule, (stamp ns, T_O_L): the newest
        believed registration; before one, the last registered sweep (else the last sweep). Not the last registered
        one: after a registration not believed that sweep stands at its guess, whose own error the next registration
        would take back as motion; a standing wearer's guess 2-7 cm off after a jump's landing had every
        registration after it refused until the walk (10-14 in a row: 3 cm in 0.1 s is the 0.3 m/s floor), the map
        built on the guesses. From the believed one the allowance grows with the time since."""
        if self._believed:
            return self._believed[-1][0], self._believed_pose
        if self._registered_ns is not None:
            return self._registered_ns, self._registered_pose
        return self._stamp_ns, self.pose

    @property
    def _last_believed(self) -> bool:
        """Whether the last sweep registered was believed."""
        return bool(self._believed) and self._believed[-1][0] == self._registered_ns

    def _vertical_rule(self, height: float, vertical: VerticalShift, up: np.ndarray, stamp_ns: int) -> str:
        """Why a registration putting the sensor at ``height`` along ``up`` (3,) in O at ``stamp_ns`` is not believed
        against the IMU's vertical motion since the newest believed registration ("" if it is, or if the IMU's
        prediction is not known)."""
        known = self._vertical_velocity(vertical, up, stamp_ns) if self._believed else None
        rise = None if known is None else vertical(known[0], known[1], known[0], stamp_ns)
        if rise is None:
            return ""
        off = height - (float(self._believed[-1][1] @ up) + rise)
        c = self.config
        allowed = c.vertical_gate_m + c.vertical_gate_mps * (stamp_ns - known[0]) * 1e-9
        if abs(off) <= allowed:
            return ""
        return f"height {off:+.2f} m off the IMU's vertical motion (allowed {allowed:.2f})"

    def _vertical_velocity(self, vertical: VerticalShift, up: np.ndarray, stamp_ns: int) -> tuple[int, float] | None:
        """The sensor's velocity along ``up`` (3,) in O at the last believed registration, fitted over the believed
        registrations of the last ``vertical_window_s`` (:func:`fitted_vertical_velocity`); None if that one is more
        than ``_MAX_EXTRAPOLATION_S`` before ``stamp_ns`` (the IMU's integral drifts)."""
        newest = self._believed[-1][0]
        if (stamp_ns - newest) * 1e-9 > _MAX_EXTRAPOLATION_S:
            return None
        recent = [(ns, float(p @ up)) for ns, p in self._believed
                  if (newest - ns) * 1e-9 <= self.config.vertical_window_s]
        return fitted_vertical_velocity(recent, vertical)

    def _level(self, pose: np.ndarray, stamp_ns: int, suit: SuitTrack | None) -> tuple[np.ndarray, float]:
        """``pose`` with its up (gravity in L) turned ``gravity_gain`` of the way to the suit's, and how far it was
        from it (deg); unchanged and NaN without gravity or the suit."""
        up = None if suit is None or self.gravity is None else suit.up_in_lidar(stamp_ns)
        if up is None:
            return pose, float("nan")
        current = pose[:3, :3].T @ self.gravity
        tilt = float(np.degrees(np.arccos(np.clip(current @ up, -1.0, 1.0))))
        out = pose.copy()
        out[:3, :3] = pose[:3, :3] @ axis_angle_to_matrix(
            self.config.gravity_gain * matrix_to_axis_angle(rotation_between(up, current)))
        return out, tilt

    def _speed_rule(self, step: np.ndarray, suit_horizontal: np.ndarray, up: np.ndarray, dt: float) -> str:
        """Why the registered motion ``step`` (T_Lprev_L) is not believed against the suit's horizontal motion over
        ``dt`` s ("" if it is)."""
        d = step[:3, 3]
        horizontal = d - (d @ up) * up
        differ = float(np.linalg.norm(horizontal - suit_horizontal)) / dt
        speed = float(np.linalg.norm(suit_horizontal)) / dt
        allowed = (self.config.speed_ratio - 1.0) * speed + self.config.speed_floor_mps
        if differ <= allowed:
            return ""
        return f"horizontal motion {differ:.2f} m/s off the suit's ({speed:.2f} m/s; allowed {allowed:.2f})"


def pinned_motion(pose: np.ndarray, guess: np.ndarray, points: np.ndarray, up: np.ndarray,
                  band: tuple[float, float], tilt_band: tuple[float, float]) -> tuple[np.ndarray, float]:
    """The registered ``pose`` T_O_L (4, 4) with its motion away from the ``guess`` (4, 4) kept only along the
    motions the ``points`` (N, 3; in L, the ones registered) pin down (:func:`registration_constraint`): along an
    eigen-direction whose information is under ``band[0]`` the guess's, over ``band[1]`` the pose's, linearly
    between; ``tilt_band`` instead for one that is mostly a turn about an axis square to ``up`` (3,; in the guess's
    L); a band (0, 0) keeps the pose's. Also the least information of a motion that is mostly a shift (a tilt seen
    at long range reads low wherever a sweep is; NaN if none is)."""
    values, vectors, scale = registration_constraint(points)
    shifts = np.einsum("ij,ij->j", vectors[3:], vectors[3:]) > 0.5
    least = float(values[shifts].min()) if shifts.any() else float("nan")
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    level = vectors[:3] - np.outer(up, up @ vectors[:3])  # each direction's turn about a horizontal axis
    tilts = np.einsum("ij,ij->j", level, level) > 0.5
    gain = np.where(tilts, _band_gain(values, tilt_band), _band_gain(values, band))
    delta = np.linalg.inv(guess) @ pose  # in the guess's L
    twist = np.concatenate([matrix_to_axis_angle(delta[:3, :3]) * scale, delta[:3, 3]])
    kept = vectors @ (gain * (vectors.T @ twist))
    return guess @ _se3(axis_angle_to_matrix(kept[:3] / scale), kept[3:]), least


def _band_gain(values: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    """How much of a motion with information ``values`` a registration keeps under ``band`` (see
    :func:`pinned_motion`)."""
    if band[1] == 0.0:
        return np.ones_like(values)
    return np.clip((values - band[0]) / (band[1] - band[0]), 0.0, 1.0)


def _is_band(band: tuple[float, float]) -> bool:
    """Whether ``band`` is a valid ``pinned_information``: two finite numbers, 0 <= low < high, or (0, 0)."""
    return (isinstance(band, tuple) and len(band) == 2 and bool(np.isfinite(band).all())
            and (0.0 <= band[0] < band[1] or band == (0.0, 0.0)))


def fitted_vertical_velocity(heights: list[tuple[int, float]], vertical: VerticalShift) -> tuple[int, float] | None:
    """The vertical velocity at the newest of ``heights`` (stamp ns, height m; in time order): each height less
    the IMU's rise from it to the newest (``vertical``, at rest then) fitted with an offset and a velocity by least
    squares, so that one height off moves the velocity by a share of its error over the window instead of by its
    error over one sweep's interval; (stamp, m/s), None with fewer than two heights or the IMU not known."""
    if len(heights) < 2:
        return None
    newest = heights[-1][0]
    rises = [vertical(newest, 0.0, ns, newest) for ns, _ in heights]
    if any(r is None for r in rises):
        return None
    dt = np.array([(ns - newest) * 1e-9 for ns, _ in heights])
    z = np.array([h for _, h in heights]) + np.array(rises, dtype=np.float64)
    (_, velocity), *_ = np.linalg.lstsq(np.stack([np.ones_like(dt), dt], axis=1), z, rcond=None)
    return newest, float(velocity)


class KissIcpAlone:
    """kiss-icp's pipeline with its defaults (deskew by its constant-velocity model on the points' times, adaptive
    threshold, 500 ICP iterations, voxel size a hundredth of the range) on sweeps with the wearer's returns
    removed (:class:`WearerFilter`, as any user would): LiDAR-only odometry, the paper's Baseline2."""

    def __init__(self, max_range_m: float = OdometryConfig.max_range_m, wearer: WearerFilter | None = None) -> None:
        self.wearer = wearer or WearerFilter()
        self._kiss = KissICP(KISSConfig(data=DataConfig(max_range=max_range_m, deskew=True),
                                        mapping=MappingConfig(voxel_size=max_range_m / 100.0)))

    def register(self, points: np.ndarray, point_ns: np.ndarray) -> np.ndarray:
        """One sweep, points (N, 3) in L seen at ``point_ns`` (N,); T_O_L (4, 4) at the middle of its points'
        times (O: L at the first sweep's)."""
        keep = self.wearer.keep(points)
        t = point_ns[keep].astype(np.float64)
        span = t.max() - t.min() if t.size else 0.0
        self._kiss.register_frame(np.asarray(points[keep], dtype=np.float64),
                                  (t - t.min()) / span if span > 0.0 else np.full(t.size, 0.5))
        return self._kiss.last_pose.copy()
