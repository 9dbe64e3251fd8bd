"""The hip LiDAR's mounting: what the HSC4D method knows of it beforehand, and its tilt from gravity (ROS-free).

The nominal mounting (:class:`HipMountPrior`) is off on a real wearer by a few
degrees, which turns gravity as the suit sees it into the wrong "up" in the
LiDAR's frame. Standing still at the start, the LiDAR's up is known from the
ground it stands on (:mod:`lip_ros.hsc4d.map_frame`) and the pelvis's from the
suit: :func:`levelled_mount_rotation` turns the nominal R_M_L by the smallest
rotation that makes the two agree (two of its three degrees of freedom; the
turn about gravity does not show in a still pose). The third, the turn about
the body's axis, shows in walking: the LiDAR's registered steps point a little
aside from the suit's prediction of them through the mounting
(:class:`MountYawEstimator`). The lever arm shows when the body turns: the
sensor then moves by more or less than the pelvis, by the turn applied to the
lever (hand-eye calibration's translation, :class:`LeverArmEstimator`). Hand-eye
calibration's rotation (:class:`MountRotationEstimator`) checks the levelled
mounting from the turns of the walk, which do not need the ground to be level.

All of these correct a nominal mounting by a few degrees. A sensor worn spun
about its own axis (an Ouster's connector to the back rather than forward:
the same tilt, another way round) is tens of degrees off it, and the up it
gives in the sensor's frame is off by up to twice the tilt, which the jump
sync and the map frame start from: :class:`SpinCheck` finds the spin from the
ground seen in the first sweeps, whose up lies the tilt away from the spin
axis whatever the spin, and in the direction about it that the spin decides.
"About 0.15 m to the side" does not say which hip, and the lever arm shows only
when the body turns about the vertical (a walk's first corner): :class:`SideCheck`
reads the hip from the first sweeps, in which the wearer's torso and thighs block
the sensor's rays toward the body's middle: no return lies beyond them.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from lip_ros.core.body import TORSO_PARTS, BodyModel, capsule_distances
from lip_ros.core.capsule_rays import first_hits
from lip_ros.core.frames import UP_M, hip_lidar_rotation
from lip_ros.core.ground_plane import fit_ground_plane
from lip_ros.core.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from lip_ros.core.scan_layout import returns_per_square_degree
from lip_ros.core.skeleton import calibration_pose, load_skeleton

#: returns nearer a hip LiDAR than this are the wearer's own (an arm swung out: the rig's wearer returns up to 0.7 m
#: away, nothing else comes that close)
WEARER_NEAR_M = 0.9
#: the prior of the suit's stride scale in :class:`LeverArmEstimator` (about 1; loose, it is solved for)
_SCALE_PRIOR = 0.2

__all__ = ["WEARER_NEAR_M", "HipMountPrior", "rotation_between", "levelled_mount_rotation", "SpinCheckConfig",
           "SpinCheck", "SideCheckConfig", "SideCheck", "MountYawEstimator", "LeverArmEstimator",
           "MountRotationEstimator"]


@dataclass(frozen=True)
class HipMountPrior:
    """The nominal mounting: lever arm (m, the sensor's origin in the pelvis frame M: x left, y up, z forward),
    tilt up (deg) of a sensor looking where the body faces, and its spin about its own axis (deg: where its +x
    points, 0 where the body faces; :func:`lip_ros.core.frames.hip_lidar_rotation`). Levelling and walking
    correct the tilt and the turn about the body's axis by a few degrees, not a spin set wrong by tens."""

    lever_m: tuple[float, float, float] = (-0.15, 0.0, -0.1)
    tilt_up_deg: float = 30.0
    spin_deg: float = 0.0

    @property
    def R_M_L(self) -> np.ndarray:
        """(3, 3) the nominal sensor frame L in the pelvis frame M."""
        return hip_lidar_rotation(self.tilt_up_deg, self.spin_deg)

    @property
    def T_M_L(self) -> np.ndarray:
        """(4, 4) the nominal sensor pose in the pelvis frame."""
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = self.R_M_L, self.lever_m
        return out

    @property
    def T_L_M(self) -> np.ndarray:
        """(4, 4) the pelvis in the nominal sensor frame."""
        return np.linalg.inv(self.T_M_L)


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking the direction ``a`` (3,) onto ``b`` (3,)."""
    a = np.asarray(a, dtype=np.float64) / np.linalg.norm(a)
    b = np.asarray(b, dtype=np.float64) / np.linalg.norm(b)
    axis = np.cross(a, b)
    sin = float(np.linalg.norm(axis))
    if sin < 1e-12:
        if a @ b > 0.0:
            return np.eye(3)
        raise ValueError(f"{a} and {b} are opposite: no smallest rotation")
    return axis_angle_to_matrix(axis / sin * np.arctan2(sin, float(a @ b)))


def levelled_mount_rotation(R_M_L: np.ndarray, up_M: np.ndarray, up_L: np.ndarray) -> np.ndarray:
    """(3, 3) R_M_L turned by the smallest rotation of the sensor frame that puts gravity's up in the pelvis frame
    ``up_M`` (3,) at ``up_L`` (3,) in the sensor frame: R' = R_M_L C with C^T (R_M_L^T up_M) = up_L."""
    R_M_L = np.asarray(R_M_L, dtype=np.float64)
    return R_M_L @ rotation_between(up_L, R_M_L.T @ np.asarray(up_M, dtype=np.float64))


@dataclass(frozen=True)
class SpinCheckConfig:
    """How the spin is read from the ground of the first sweeps (:class:`SpinCheck`)."""

    min_range_m: float = 1.5  # points nearer than this are left out (the wearer's own returns; the ground at a
    #                           hip's height starts beyond WEARER_NEAR_M)
    max_range_m: float = 6.0  # ... and farther than this (the ground near the wearer)
    tolerance_m: float = 0.04  # of a point on the ground plane
    margin_deg: float = 25.0  # the ground's up within the nominal tilt plus this of the spin axis (walls are 60+ off)
    tilt_margin_deg: float = 25.0  # ... and within this of the nominal tilt (the spin turns it, does not tilt it;
    #                                the rig's variants put the true tilt 10-50 deg against the nominal 30)
    height_m: tuple[float, float] = (0.4, 1.6)  # the sensor this high above the plane (on a hip)
    min_points: int = 200  # on the plane
    min_tilt_deg: float = 8.0  # a sensor tilted less shows no spin in the ground's up (its spin: the walk's yaw)
    sweeps: int = 5  # sweeps whose ground is read before deciding
    max_sweeps: int = 30  # ... tried at most (the ground not seen: the spin stays as configured)
    agree_deg: float = 10.0  # each sweep's reading within this of their mean, else the spin stays as configured
    min_error_deg: float = 30.0  # a spin found at least this far from the nominal is used; below, levelling and the
    #                              walk's yaw estimate take care of it (the rig's mountings: within 10 deg)

    def __post_init__(self) -> None:
        if not (0.0 <= self.min_range_m < self.max_range_m and self.tolerance_m > 0.0 and self.margin_deg > 0.0
                and self.tilt_margin_deg > 0.0 and 0.0 < self.height_m[0] < self.height_m[1] and self.min_points >= 3
                and 0.0 <= self.min_tilt_deg and 1 <= self.sweeps <= self.max_sweeps and self.agree_deg > 0.0
                and self.min_error_deg > 0.0):
            raise ValueError(f"invalid {self}")


class SpinCheck:
    """The sensor's spin about its own axis against the nominal mounting's, from the ground under a wearer standing
    upright: in each sweep the ground's up (a plane within the nominal tilt plus ``margin_deg`` of the spin axis,
    on points away from the wearer) lies the tilt from the axis, in the direction about it the spin decides; the
    difference from the nominal up's direction is how far the sensor is spun from the nominal. :meth:`add` takes
    sweeps until ``sweeps`` of them read the ground (or ``max_sweeps`` were tried); the readings must agree within
    ``agree_deg``. :attr:`correction_deg` is then the spin to add to the nominal one when it is at least
    ``min_error_deg`` (0 otherwise, or when the ground did not tell), :attr:`status` says what was found."""

    def __init__(self, mount: HipMountPrior, config: SpinCheckConfig | None = None, seed: int = 0) -> None:
        self.mount = mount
        self.config = config or SpinCheckConfig()
        self._rng = np.random.default_rng([seed, 7])  # its own stream: the checks leave the other fits' draws alone
        self._readings: list[float] = []
        self._ups: list[np.ndarray] = []
        self._agreed = False  # the check decided from readings that agree
        self._tried = 0
        self.correction_deg: float | None = None  #: once decided: the spin to add to the nominal one (deg)
        self.status = "not checked yet"  #: what was found

    @property
    def decided(self) -> bool:
        """Whether the check is over."""
        return self.correction_deg is not None

    @property
    def spin_deg(self) -> float:
        """The spin to use (deg, -180 to 180): the nominal one plus the correction found (none until decided)."""
        spin = self.mount.spin_deg + (self.correction_deg or 0.0)
        return float((spin + 180.0) % 360.0 - 180.0)

    def skip(self, status: str) -> None:
        """End the check without a reading (the mounting came from elsewhere: ``status``)."""
        self.correction_deg, self.status = 0.0, status

    @property
    def up_L(self) -> np.ndarray | None:
        """(3,) gravity's up in L as the ground of the sweeps that decided the check shows it (their mean); None
        until then, and when their readings disagreed or were too few."""
        if not self._agreed:
            return None
        up = np.sum(self._ups, axis=0)
        return up / np.linalg.norm(up)

    def ground_up(self, points: np.ndarray) -> np.ndarray | None:
        """(3,) gravity's up in L from one sweep's ground (points (N, 3) in L); None if no ground plane was found
        (tilted from the spin axis as the nominal tilt, with the sensor a hip's height above it), or the sensor is
        tilted too little from it to show its spin."""
        c, m = self.config, self.mount
        points = np.asarray(points, dtype=np.float64)
        r = np.linalg.norm(points, axis=1)
        plane = fit_ground_plane(points[(r >= c.min_range_m) & (r <= c.max_range_m)], c.tolerance_m,
                                 m.tilt_up_deg + c.margin_deg, c.min_points, self._rng)
        if plane is None or not c.height_m[0] <= plane.offset <= c.height_m[1]:
            return None
        tilt = float(np.degrees(np.arccos(np.clip(plane.normal[2], -1.0, 1.0))))
        if tilt < c.min_tilt_deg or abs(tilt - m.tilt_up_deg) > c.tilt_margin_deg:
            return None
        return plane.normal

    def spin_of(self, up: np.ndarray) -> float:
        """How far (deg) gravity's ``up`` (3,) in L says the sensor is spun from the nominal mounting."""
        nominal = self.mount.R_M_L.T @ UP_M  # the body's up through the nominal mounting
        # spun by d more than nominal, R_M_L becomes R_M_L Rz(d): the up in L turns by -d about L's z
        d = np.arctan2(nominal[1], nominal[0]) - np.arctan2(up[1], up[0])
        return float(np.degrees(np.arctan2(np.sin(d), np.cos(d))))

    def add(self, points: np.ndarray) -> bool:
        """One sweep of the wearer standing (points (N, 3) in L, non-finite ones left out); whether the check is
        now decided."""
        if self.decided:
            return True
        c = self.config
        self._tried += 1
        points = np.asarray(points, dtype=np.float64)
        up = self.ground_up(points[np.isfinite(points).all(axis=1)])
        if up is not None:
            self._ups.append(up)
            self._readings.append(self.spin_of(up))
        if len(self._readings) >= c.sweeps:
            a = np.radians(self._readings)
            mean = float(np.degrees(np.arctan2(np.sin(a).sum(), np.cos(a).sum())))
            spread = max(abs((r - mean + 180.0) % 360.0 - 180.0) for r in self._readings)
            self._agreed = spread <= c.agree_deg
            if not self._agreed:
                self.correction_deg = 0.0
                self.status = (f"as configured: the ground's readings of the spin disagree ({spread:.0f} deg from "
                               "their mean)")
            elif abs(mean) >= c.min_error_deg:
                self.correction_deg = mean
                self.status = (f"the ground at the start shows the LiDAR spun {mean:+.0f} deg from mount_spin_deg: "
                               f"used {self.spin_deg:.0f} deg (set mount_spin_deg to it)")
            else:
                self.correction_deg = 0.0
                self.status = f"as configured (the ground at the start: {mean:+.1f} deg)"
        elif self._tried >= c.max_sweeps:
            self.correction_deg = 0.0
            self.status = f"as configured: the ground was not read in {self._tried} sweeps"
        return self.decided


@dataclass(frozen=True)
class SideCheckConfig:
    """How the hip the sensor is worn on is read from the first sweeps (:class:`SideCheck`)."""

    lever_spread_m: tuple[float, float, float] = (0.05, 0.05, 0.1)  # the wearer's body tried with the lever arm this
    #                                                                 far either way of the nominal, per axis (3 x 3
    #                                                                 x 3 positions: a real mounting is off by some)
    erode: float = 0.5  # the body's capsules at this share of their radii (the wearer's girth and shape unknown)
    margin_m: float = 0.1  # a return this far beyond the body's surface along its ray says the body is not there
    min_seen_through_deg2: float = 7.5  # a sweep tells a side when the other side's body is seen through by the
    #                                      returns of this much of the view (square degrees: about 30 of the rig's
    #                                      OS1-64 at 1024 columns, 3.9 a square degree; the sweep's own density
    #                                      counts, core.scan_layout.returns_per_square_degree) ...
    max_share: float = 0.25  # ... and this side's by at most this share of them
    sweeps: int = 3  # the first sweeps read (the wearer standing at the start); each must tell the same side

    def __post_init__(self) -> None:
        if not (min(self.lever_spread_m) >= 0.0 and 0.0 < self.erode <= 1.0 and self.margin_m > 0.0
                and self.min_seen_through_deg2 > 0.0 and 0.0 <= self.max_share < 1.0 and self.sweeps >= 1):
            raise ValueError(f"invalid {self}")


def _standing_body(girth: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The capsules (ends a, b (K, 3), radii (K,)) of the contract skeleton's torso and thighs in its A-pose, in
    the pelvis frame, at ``girth`` times their radii: the parts of a wearer standing at the start that stay where
    they are whatever the arms do."""
    skeleton = load_skeleton()
    body = BodyModel(skeleton, girth=girth)
    a, b, r = body.capsules(*calibration_pose(skeleton, "a_pose"))
    keep = np.isin(body.names, TORSO_PARTS + ("left_thigh", "right_thigh"))
    return a[keep], b[keep], r[keep]


class SideCheck:
    """Which hip the sensor is worn on, against the nominal lever arm's side, from the first sweeps of the wearer
    standing: the wearer's torso and thighs, right beside a hip-worn sensor, block its rays toward the body's middle,
    so no return lies beyond them. :meth:`check` puts the contract skeleton's torso and thighs (A-pose, thinned to
    ``erode`` of their girth, the pelvis upright) where the nominal lever arm says and where it says mirrored across
    the body's middle, each at the lever arm's 27 positions within ``lever_spread_m`` of it keeping the one that fits
    best, and counts the returns seen through each side's body (more than ``margin_m`` beyond it along their rays): a
    sweep tells the side whose body is seen through by at most ``max_share`` of the other's count, when that covers
    at least ``min_seen_through_deg2`` of the view (the sweep's returns per square degree from its points: a sensor
    of fewer beams or columns sees fewer through the same body). The first ``sweeps`` sweeps must all tell the same
    side; it is then used: the nominal lever arm mirrored if it is the other (:attr:`lever_m`). Otherwise (the body's
    place not seen: the near arm hides it, or the sensor's field of view misses it; or the mounting's rotation not
    confirmed by the ground) the lever arm stays as configured, and :attr:`status` says why. The wearer's own returns
    do not take part: which of them are the near arm and which the body beyond depends on the arms and on the
    sensor's minimum range."""

    def __init__(self, mount: HipMountPrior, config: SideCheckConfig | None = None) -> None:
        self.mount = mount
        self.config = config or SideCheckConfig()
        self.lever_m: tuple[float, float, float] | None = None  #: once decided: the lever arm to use
        self.hip: str | None = None  #: the hip the wearer's body showed ("right", "left"), None if it did not tell
        self.status = "not checked yet"  #: what was found
        self._body: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    @property
    def decided(self) -> bool:
        """Whether the check is over."""
        return self.lever_m is not None

    @property
    def mirrored(self) -> bool:
        """Whether the check put the sensor on the other hip than the nominal lever arm's."""
        return self.lever_m is not None and self.lever_m != tuple(self.mount.lever_m)

    def skip(self, status: str) -> None:
        """End the check without a reading (the mounting came from elsewhere: ``status``)."""
        self.lever_m, self.status = tuple(self.mount.lever_m), status

    def seen_through(self, points: np.ndarray, R_M_L: np.ndarray) -> tuple[int, int]:
        """How many of one sweep's returns (points (N, 3) in L; non-finite and zero ones left out) lie beyond the
        wearer's torso and thighs with the sensor on the right hip and on the left (the best fitting of the lever
        arm's positions on each), with the sensor frame L in the pelvis frame as ``R_M_L`` (3, 3)."""
        c = self.config
        if self._body is None:
            self._body = _standing_body(c.erode)
        points = np.asarray(points, dtype=np.float64)
        points = points[np.isfinite(points).all(axis=1)]
        ranges = np.linalg.norm(points, axis=1)
        points, ranges = points[ranges > 0.0], ranges[ranges > 0.0]
        dirs = (points / ranges[:, None]) @ np.asarray(R_M_L, dtype=np.float64).T  # rays in M
        nominal = np.array(self.mount.lever_m, dtype=np.float64)
        steps = [np.array([-1.0, 0.0, 1.0]) * s for s in c.lever_spread_m]
        counts: list[int] = []
        for side in (-1.0, 1.0):  # right hip (M's x is left), left hip
            levers = np.array([[side * (abs(nominal[0]) + dx), nominal[1] + dy, nominal[2] + dz]
                               for dx in steps[0] for dy in steps[1] for dz in steps[2]])
            # from inside the body the rays would miss it: lever arms there are not tried
            levers = levers[capsule_distances(levers, *self._body).min(axis=1) > 0.0]
            best = len(ranges)
            for lever in levers:
                hit, _ = first_hits(lever, dirs, *self._body)
                best = min(best, int(np.count_nonzero(hit < ranges - c.margin_m)))
                if best == 0:  # none fits better
                    break
            counts.append(best)
        return counts[0], counts[1]

    def reading(self, points: np.ndarray, R_M_L: np.ndarray) -> int | None:
        """Which hip one sweep (points (N, 3) in L) puts the sensor on, with the sensor frame L in the pelvis frame
        as ``R_M_L`` (3, 3): +1 the right, -1 the left, None if it does not tell."""
        c = self.config
        density = returns_per_square_degree(points)
        if not density > 0.0:  # too few returns to tell how densely they sample
            return None
        least = max(c.min_seen_through_deg2 * density, 1.0)
        right, left = self.seen_through(points, R_M_L)
        if left >= least and right <= c.max_share * left:
            return 1
        if right >= least and left <= c.max_share * right:
            return -1
        return None

    def check(self, sweeps: list[np.ndarray], R_M_L: np.ndarray, up_L: np.ndarray | None) -> None:
        """Decide from the first sweeps of the wearer standing (points (N, 3) in L each; the first ``sweeps`` of
        them read) with the mounting's rotation ``R_M_L`` (3, 3) as it stands, levelled with gravity's up in L
        ``up_L`` (3,; :attr:`SpinCheck.up_L`), the wearer standing upright. Without ``up_L`` (the ground at the
        start did not confirm the rotation: a sensor hardly tilted, whose spin the ground does not show) the
        sides would be read through a rotation perhaps spun half a turn: the lever arm stays as configured."""
        if self.decided:
            return
        nominal = tuple(float(v) for v in self.mount.lever_m)
        if nominal[0] == 0.0:
            self.skip("as configured: the nominal lever arm is not to a side")
            return
        if up_L is None:
            self.skip("as configured: not read (the ground at the start did not confirm the mounting's rotation, "
                      "its spin among it)")
            return
        R_M_L = levelled_mount_rotation(R_M_L, UP_M, up_L)
        read = sweeps[:self.config.sweeps]
        said: list[int | None] = []
        for points in read:  # each must tell: the first that does not ends the check
            said.append(self.reading(points, R_M_L))
            if said[-1] is None:
                self.skip(f"as configured: the wearer's body did not tell a side (sweep {len(said)} of the first "
                          f"{len(read)} read)")
                return
        if len(said) < self.config.sweeps:
            self.skip(f"as configured: {len(said)} sweeps read, {self.config.sweeps} needed")
            return
        if len(set(said)) > 1:
            self.skip(f"as configured: the wearer's body told both sides ({said.count(1)} sweeps the right hip, "
                      f"{said.count(-1)} the left)")
            return
        self.hip = hip = "right" if said[0] > 0 else "left"
        if (nominal[0] < 0.0) == (said[0] > 0):  # M's x is left: a right hip has the lever's x negative
            self.lever_m, self.status = nominal, f"as configured (the wearer's body at the start: the {hip} hip)"
            return
        self.lever_m = (-nominal[0], nominal[1], nominal[2])
        self.status = (f"the wearer's body at the start puts the LiDAR on the {hip} hip, mount_lever_m on the "
                       f"other: used [{', '.join(f'{v:.3f}' for v in self.lever_m)}] (set mount_lever_m to it)")


class MountYawEstimator:
    """The mounting's turn about the body's axis from walking. Each believed sweep gives the LiDAR's registered
    translation and the suit's prediction of it through the current mounting (both in L); their parts across the
    body's axis are summed until the prediction has covered ``min_path_m``; the angle from the summed prediction
    to the summed registration is then what is left of the mounting's error, give or take the window's noise.
    The correction returned is that angle over the number of windows so far (at most ``average_windows``): the
    mounting does not change, so the estimate is the running mean of what the windows measured (the sums restart
    after each window, so each measures the mounting as it then stands)."""

    def __init__(self, min_path_m: float = 5.0, average_windows: int = 20, min_correction_deg: float = 0.02,
                 max_correction_deg: float = 15.0) -> None:
        if not (min_path_m > 0.0 and average_windows >= 1 and 0.0 <= min_correction_deg < max_correction_deg):
            raise ValueError(f"invalid path {min_path_m}, windows {average_windows} or corrections "
                             f"{min_correction_deg}..{max_correction_deg}")
        self.min_path_m = min_path_m
        self.average_windows = average_windows
        self.min_correction = np.radians(min_correction_deg)
        self.max_correction = np.radians(max_correction_deg)
        self._cross = self._dot = self._path = 0.0
        self.windows = 0  #: windows completed

    def add(self, registered: np.ndarray, predicted: np.ndarray, axis: np.ndarray) -> float | None:
        """One sweep's registered and predicted translations (3,) in L and the body's axis (3,) in L; the
        correction (rad, about ``axis``: the true sensor frame is the mounting's turned by minus it) when a
        window completes with one worth making (clipped to ``max_correction_deg``), else None."""
        axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
        r = registered - (registered @ axis) * axis
        p = predicted - (predicted @ axis) * axis
        self._cross += float(axis @ np.cross(p, r))
        self._dot += float(p @ r)
        self._path += float(np.linalg.norm(p))
        if self._path < self.min_path_m:
            return None
        self.windows += 1
        angle = float(np.arctan2(self._cross, self._dot)) / min(self.windows, self.average_windows)
        self._cross = self._dot = self._path = 0.0
        if abs(angle) < self.min_correction:
            return None
        return float(np.clip(angle, -self.max_correction, self.max_correction))


class _Interval:
    """The sweeps of the last ``2 span``: each new one paired with the oldest kept, at least ``span`` before it."""

    def __init__(self, span_ns: int) -> None:
        self.span_ns = span_ns
        self._recent: deque[tuple[int, tuple[np.ndarray, ...]]] = deque()

    def add(self, stamp_ns: int, *values: np.ndarray) -> tuple[np.ndarray, ...] | None:
        """A sweep's values; the oldest kept sweep's when the interval from it to this one is ``span`` to
        ``2 span`` long, else None."""
        recent = self._recent
        recent.append((int(stamp_ns), tuple(np.asarray(v, dtype=np.float64) for v in values)))
        while len(recent) > 1 and recent[1][0] <= stamp_ns - self.span_ns:
            recent.popleft()
        start_ns, start = recent[0]
        return start if self.span_ns <= stamp_ns - start_ns <= 2 * self.span_ns else None


class LeverArmEstimator:
    """The lever arm (the sensor's origin in the pelvis frame) from walking: the translation of hand-eye
    calibration. Over an interval of about ``span_s`` between two believed sweeps, the pelvis moves by t_P in its
    own frame at the start (the suit's t_S times its stride scale k) and turns by R_P; the LiDAR rigid to it with
    rotation R_M_L and lever l moves by t_L (in its own frame), and R_M_L t_L = k t_S + (R_P - I) l. Only the two
    horizontal directions are used (the suit knows no stairs), so only the turn about the vertical shows the
    lever, and only its horizontal parts (x, z of the pelvis frame); its vertical part stays nominal. k is
    solved for with the lever (one for the capture; a scale error of 1 % is 1 cm over a 1 s interval, as much
    as the lever shows in a turn, so a scale from elsewhere would pull the lever aside). The estimate is the
    least-squares solution over every interval so far with a prior of ``prior_m`` (per axis) on the nominal
    lever, each interval's horizontal misfit taken as ``noise_m``;
    :meth:`add` returns it once per ``update_s`` of intervals, once its standard deviation is under
    ``max_sigma_m`` on both axes, when it moved by more than ``min_change_m``. Memory: the sweeps of the last
    ``2 span_s`` and a 3 x 3 system."""

    #: the lever's axes estimated: x (left) and z (forward) of the pelvis frame
    AXES = (0, 2)

    def __init__(self, nominal_m: tuple[float, float, float], span_s: float = 1.0, prior_m: float = 0.03,
                 noise_m: float = 0.03, update_s: float = 5.0, max_sigma_m: float = 0.01,
                 min_change_m: float = 0.002) -> None:
        if not (span_s > 0.0 and prior_m > 0.0 and noise_m > 0.0 and update_s > 0.0 and max_sigma_m > 0.0
                and min_change_m >= 0.0):
            raise ValueError(f"invalid span {span_s}, prior {prior_m}, noise {noise_m}, update {update_s}, "
                             f"sigma {max_sigma_m} or change {min_change_m}")
        self.span_ns, self.update_ns = int(span_s * 1e9), int(update_s * 1e9)
        self.nominal = np.asarray(nominal_m, dtype=np.float64)
        self.max_sigma_m, self.min_change_m = max_sigma_m, min_change_m
        prior = np.diag([1.0 / prior_m**2, 1.0 / prior_m**2, 1.0 / _SCALE_PRIOR**2])  # lever x, z and k
        self._weight = 1.0 / noise_m**2
        self._normal = prior
        self._rhs = prior @ np.array([*self.nominal[list(self.AXES)], 1.0])
        self._interval = _Interval(self.span_ns)
        self._last_update_ns: int | None = None
        self.lever_m = self.nominal.copy()  #: the estimate last returned
        self.intervals = 0  #: intervals used

    @property
    def sigma_m(self) -> np.ndarray:
        """(3,) the standard deviation of the estimate per axis (m) as the model has it; 0 where held nominal."""
        out = np.zeros(3)
        out[list(self.AXES)] = np.sqrt(np.diag(np.linalg.inv(self._normal))[:2])
        return out

    @property
    def scale(self) -> float:
        """The suit's stride scale solved for with the lever (LiDAR per suit)."""
        return float(np.linalg.solve(self._normal, self._rhs)[2])

    def add(self, stamp_ns: int, T_O_L: np.ndarray, T_I_P: np.ndarray, R_M_L: np.ndarray) -> np.ndarray | None:
        """One believed sweep: the LiDAR's registered pose (4, 4) in its odometry frame, the suit's pelvis pose
        (4, 4) in the suit's world and the mounting's rotation in use; the new lever (3,) when an update is due
        and it moved, else None."""
        start = self._interval.add(stamp_ns, T_O_L, T_I_P)
        if start is None:
            return None
        L0, P0 = start
        up = P0[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # the suit's up in the pelvis frame
        side = np.cross(up, [0.0, 0.0, 1.0])  # the pelvis frame's z is forward: across it, horizontally
        if np.linalg.norm(side) < 0.5:  # bent over by more than 60 deg: no pelvis frame horizontal to use
            return None
        side /= np.linalg.norm(side)
        H = np.stack([side, np.cross(up, side)])  # (2, 3) the horizontal directions
        A = np.linalg.inv(L0) @ T_O_L  # T_L0_L1
        B = np.linalg.inv(P0) @ T_I_P  # T_P0_P1, the suit's
        turn = H @ (R_M_L @ A[:3, :3] @ R_M_L.T - np.eye(3))
        J = np.column_stack([turn[:, list(self.AXES)], H @ B[:3, 3]])
        y = H @ R_M_L @ A[:3, 3] - turn[:, 1] * self.nominal[1]
        self._normal += self._weight * J.T @ J
        self._rhs += self._weight * J.T @ y
        self.intervals += 1
        if self._last_update_ns is None:
            self._last_update_ns = int(stamp_ns)
        if stamp_ns - self._last_update_ns < self.update_ns or self.sigma_m.max() > self.max_sigma_m:
            return None
        self._last_update_ns = int(stamp_ns)
        lever = self.nominal.copy()
        lever[list(self.AXES)] = np.linalg.solve(self._normal, self._rhs)[:2]
        if np.linalg.norm(lever - self.lever_m) <= self.min_change_m:
            return None
        self.lever_m = lever
        return lever


class MountRotationEstimator:
    """The mounting's rotation R_M_L by hand-eye calibration of rotations: over an interval of about ``span_s``
    between two believed sweeps the LiDAR turns by R_L (in its own frame at the start, from the odometry) and the
    pelvis by R_P (in its own frame, from the suit); rigid to each other, R_P = R_M_L R_L R_M_L^T, so their
    rotation vectors satisfy r_P = R_M_L r_L. The estimate is the rotation that best takes the r_L onto the r_P
    over every interval so far (Kabsch; each interval weighs as the square of its angle), given once the
    intervals have turned the sensor by ``min_excitation_deg`` about two directions (:attr:`excitation_deg`: the
    walk's turns about the vertical show the body's axis in L, the hips' sway the turn about it). It needs the
    odometry's rotations deskewed through a mounting near the truth (1.6 deg off in the turns through one 11 deg
    off): the trajectory feeds it once the mounting is levelled. Memory: the sweeps of the last ``2 span_s`` and
    two 3 x 3 sums."""

    def __init__(self, span_s: float = 0.5, min_excitation_deg: float = 30.0) -> None:
        if not (span_s > 0.0 and min_excitation_deg > 0.0):
            raise ValueError(f"invalid span {span_s} or excitation {min_excitation_deg}")
        self.span_ns, self.min_excitation_deg = int(span_s * 1e9), min_excitation_deg
        self._interval = _Interval(self.span_ns)
        self._cross = np.zeros((3, 3))  # sum of r_P r_L^T
        self._scatter = np.zeros((3, 3))  # sum of r_L r_L^T
        self.intervals = 0  #: intervals used

    def add(self, stamp_ns: int, R_O_L: np.ndarray, R_I_P: np.ndarray) -> None:
        """One believed sweep: the LiDAR's registered rotation (3, 3) in its odometry frame and the suit's pelvis
        rotation (3, 3) in the suit's world."""
        start = self._interval.add(stamp_ns, R_O_L, R_I_P)
        if start is None:
            return
        L0, P0 = start
        r_L = matrix_to_axis_angle(L0.T @ R_O_L)
        r_P = matrix_to_axis_angle(P0.T @ R_I_P)
        self._cross += np.outer(r_P, r_L)
        self._scatter += np.outer(r_L, r_L)
        self.intervals += 1

    @property
    def excitation_deg(self) -> np.ndarray:
        """(3,) how far the intervals turned the sensor about each principal direction (the root of the sum of
        squared angles, deg), largest first."""
        return np.degrees(np.sqrt(np.clip(np.linalg.eigvalsh(self._scatter), 0.0, None)))[::-1]

    @property
    def R_M_L(self) -> np.ndarray | None:
        """(3, 3) the estimate; None until the turns excite two directions by ``min_excitation_deg``."""
        if self.excitation_deg[1] < self.min_excitation_deg:
            return None
        U, _, Vt = np.linalg.svd(self._cross)
        return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
