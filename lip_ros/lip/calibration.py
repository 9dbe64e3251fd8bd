"""A-pose / T-pose calibration of the LIP rig's four IMUs (LIP appendix A.1, equations 10-13 and 16).

Frames as in docs/conventions.md: L the LiDAR frame, M the model frame of the
calibrating body, I the inertial frame the sensors share, S a sensor frame, B
the frame of the bone it is strapped to. The performer holds the contract's A-pose,
then its T-pose, still; in each pose X the bone orientations in M are known,
``R_M_B(X)`` (forward kinematics of the pose with the body's root as M), and each
sensor reports ``R_I_S(X) = R_I_M @ R_M_B(X) @ R_B_S``. Unknown are ``R_I_M``
(the paper's R_M2I) and the mountings ``R_B_S`` (its R_s2b).

* Equation 11 (the same ``R_B_S`` from both poses) fixes the axis about which the
  arms turned, i.e. the body's forward axis in I; the ankles do not move between
  the poses and add nothing to it. The rotation about that axis is fixed by
  gravity: the body stands upright, so its up ``y_M`` is I's ``z``. ``R_I_M`` is
  the non-linear least-squares solution of both (started from a closed-form
  vector alignment), and ``R_B_S`` follows from either side of equation 11.
* Equation 12 needs the body in L. Instead of assuming it faces the LiDAR
  exactly, its heading comes from the T-pose point cloud (the outstretched arms
  span the body's left-right axis; the body faces the sensor, which resolves
  the sign). L is level and I gravity-aligned, so ``R_L_I = Rz(psi)`` with psi
  the body's heading in L minus its heading in I. (For a tilted LiDAR, "L" here
  is its level frame: :mod:`lip_ros.lip.stages` turns points into it and the
  bones out of it, so a calibration and its file hold for any tilt.)
* Equations 13 and 16 then give every sample's bone orientation and free
  acceleration in L: ``R_L_B = R_L_I @ R_I_S @ R_B_S^T`` and
  ``a_L = R_L_I @ R_I_S @ f_S - [0, 0, g]`` (``f_S`` the specific force).
* DOTs not heading-reset together do not share I: each wrist alone fixes the
  body's heading in its own frame, and when the two disagree (more than
  ``max_heading_split_deg``) each sensor gets its own, ``R_L_Ii = R_L_I @
  Rz(heading_offset)`` with I the first wrist's; the wrists' offsets follow
  from the poses, the ankles' (``heading_pending``) from the walking after
  them (:mod:`lip_ros.lip.gait_heading`, :meth:`Calibration.with_heading`).

The still A-pose and T-pose windows are found automatically (all four sensors
still; the wrists turned as the poses say between the two, the ankles did not)
or given. Data that cannot give a trustworthy answer (no still windows, a pose
not held still, residuals too large, a missing sensor) raise
:class:`CalibrationError` saying why.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from itertools import combinations, pairwise
from pathlib import Path
from typing import NamedTuple

import numpy as np
import yaml
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from lip_ros.core.frames import GRAVITY
from lip_ros.core.imu_sync import ImuArrays, ImuSeries
from lip_ros.core.rotations import (
    axis_angle_to_matrix,
    geodesic_angle,
    matrix_to_axis_angle,
    matrix_to_quat,
    project_to_so3,
    quat_to_matrix,
    rot_z,
)
from lip_ros.core.skeleton import Skeleton, calibration_pose, load_skeleton
from lip_ros.lip.gait_heading import GaitHeadingConfig, stride_heading

__all__ = [
    "CALIBRATION_VERSION",
    "POSES",
    "CalibrationError",
    "CalibrationConfig",
    "Calibration",
    "pose_bone_rotations",
    "detect_pose_windows",
    "heading_from_tpose",
    "calibrate",
    "save_calibration",
    "load_calibration",
    "CalibrationDetector",
    "MAX_SAMPLE_RATE_HZ",
    "MAX_FRAME_RATE_HZ",
]

CALIBRATION_VERSION = 1
#: The calibration poses of the contract, in the order they are held.
POSES = ("a_pose", "t_pose")
_UP_M = np.array([0.0, 1.0, 0.0])
_UP = np.array([0.0, 0.0, 1.0])  # of I and of L
_MIN_STILL_SAMPLES = 3  # per sensor in a stillness window
#: More samples (frames) per second than any sensor (LiDAR) sends: with the detector's horizon, the bounds of its
#: buffers whatever the stamps do.
MAX_SAMPLE_RATE_HZ = 400.0
MAX_FRAME_RATE_HZ = 50.0
_ARM_ITERATIONS = 3  # re-selections of the arm points in heading_from_tpose


class _Samples(NamedTuple):
    """Samples as they came (ImuArrays, not yet cleaned)."""

    stamp_ns: np.ndarray
    quat: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray


class CalibrationError(RuntimeError):
    """The data cannot give a trustworthy calibration; the message says why."""


@dataclass(frozen=True)
class CalibrationConfig:
    """Thresholds of window detection, stillness and quality checks (SI units, degrees where named so)."""

    still_window_s: float = 0.5  # sliding window of the stillness statistics
    grid_s: float = 0.02  # step of the common time grid the sensors are checked on
    still_gyro_rms: float = 0.1  # rad/s, largest RMS angular rate of a still sensor
    still_accel_std: float = 0.2  # m/s^2, largest specific-force spread of a still sensor
    min_still_s: float = 1.0  # shortest still window used for a pose
    same_pose_deg: float = 10.0  # consecutive still windows closer than this (every sensor) are one pose
    pose_match_deg: float = 20.0  # tolerance on each sensor's turn between the detected A- and T-pose
    min_window_samples: int = 20  # per sensor and pose window
    max_spread_deg: float = 4.0  # largest turn of a sensor from its mean orientation within a pose window
    max_residual_deg: float = 8.0  # largest equation-11 residual of a sensor
    max_tilt_deg: float = 10.0  # largest angle between the body's up and I's z
    # the body's headings seen by each turning sensor alone further apart: each DOT has its own inertial heading
    max_heading_split_deg: float = 5.0
    min_turn_deg: float = 30.0  # a sensor that turns this much between the poses sees the body's heading alone
    gravity_weight: float = 1.0  # weight of the upright constraint against the equation-11 residuals
    min_tpose_points: int = 50
    min_tpose_elongation: float = 2.5  # std along the arms / std across, of the T-pose cloud seen from above
    arm_gap_m: float = 0.3  # T-pose points farther than this from the body's middle are the arms'
    min_arm_points: int = 10  # per arm
    default_heading: float = float(np.pi)  # heading of the body in L without a cloud: in front on +x, facing L


@dataclass(frozen=True, eq=False)
class Calibration:
    """The result: what turns the sensors' readings into bone orientations and free accelerations in L."""

    R_L_I: np.ndarray  # (3, 3) the sensors' inertial frame in L, Rz(psi) (the paper's R_I2L)
    R_B_S: dict[str, np.ndarray]  # (3, 3) each sensor's frame in its bone's frame (the paper's R_s2b)
    R_I_M: np.ndarray  # (3, 3) the calibrating body's model frame in I (the paper's R_M2I)
    heading: float  # rad, facing direction of the calibrating body in L (about z, from +x)
    heading_source: str  # "cloud" (T-pose point cloud) or "assumed" (config.default_heading)
    windows: dict[str, tuple[int, int]]  # pose -> (start_ns, end_ns) used
    residual_deg: dict[str, float]  # per sensor: equation-11 disagreement between the poses
    spread_deg: dict[str, float]  # per sensor: largest turn from the mean within the pose windows
    tilt_deg: float  # angle between the body's up and I's z (the upright assumption's residual)
    elongation: float | None = None  # of the T-pose cloud (None without a cloud)
    #: rad, per sensor whose own inertial frame is not I: that frame in L is ``R_L_I @ Rz(offset)`` (0 when absent)
    heading_offset: dict[str, float] = field(default_factory=dict)
    #: sensors whose own inertial heading is not known yet (the ankles of DOTs not reset together, until walking
    #: gives it: :meth:`with_heading`); such a calibration is not complete and not used
    heading_pending: tuple[str, ...] = ()

    @property
    def complete(self) -> bool:
        """Whether every sensor's inertial heading is known."""
        return not self.heading_pending

    @property
    def headings(self) -> str:
        """Which inertial headings the sensors have: one shared, or each its own (and whose are still pending)."""
        if not self.heading_offset and not self.heading_pending:
            return "one shared"
        pending = f", pending for {', '.join(self.heading_pending)}" if self.heading_pending else ""
        return f"each its own (wrists from the poses, ankles from walking){pending}"

    @property
    def psi(self) -> float:
        """Heading of I in L (rad): ``R_L_I = Rz(psi)``."""
        return float(np.arctan2(self.R_L_I[1, 0], self.R_L_I[0, 0]))

    @property
    def R_L_M(self) -> np.ndarray:
        """(3, 3) the calibrating body's model frame in L."""
        return self.R_L_I @ self.R_I_M

    def apply(self, name: str, quat: np.ndarray, accel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Equations 13 and 16 for sensor ``name``: R_I_S (..., 4) xyzw and specific force (..., 3) in S
        -> bone orientation R_L_B (..., 3, 3) and free acceleration of the sensor in L (..., 3)."""
        R_L_S = self.R_L_I @ rot_z(self.heading_offset.get(name, 0.0)) @ quat_to_matrix(quat)
        acc = np.einsum("...ab,...b->...a", R_L_S, np.asarray(accel, dtype=np.float64)) - GRAVITY * _UP
        return R_L_S @ self.R_B_S[name].T, acc

    def as_dict(self) -> dict:
        """Plain Python types, rotations as (x, y, z, w) quaternions (the YAML layout)."""

        def quat(r: np.ndarray) -> list[float]:
            return [float(v) for v in matrix_to_quat(r)]

        return {
            "version": CALIBRATION_VERSION,
            "R_L_I": quat(self.R_L_I),
            "psi": self.psi,
            "R_I_M": quat(self.R_I_M),
            "heading": float(self.heading),
            "heading_source": self.heading_source,
            "windows": {p: [int(a), int(b)] for p, (a, b) in self.windows.items()},
            "sensors": {
                n: {"R_B_S": quat(r), "residual_deg": float(self.residual_deg[n]),
                    "spread_deg": float(self.spread_deg[n]), "heading_offset": self.heading_offset.get(n, 0.0)}
                for n, r in self.R_B_S.items()
            },
            "tilt_deg": float(self.tilt_deg),
            "elongation": None if self.elongation is None else float(self.elongation),
            "heading_pending": list(self.heading_pending),
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> Calibration:
        """Inverse of :meth:`as_dict`."""
        if d.get("version") != CALIBRATION_VERSION:
            raise ValueError(f"calibration version {d.get('version')!r}, expected {CALIBRATION_VERSION}")
        sensors = d["sensors"]
        return cls(
            R_L_I=quat_to_matrix(d["R_L_I"]),
            R_B_S={n: quat_to_matrix(s["R_B_S"]) for n, s in sensors.items()},
            R_I_M=quat_to_matrix(d["R_I_M"]),
            heading=float(d["heading"]),
            heading_source=str(d["heading_source"]),
            windows={p: (int(a), int(b)) for p, (a, b) in d["windows"].items()},
            residual_deg={n: float(s["residual_deg"]) for n, s in sensors.items()},
            spread_deg={n: float(s["spread_deg"]) for n, s in sensors.items()},
            tilt_deg=float(d["tilt_deg"]),
            elongation=None if d.get("elongation") is None else float(d["elongation"]),
            heading_offset={n: float(s["heading_offset"]) for n, s in sensors.items() if s.get("heading_offset")},
            heading_pending=tuple(str(n) for n in d.get("heading_pending", ())),
        )

    def with_heading(self, name: str, heading: float, skeleton: Skeleton) -> Calibration:
        """This calibration with sensor ``name``'s own inertial frame at ``heading`` (rad about z of L) instead of
        I: its offset set, its mounting solved again from the T-pose, no longer pending."""
        offset = float(np.angle(np.exp(1j * (heading - self.psi))))
        R_I_B = self.R_I_M @ pose_bone_rotations(skeleton, (name,))["t_pose"][0]  # the bone in I in the T-pose
        # the T-pose reading moves from Rz(old) to Rz(offset) in I: R_B_S = R_I_B^T Rz(offset) R_I_S(T)
        turn = R_I_B.T @ rot_z(offset - self.heading_offset.get(name, 0.0)) @ R_I_B
        return replace(self, R_B_S={**self.R_B_S, name: turn @ self.R_B_S[name]},
                       heading_offset={**self.heading_offset, name: offset},
                       heading_pending=tuple(n for n in self.heading_pending if n != name))


def save_calibration(calibration: Calibration, path: str | Path) -> None:
    """Write ``calibration`` as YAML."""
    with open(path, "w", encoding="utf-8") as f:
        yaml.safe_dump(calibration.as_dict(), f, sort_keys=False)


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration written by :func:`save_calibration`; OSError if unreadable, ValueError if it is not one."""
    with open(path, encoding="utf-8") as f:
        text = f.read()
    try:
        return Calibration.from_dict(yaml.safe_load(text))
    except (yaml.YAMLError, AttributeError, TypeError, KeyError, IndexError, ValueError) as exc:
        raise ValueError(f"{path} is not a lip_ros calibration: {exc}") from exc


def pose_bone_rotations(skeleton: Skeleton, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Per calibration pose, (S, 3, 3) R_M_B of each named sensor's bone (the body's root frame is M)."""
    joints = [skeleton.index(skeleton.lip_imus[n]["bone_joint"]) for n in names]
    return {p: calibration_pose(skeleton, p)[0][joints] for p in POSES}


def _mean_rotation(rot: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of rotations (..., N, 3, 3)."""
    return project_to_so3(rot.mean(axis=-3))


def _angle_deg(r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    return np.rad2deg(geodesic_angle(r1, r2))


def _window_stats(series: ImuSeries, t: np.ndarray, half_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample count, RMS angular rate and specific-force spread (std of the vector) in [t - half, t + half]."""
    lo = np.searchsorted(series.stamp_ns, t - half_ns, side="left")
    hi = np.searchsorted(series.stamp_ns, t + half_ns, side="right")
    acc = series.accel - series.accel.mean(axis=0)  # centred: no cancellation in the variance

    def window_sum(x: np.ndarray) -> np.ndarray:
        c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
        return c[hi] - c[lo]

    n = hi - lo
    m = np.maximum(n, 1)
    gyro_rms = np.sqrt(window_sum(np.sum(series.gyro**2, axis=1)) / m)
    mean = window_sum(acc) / m[:, None]
    var = window_sum(np.sum(acc**2, axis=1)) / m - np.sum(mean**2, axis=1)
    return n, gyro_rms, np.sqrt(np.maximum(var, 0.0))


def _still_segments(series: Mapping[str, ImuSeries], config: CalibrationConfig) -> list[tuple[int, int]]:
    """Windows (start_ns, end_ns) of at least ``min_still_s`` in which every sensor is still."""
    start = max(int(s.stamp_ns[0]) for s in series.values())
    end = min(int(s.stamp_ns[-1]) for s in series.values())
    step = int(config.grid_s * 1e9)
    if end <= start:
        return []
    t = np.arange(start, end + 1, step, dtype=np.int64)
    half = int(config.still_window_s * 0.5e9)
    still = np.ones(t.size, dtype=bool)
    for s in series.values():
        n, gyro_rms, accel_std = _window_stats(s, t, half)
        still &= (n >= _MIN_STILL_SAMPLES) & (gyro_rms <= config.still_gyro_rms) & (accel_std <= config.still_accel_std)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(np.int8), [0]])))
    runs = [(int(t[a]), int(t[b - 1])) for a, b in zip(edges[::2], edges[1::2])]
    return [(a, b) for a, b in runs if b - a >= config.min_still_s * 1e9]


def _in_window(series: ImuSeries, window: tuple[int, int]) -> np.ndarray:
    return (series.stamp_ns >= window[0]) & (series.stamp_ns <= window[1])


def _window_orientation(series: ImuSeries, window: tuple[int, int]) -> np.ndarray:
    """Mean R_I_S (3, 3) over a window."""
    return _mean_rotation(quat_to_matrix(series.quat[_in_window(series, window)]))


def detect_pose_windows(
    streams: Mapping[str, ImuArrays], skeleton: Skeleton | None = None, config: CalibrationConfig | None = None
) -> dict[str, tuple[int, int]]:
    """The A-pose and T-pose windows (start_ns, end_ns): the first pair of consecutive still windows of all
    sensors between which every sensor turned as the calibration poses say (wrists, not ankles)."""
    skeleton = skeleton or load_skeleton()
    return _detect_windows(_clean_all(streams, tuple(skeleton.lip_imus)), skeleton, config or CalibrationConfig())


def _detect_windows(
    series: dict[str, ImuSeries], skeleton: Skeleton, config: CalibrationConfig
) -> dict[str, tuple[int, int]]:
    names = tuple(series)
    segments = _still_segments(series, config)
    if not segments:
        raise CalibrationError(
            f"no window of >= {config.min_still_s:g} s in which all of {', '.join(names)} are still "
            f"(RMS rate <= {config.still_gyro_rms:g} rad/s, accel spread <= {config.still_accel_std:g} m/s^2)"
        )
    poses = [np.stack([_window_orientation(series[n], w) for n in names]) for w in segments]
    merged: list[tuple[tuple[int, int], np.ndarray]] = []
    for w, r in zip(segments, poses):  # neighbours in the same pose are one pose: keep the longer
        if merged and (_angle_deg(merged[-1][1], r) < config.same_pose_deg).all():
            if w[1] - w[0] > merged[-1][0][1] - merged[-1][0][0]:
                merged[-1] = (w, r)
        else:
            merged.append((w, r))
    bones = pose_bone_rotations(skeleton, names)
    expected = _angle_deg(bones["a_pose"], bones["t_pose"])  # conjugation keeps the angle: same in I
    turns = []
    for (wa, ra), (wt, rt) in pairwise(merged):
        turn = _angle_deg(ra, rt)
        if (np.abs(turn - expected) <= config.pose_match_deg).all():
            return {"a_pose": wa, "t_pose": wt}
        turns.append(", ".join(f"{n} {a:.0f}" for n, a in zip(names, turn)))
    raise CalibrationError(
        f"{len(merged)} still pose(s) found, but no A-pose followed by a T-pose: expected turns "
        + ", ".join(f"{n} {a:.0f}" for n, a in zip(names, expected))
        + " deg; found " + ("; ".join(turns) if turns else "nothing to pair")
    )


def heading_from_tpose(points: np.ndarray, config: CalibrationConfig | None = None) -> tuple[float, float]:
    """Facing direction (rad about z of L) of a performer in T-pose from their points (N, 3) in L, and the
    cloud's elongation.

    Seen from above, the outstretched arms span the body's left-right axis: a first guess is the cloud's
    principal axis, which the near side of the torso skews once the body is turned away from the
    sensor; the axis through the centroids of the two arms' points (those farther than ``arm_gap_m``
    from the body's middle along it) is not. Of the two perpendicular directions the body faces the
    one towards the sensor.
    """
    config = config or CalibrationConfig()
    xy = np.asarray(points, dtype=np.float64).reshape(-1, 3)[:, :2]
    xy = xy[np.isfinite(xy).all(axis=1)]
    if len(xy) < config.min_tpose_points:
        raise CalibrationError(f"{len(xy)} T-pose points, need {config.min_tpose_points}")
    middle = np.median(xy, axis=0)
    var, axes = np.linalg.eigh(np.cov(xy.T))
    elongation = float(np.sqrt(var[1] / max(var[0], 1e-12)))
    if elongation < config.min_tpose_elongation:
        raise CalibrationError(
            f"the T-pose cloud is not elongated enough ({elongation:.1f} < {config.min_tpose_elongation:g}): "
            "arms not spread, or not the performer's points"
        )
    across = axes[:, 1]
    for _ in range(_ARM_ITERATIONS):
        lateral = (xy - middle) @ across
        arms = [xy[lateral > config.arm_gap_m], xy[lateral < -config.arm_gap_m]]
        if min(len(a) for a in arms) < config.min_arm_points:
            raise CalibrationError(
                f"T-pose arms not found: {len(arms[0])} and {len(arms[1])} points beyond "
                f"{config.arm_gap_m:g} m either side of the body, need {config.min_arm_points}"
            )
        ends = [a.mean(axis=0) for a in arms]
        across = (ends[0] - ends[1]) / np.linalg.norm(ends[0] - ends[1])
        middle = 0.5 * (ends[0] + ends[1])
    forward = np.array([across[1], -across[0]])
    if forward @ middle > 0.0:  # facing away from the sensor at the origin: the other way round
        forward = -forward
    return float(np.arctan2(forward[1], forward[0])), elongation


def _clean_all(streams: Mapping[str, ImuArrays], names: tuple[str, ...]) -> dict[str, ImuSeries]:
    series = {n: ImuSeries.clean(streams[n])[0] for n in names if n in streams}
    missing = [n for n in names if n not in series or series[n].stamp_ns.size == 0]
    if missing:
        raise CalibrationError(f"no valid data from {', '.join(missing)}")
    return series


def _held_pose(series: ImuSeries, window: tuple[int, int], name: str, pose: str, config: CalibrationConfig
               ) -> tuple[np.ndarray, float]:
    """Mean R_I_S (3, 3) of a sensor in a pose window and its spread (deg); raises if the pose was not held."""
    inside = _in_window(series, window)
    count = int(inside.sum())
    if count < config.min_window_samples:
        raise CalibrationError(f"{name}: {count} samples in the {pose} window, need {config.min_window_samples}")
    rot = quat_to_matrix(series.quat[inside])
    mean = _mean_rotation(rot)
    spread = float(_angle_deg(mean, rot).max())
    rate = float(np.sqrt(np.mean(np.sum(series.gyro[inside] ** 2, axis=1))))
    if spread > config.max_spread_deg or rate > config.still_gyro_rms:
        raise CalibrationError(
            f"{name} was not held still in the {pose} window: turned up to {spread:.1f} deg from its mean "
            f"(limit {config.max_spread_deg:g}), RMS rate {rate:.3f} rad/s (limit {config.still_gyro_rms:g})"
        )
    return mean, spread


def _solve_R_I_M(
    R_I_S: dict[str, np.ndarray], R_M_B: dict[str, np.ndarray], gravity_weight: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """R_I_M (3, 3) from equation 11 over all sensors plus the upright constraint, and per pose R_B_S (S, 3, 3)."""
    (sa, st), (ba, bt) = (R_I_S[p] for p in POSES), (R_M_B[p] for p in POSES)
    # closed-form start: the turn between the poses seen in I is R_I_M times the turn in M, and up is up
    turn_i = matrix_to_axis_angle(sa @ np.swapaxes(st, -1, -2))
    turn_m = matrix_to_axis_angle(ba @ np.swapaxes(bt, -1, -2))
    weights = np.concatenate([np.ones(len(turn_i)), [gravity_weight]])
    start, _ = Rotation.align_vectors(np.vstack([turn_i, _UP]), np.vstack([turn_m, _UP_M]), weights)

    def mountings(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R_M_I = axis_angle_to_matrix(x).T
        return np.swapaxes(ba, -1, -2) @ R_M_I @ sa, np.swapaxes(bt, -1, -2) @ R_M_I @ st

    def residuals(x: np.ndarray) -> np.ndarray:
        bs_a, bs_t = mountings(x)
        eq11 = matrix_to_axis_angle(np.swapaxes(bs_a, -1, -2) @ bs_t)
        return np.concatenate([eq11.ravel(), gravity_weight * (axis_angle_to_matrix(x) @ _UP_M - _UP)])

    x = least_squares(residuals, start.as_rotvec(), method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12).x
    bs_a, bs_t = mountings(x)
    return axis_angle_to_matrix(x), bs_a, bs_t


def _own_headings(R_I_S: dict[str, np.ndarray], R_M_B: dict[str, np.ndarray], config: CalibrationConfig
                  ) -> dict[int, float]:
    """The body's heading (rad, its forward z_M about z) in the inertial frame of each sensor that turns between
    the poses (the wrists), from that sensor alone; index -> heading."""
    turn = _angle_deg(*(R_I_S[p] for p in POSES))
    heading = {}
    for i in np.flatnonzero(turn >= config.min_turn_deg).tolist():
        R_I_M, _, _ = _solve_R_I_M({p: R_I_S[p][i:i + 1] for p in POSES}, {p: R_M_B[p][i:i + 1] for p in POSES},
                                   config.gravity_weight)
        heading[i] = float(np.arctan2(R_I_M[1, 2], R_I_M[0, 2]))
    return heading


def _heading_offsets(own: dict[int, float], config: CalibrationConfig) -> dict[int, float]:
    """Per turning sensor, the turn (rad about z) from its own inertial frame into the first one's, if the sensors
    see the body's heading more than ``max_heading_split_deg`` apart (each its own heading); {} if they share one."""
    if len(own) < 2:
        return {}
    split = max(abs(np.angle(np.exp(1j * (a - b)))) for a, b in combinations(own.values(), 2))
    if np.degrees(split) <= config.max_heading_split_deg:
        return {}
    first = next(iter(own.values()))
    return {i: float(np.angle(np.exp(1j * (first - h)))) for i, h in own.items()}


def calibrate(
    streams: Mapping[str, ImuArrays],
    tpose_points: np.ndarray | None = None,
    windows: Mapping[str, tuple[int, int]] | None = None,
    skeleton: Skeleton | None = None,
    config: CalibrationConfig | None = None,
) -> Calibration:
    """Calibrate from the four sensors' samples (name -> arrays, as ``lip_imus``), optionally the performer's
    points (N, 3) in L while in T-pose (else the heading is ``config.default_heading``) and explicit pose
    windows (pose -> (start_ns, end_ns); else detected). Raises :class:`CalibrationError`."""
    skeleton = skeleton or load_skeleton()
    config = config or CalibrationConfig()
    names = tuple(skeleton.lip_imus)
    series = _clean_all(streams, names)
    if windows is None:
        windows = _detect_windows(series, skeleton, config)
    elif set(POSES) - set(windows):
        raise CalibrationError(f"windows for {', '.join(POSES)} are needed, got {', '.join(windows)}")
    elif windows["a_pose"][1] > windows["t_pose"][0]:
        raise CalibrationError("the A-pose window must end before the T-pose window starts (A-pose first)")
    held = {p: [_held_pose(series[n], windows[p], n, p, config) for n in names] for p in POSES}
    R_I_S = {p: np.stack([m for m, _ in held[p]]) for p in POSES}
    R_M_B = pose_bone_rotations(skeleton, names)
    own = _own_headings(R_I_S, R_M_B, config)
    offsets = _heading_offsets(own, config)
    for i, offset in offsets.items():  # each turning sensor's readings into the first one's inertial frame
        for p in POSES:
            R_I_S[p][i] = rot_z(offset) @ R_I_S[p][i]
    R_I_M, bs_a, bs_t = _solve_R_I_M(R_I_S, R_M_B, config.gravity_weight)
    residual = _angle_deg(bs_a, bs_t)
    tilt = float(np.rad2deg(np.arccos(np.clip(R_I_M[2, 1], -1.0, 1.0))))
    bad = [f"{n} {r:.1f} deg" for n, r in zip(names, residual) if r > config.max_residual_deg]
    problems = [
        f"A-pose and T-pose disagree (equation 11) beyond {config.max_residual_deg:g} deg: {', '.join(bad)}; "
        "were the contract's poses held, or did a sensor slip?"
    ] if bad else []
    if tilt > config.max_tilt_deg:
        problems.append(f"the body's up is {tilt:.1f} deg from vertical (limit {config.max_tilt_deg:g})")
    if problems:
        raise CalibrationError("; ".join(problems))
    if tpose_points is None:
        heading, elongation, source = config.default_heading, None, "assumed"
    else:
        (heading, elongation), source = heading_from_tpose(tpose_points, config), "cloud"
    psi = heading - np.arctan2(R_I_M[1, 2], R_I_M[0, 2])  # body heading in L minus in I (forward = z_M)
    return Calibration(
        R_L_I=rot_z(psi),
        R_B_S=dict(zip(names, _mean_rotation(np.stack([bs_a, bs_t], axis=1)))),
        R_I_M=R_I_M,
        heading=float(np.arctan2(np.sin(heading), np.cos(heading))),
        heading_source=source,
        windows={p: (int(windows[p][0]), int(windows[p][1])) for p in POSES},
        residual_deg=dict(zip(names, residual.tolist())),
        spread_deg={n: max(held[p][i][1] for p in POSES) for i, n in enumerate(names)},
        tilt_deg=tilt,
        elongation=elongation,
        heading_offset={names[i]: offset for i, offset in offsets.items() if offset},
        heading_pending=tuple(n for i, n in enumerate(names) if offsets and i not in own),
    )


@dataclass
class CalibrationDetector:
    """Online calibration: feed samples and performer clouds as they come, call :meth:`update` now and then.

    Keeps the last ``horizon_s`` of data (by stamp, and never more than ``horizon_s`` times
    :data:`MAX_SAMPLE_RATE_HZ` samples per sensor or :data:`MAX_FRAME_RATE_HZ` clouds, whatever the
    stamps do); clouds are the performer's points (N, 3) in L with their effective stamp, and those inside
    the detected T-pose window give the heading (with ``need_cloud`` it waits for them, else it assumes
    ``config.default_heading`` when there are none). DOTs with their own inertial headings: once the poses
    are solved (the wrists' headings with them), the ankles' come from the walking that follows
    (:func:`lip_ros.lip.gait_heading.stride_heading`, on the samples and clouds after the T-pose), and the
    calibration is complete when both are known.
    """

    skeleton: Skeleton = field(default_factory=load_skeleton)
    config: CalibrationConfig = field(default_factory=CalibrationConfig)
    horizon_s: float = 60.0
    need_cloud: bool = True
    calibration: Calibration | None = None
    status: str = "waiting for the calibration poses (A-pose, then T-pose, held still, facing the LiDAR)"
    gait: GaitHeadingConfig = field(default_factory=GaitHeadingConfig)
    _samples: dict[str, deque] = field(default_factory=dict, repr=False)
    _clouds: deque = field(default_factory=deque, repr=False)
    _track: deque = field(default_factory=deque, repr=False)  # (stamp, median xy) of each non-empty cloud
    _poses: Calibration | None = field(default=None, repr=False)  # solved from the poses, ankle headings pending

    def __post_init__(self) -> None:
        self._clouds = deque(self._clouds, maxlen=int(self.horizon_s * MAX_FRAME_RATE_HZ))
        self._track = deque(self._track, maxlen=self._clouds.maxlen)

    @property
    def max_buffered(self) -> int:
        """The most samples kept per sensor (and clouds)."""
        return int(self.horizon_s * MAX_SAMPLE_RATE_HZ)

    def _trim(self, queue: deque, newest_ns: int) -> None:
        while queue and queue[0][0] < newest_ns - self.horizon_s * 1e9:
            queue.popleft()

    def add_imu(self, name: str, stamp_ns: int, quat: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> None:
        """One sample of sensor ``name`` (R_I_S xyzw, rad/s and specific force in S); ignored once calibrated."""
        if self.calibration is not None:
            return
        queue = self._samples.setdefault(name, deque(maxlen=self.max_buffered))
        queue.append((int(stamp_ns), np.asarray(quat), np.asarray(gyro), np.asarray(accel)))
        self._trim(queue, int(stamp_ns))

    def add_cloud(self, stamp_ns: int, points: np.ndarray) -> None:
        """The performer's points (N, 3) in L of one frame, at the frame's effective stamp; ignored once calibrated."""
        if self.calibration is not None:
            return
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        self._clouds.append((int(stamp_ns), points))
        self._trim(self._clouds, int(stamp_ns))
        if len(points):
            self._track.append((int(stamp_ns), np.median(points[:, :2], axis=0)))
            self._trim(self._track, int(stamp_ns))

    def update(self) -> Calibration | None:
        """Try to calibrate on the data so far; the calibration once it succeeded, else None (see ``status``)."""
        if self.calibration is not None:
            return self.calibration
        streams = {n: _Samples(*map(np.array, zip(*q))) for n, q in self._samples.items() if q}
        if self._poses is None:
            try:
                windows = detect_pose_windows(streams, self.skeleton, self.config)
                t0, t1 = windows["t_pose"]
                clouds = [p for t, p in self._clouds if t0 <= t <= t1]
                if self.need_cloud and not clouds:
                    raise CalibrationError("no performer cloud in the T-pose window yet")
                points = np.concatenate(clouds) if clouds else None
                self._poses = calibrate(streams, points, windows, self.skeleton, self.config)
            except CalibrationError as exc:
                self.status = str(exc)
                return None
        if not self._walk_headings(streams):
            return None
        self.calibration, self._poses = self._poses, None
        self.status = (f"calibrated: psi {np.rad2deg(self.calibration.psi):.1f} deg "
                       f"({self.calibration.heading_source}; DOT headings: {self.calibration.headings})")
        return self.calibration

    def _walk_headings(self, streams: Mapping[str, _Samples]) -> bool:
        """Solve the pending sensors' headings from the walking after the T-pose; whether none is left pending."""
        after = self._poses.windows["t_pose"][1]
        track = [(t, xy) for t, xy in self._track if t > after]
        missing = []
        for name in self._poses.heading_pending:
            x = ImuSeries.clean(streams[name])[0] if name in streams else None
            found = None if x is None or len(track) < 2 else stride_heading(
                x.stamp_ns, x.quat, x.gyro, x.accel, np.array([t for t, _ in track]),
                np.array([c for _, c in track]), self.gait)
            if found is not None and found.heading is not None:
                self._poses = self._poses.with_heading(name, found.heading, self.skeleton)
            else:
                missing.append(f"{name}: {found.reason if found else 'no walking seen yet'}")
        if missing:
            self.status = ("A-pose and T-pose solved; the DOTs keep headings of their own, and the ankles' come from "
                           "walking: walk a few steps forward (" + "; ".join(missing) + ")")
        return not missing
