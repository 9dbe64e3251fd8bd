"""An ankle DOT's own inertial heading from a few walking strides, seen by the DOT and by the LiDAR.

DOTs that were not heading-reset together each report orientation in an
inertial frame of their own (z up, heading arbitrary). The A-pose and T-pose
fix a wrist DOT's heading (the arm turns about the body's forward axis), not
an ankle DOT's: the shank does not move between the poses, and its heading
trades off against the unknown mounting. Walking fixes it: over one stride
(from one stance of that foot to the next) the foot moves as far, and in the
same direction, as the performer, and the DOT measures that displacement in
its own frame by integrating its free acceleration between the two stances,
where the foot is still (zero-velocity updates, as foot-mounted inertial
navigation does). The performer's displacement over the same interval comes
from the LiDAR track (the segmented points' centre in the level frame). The
angle between the two is the DOT's inertial heading in that frame; strides
vote, weighted by length, and the strides whose lengths disagree (not a
walking stride: a shuffle, a turn on the spot, a missed stance) are left out.

Everything here is in the calibration's level frame P (z up); stamps in ns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lip_ros.core.frames import GRAVITY
from lip_ros.core.rotations import quat_to_matrix

__all__ = ["GaitHeadingConfig", "GaitHeading", "stride_heading"]


@dataclass(frozen=True)
class GaitHeadingConfig:
    """Stance detection and the acceptance of strides and of the estimate (SI units)."""

    smooth_s: float = 0.07  # moving average of the angular rate before looking for stances
    max_stance_rate: float = 1.5  # rad/s, largest (smoothed) angular rate of the shank in a stance
    min_stride_s: float = 0.4  # shortest time between two stances of one foot
    max_stride_s: float = 2.0  # mid-stance to mid-stance; longer: not one stride (the foot stood, a stance missed)
    min_stride_m: float = 0.3  # shortest performer displacement over a stride that votes
    still_foot_m: float = 0.15  # the foot moved less between two stance instants: both in one stance
    stride_ratio: tuple[float, float] = (0.6, 1.6)  # foot displacement / performer displacement of a stride
    min_strides: int = 3  # strides needed for an estimate
    min_agreement: float = 0.9  # |sum of the strides' votes| / sum of their lengths (1: all agree)


@dataclass(frozen=True)
class GaitHeading:
    """The estimate: ``heading`` (rad) of the DOT's inertial frame about z of P, None while there is not enough
    walking (``reason`` says what is missing)."""

    heading: float | None
    strides: int  # strides that voted
    agreement: float  # of their votes, 0 to 1
    reason: str = ""


def _stances(t: np.ndarray, rate: np.ndarray, config: GaitHeadingConfig) -> np.ndarray:
    """Indices of the stance instants: the lowest smoothed rate of each still spell of the shank."""
    width = max(1, int(round(config.smooth_s / max(float(np.median(np.diff(t))), 1e-6))))
    smooth = np.convolve(rate, np.ones(width) / width, mode="same")
    still = smooth <= config.max_stance_rate
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(np.int8), [0]])))
    stances = [a + int(np.argmin(smooth[a:b])) for a, b in zip(edges[::2], edges[1::2])]
    return np.asarray(stances, dtype=np.int64)


def _foot_displacement(t: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """Horizontal displacement (2,) over a stride from the free acceleration (N, 3) between two stances, the
    velocity zero at both (its drift removed linearly)."""
    dt = np.diff(t)
    vel = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (acc[1:] + acc[:-1]) * dt[:, None], axis=0)])
    vel -= np.outer((t - t[0]) / (t[-1] - t[0]), vel[-1])
    return np.sum(0.5 * (vel[1:] + vel[:-1]) * dt[:, None], axis=0)[:2]


def _stance_periods(t: np.ndarray, acc: np.ndarray, stances: np.ndarray, config: GaitHeadingConfig
                    ) -> tuple[list[tuple[int, int]], list[np.ndarray]]:
    """Stance instants grouped into stances (the foot did not move between them: the shank's rate can rise within
    one, as it rolls over the foot), as (first, last) indices, and the foot's displacement over each swing
    between two stances."""
    periods: list[tuple[int, int]] = []
    swings: list[np.ndarray] = []
    for k, b in enumerate(stances.tolist()):
        if k:
            a = periods[-1][1]
            moved = _foot_displacement(t[a:b + 1], acc[a:b + 1])
            if np.hypot(*moved) < config.still_foot_m:
                periods[-1] = (periods[-1][0], b)
                continue
            swings.append(moved)
        periods.append((b, b))
    return periods, swings


def stride_heading(
    stamp_ns: np.ndarray,
    quat: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    track_ns: np.ndarray,
    track_xy: np.ndarray,
    config: GaitHeadingConfig | None = None,
) -> GaitHeading:
    """The inertial heading of an ankle DOT from its samples (stamps (N,), R_I_S xyzw (N, 4), rate and specific
    force in S (N, 3), time-ordered, I its own frame) and the performer's track (stamps (F,), ordered, and
    positions (F, 2) in P) over the same walk."""
    config = config or GaitHeadingConfig()
    track_ns = np.asarray(track_ns, dtype=np.int64)
    inside = (stamp_ns >= track_ns[0]) & (stamp_ns <= track_ns[-1]) if len(track_ns) > 1 else np.zeros(0, bool)
    if inside.sum() < 3:
        return GaitHeading(None, 0, 0.0, "no DOT samples along the performer's track yet")
    t = (np.asarray(stamp_ns[inside], dtype=np.int64) - track_ns[0]) * 1e-9
    acc = np.einsum("nab,nb->na", quat_to_matrix(quat[inside]), accel[inside]) - [0.0, 0.0, GRAVITY]
    stances = _stances(t, np.linalg.norm(gyro[inside], axis=1), config)
    track_t = (track_ns - track_ns[0]) * 1e-9
    periods, swings = _stance_periods(t, acc, stances, config)
    votes, lengths = [], []
    for (a0, a1), (b0, b1), foot in zip(periods[:-1], periods[1:], swings):
        start, end = 0.5 * (t[a0] + t[a1]), 0.5 * (t[b0] + t[b1])  # mid-stance to mid-stance: one stride
        if not config.min_stride_s <= end - start <= config.max_stride_s:
            continue
        body = np.array([np.interp(end, track_t, track_xy[:, k]) - np.interp(start, track_t, track_xy[:, k])
                         for k in range(2)])
        body_m, foot_m = float(np.hypot(*body)), float(np.hypot(*foot))
        lo, hi = config.stride_ratio
        if body_m < config.min_stride_m or not lo <= foot_m / body_m <= hi:
            continue
        votes.append(complex(*body) * np.conj(complex(*foot)) / foot_m)  # |vote| = body_m, at angle body - foot
        lengths.append(body_m)
    if len(votes) < config.min_strides:
        return GaitHeading(None, len(votes), 0.0, f"{len(votes)} of {config.min_strides} walking strides seen")
    total = complex(np.sum(votes))
    agreement = abs(total) / float(np.sum(lengths))
    if agreement < config.min_agreement:
        return GaitHeading(None, len(votes), agreement,
                           f"{len(votes)} strides disagree (agreement {agreement:.2f} < {config.min_agreement:g})")
    return GaitHeading(float(np.angle(total)), len(votes), agreement)
