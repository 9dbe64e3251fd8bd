"""Tracks of person-sized clusters across LiDAR frames: constant-velocity prediction and gated association.

Part of the performer segmentation (:mod:`lip_ros.lip.segmentation`), ROS-free.
Positions are horizontal (xy in L); stamps are integer ns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Track", "associate"]


@dataclass
class Track:
    """A cluster followed across frames: where it was last seen, how fast it moves, how its outline spread.

    A *stay* is the time it remains within ``stay_radius`` of where the stay
    began (``origin``); moving farther starts a new stay. The outline is the
    cluster's horizontal extent to the left and right of the line of sight
    through ``origin``: ``narrowest`` is the (left, right) of the narrowest view
    in this stay and ``widest`` the largest left and right seen since. A person
    spreading their arms on the spot grows on both sides; a static object that
    someone passes in front of only ever regains one side.
    """

    position: np.ndarray  # (2,) xy when last seen
    velocity: np.ndarray  # (2,) m/s
    seen_ns: int  # stamp of the frame it was last seen in
    stay_radius: float  # m
    origin: np.ndarray  # (2,) xy where the stay began
    narrowest: np.ndarray  # (2,) left, right extent (m) in the narrowest view of the stay
    widest: np.ndarray  # (2,) largest left, right extent since then
    stay_frames: int = 1  # frames it was seen in during the stay

    @classmethod
    def start(cls, position: np.ndarray, left: float, right: float, stamp_ns: int, stay_radius: float) -> Track:
        """A new track seen once, at ``position`` (2,) with ``left`` and ``right`` extents across the line of sight."""
        position = np.asarray(position, dtype=np.float64)
        sides = np.array([left, right], dtype=np.float64)
        return cls(position.copy(), np.zeros(2), int(stamp_ns), float(stay_radius), position.copy(), sides,
                   sides.copy())

    @property
    def spread(self) -> np.ndarray:
        """(2,) growth (m) of the left and right extents since the narrowest view of the stay."""
        return self.widest - self.narrowest

    def unseen_s(self, stamp_ns: int) -> float:
        """Seconds since it was last seen."""
        return (stamp_ns - self.seen_ns) * 1e-9

    def predict(self, stamp_ns: int, horizon_s: float) -> np.ndarray:
        """(2,) predicted xy at ``stamp_ns`` (extrapolating 0 to ``horizon_s`` seconds)."""
        return self.position + self.velocity * min(max(self.unseen_s(stamp_ns), 0.0), horizon_s)

    def observe(self, position: np.ndarray, left: float, right: float, stamp_ns: int, gain: float) -> None:
        """Seen at ``position`` (2,), extending ``left`` and ``right`` of its own line of sight, in the frame of
        ``stamp_ns``; the velocity is smoothed exponentially with ``gain``."""
        position = np.asarray(position, dtype=np.float64)
        dt = self.unseen_s(stamp_ns)
        if dt > 0.0:
            self.velocity += gain * ((position - self.position) / dt - self.velocity)
        self.position = position.copy()
        self.seen_ns = int(stamp_ns)
        moved = np.linalg.norm(position - self.origin) > self.stay_radius
        if moved:
            self.origin = position.copy()
        heading = np.arctan2(self.origin[1], self.origin[0])
        offset = float(np.array([-np.sin(heading), np.cos(heading)]) @ position)  # left of the origin's line
        sides = np.array([offset + left, right - offset])
        if moved or sides.sum() < self.narrowest.sum():
            self.narrowest, self.widest = sides, sides.copy()
        else:
            self.widest = np.maximum(self.widest, sides)
        self.stay_frames = 1 if moved else self.stay_frames + 1


def associate(predicted: np.ndarray, gates: np.ndarray, centroids: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """Greedy nearest-first assignment of tracks to clusters: (T,) cluster index per track, -1 if none.

    ``predicted`` (T, 2) track positions, ``gates`` (T,) their radii (m),
    ``centroids`` (K, 2) cluster positions, ``allowed`` (T, K) bool which pairs
    may match. The closest allowed pair within its gate is matched first.
    """
    cost = np.linalg.norm(predicted[:, None, :] - centroids[None, :, :], axis=2)
    cost = np.where(allowed & (cost <= gates[:, None]), cost, np.inf)
    assignment = np.full(len(predicted), -1, dtype=np.int64)
    for _ in range(min(cost.shape)):
        t, k = np.unravel_index(np.argmin(cost), cost.shape)
        if not np.isfinite(cost[t, k]):
            break
        assignment[t] = k
        cost[t, :] = np.inf
        cost[:, k] = np.inf
    return assignment
