"""The map of the whole site, live (``/hsc4d/map``) and for the offline refinement (ROS-free).

The live odometry registers against kiss-icp's local map round the wearer
(bounded by its range). :class:`SiteMap` keeps every part of the site a capture
saw: each posed sweep's deskewed points placed by its pose in ``map``, one point per
voxel, each remembering the sweep that placed it. A voxel keeps its nearest
sighting from at least ``sighting_from_m`` (8 m); nearer ones only until it
has one from that far (nearest first). Why not the first sighting: it is often
from 20-30 m as the wearer approached, and a sweep placed a fraction of a
degree off moves a point by its range times that (the ground the feet later
stood on was 1.7-2.8 cm high on held-out 1000, session 35). Why not the
nearest: measured (``hsc4d_eval``, docs/hsc4d/optimisation.md "Maps"), it made
the optimised bodies worse, where the nearest from 8 m made the live optimised
ones better on the held-out and development sets (the refined ones mixed) and
the maps sharper (p90 on every set); a guess the figures fit: the nearest sighting of the ground
under the feet is placed by the pose of about the time the wearer stands there,
so the contact term meets ground that carries the body's own pose error.
Rebuilding the map from another trajectory (the paper's S_opt, from the
refined one) is then moving each point by its own sweep's shift
(:meth:`SiteMap.shifted`): the points stay as the sensor saw them, only where
each sweep stood changes, and no sweep has to be kept. Bounded: points in new
voxels past ``max_points`` are not kept and are counted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["SiteMapConfig", "SiteMap"]

_BITS = 21  # per axis of a voxel's key: +-2^20 voxels (105 km at 0.1 m)
_RECENT = 200_000  # voxels in the small sorted index before it is merged into the large one


@dataclass(frozen=True)
class SiteMapConfig:
    """The voxel size, the farthest point kept from the sensor (farther ones are sparse and the least accurate),
    the range from which a voxel's nearest sighting is kept (nearer ones rank behind) and the most points kept
    (32 B each)."""

    voxel_m: float = 0.1
    max_range_m: float = 30.0
    max_points: int = 4_000_000
    sighting_from_m: float = 8.0

    def __post_init__(self) -> None:
        if not (self.voxel_m > 0.0 and self.max_range_m > 0.0 and 0.0 <= self.sighting_from_m <= self.max_range_m
                and 0 < self.max_points < 2**31):
            raise ValueError(f"invalid {self}")


class SiteMap:
    """Points (float32, in ``map``) one per voxel, each with the rank of its sighting (its range; behind every
    sighting from ``sighting_from_m`` on if nearer) and the index of the sweep that placed it."""

    def __init__(self, config: SiteMapConfig | None = None) -> None:
        self.config = config or SiteMapConfig()
        # two sorted indexes of the voxels' keys and each one's point: a large one and one of the voxels added
        # since it was last merged into it (inserting into the small one each sweep is cheap)
        self._index = [(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int32))] * 2
        self._points = np.zeros((0, 3), dtype=np.float32)  # capacity grows by doubling, up to max_points
        self._rank = np.zeros(0, dtype=np.float32)
        self._sweep = np.zeros(0, dtype=np.int32)
        self.size = 0  #: points kept
        self.refused = 0  #: points in new voxels not kept: the map was full
        self.replaced = 0  #: points replaced by a better sighting of their voxel

    def _voxel_keys(self, points: np.ndarray) -> np.ndarray:
        cells = np.floor(points / self.config.voxel_m).astype(np.int64) + (1 << (_BITS - 1))
        return (cells[:, 0] << (2 * _BITS)) | (cells[:, 1] << _BITS) | cells[:, 2]

    def add(self, points_L: np.ndarray, T_map_L: np.ndarray, sweep: int) -> int:
        """A sweep's points (N, 3) in the sensor frame L, placed by its pose ``T_map_L`` (4, 4): in each voxel its
        best sighting (the nearest from ``sighting_from_m`` on, else the nearest), kept where the voxel is new
        (while there is room) or its point ranks behind; how many landed in voxels not seen before."""
        points_L = np.asarray(points_L, dtype=np.float64)
        ranges = np.sqrt(np.einsum("na,na->n", points_L, points_L))
        near = ranges <= self.config.max_range_m
        points, ranges = points_L[near] @ T_map_L[:3, :3].T + T_map_L[:3, 3], ranges[near].astype(np.float32)
        c = self.config
        ranks = np.where(ranges < c.sighting_from_m, ranges + np.float32(2 * c.max_range_m), ranges)  # lower: better
        keys = self._voxel_keys(points)
        pick = _best_per_voxel(keys, ranks)
        keys = keys[pick]
        slots = self._lookup(keys)
        seen = slots >= 0
        better = seen.copy()
        better[seen] = ranks[pick[seen]] < self._rank[slots[seen]]
        self._put(slots[better], points[pick[better]], ranks[pick[better]], sweep)
        self.replaced += int(better.sum())
        new = np.flatnonzero(~seen)
        room = c.max_points - self.size
        if len(new) > room:
            self.refused += len(new) - room
            new = new[:room]
        if len(new):
            slots = np.arange(self.size, self.size + len(new), dtype=np.int32)
            self._grow(self.size + len(new))
            self._put(slots, points[pick[new]], ranks[pick[new]], sweep)
            self._index[1] = _inserted(self._index[1], keys[new], slots)  # keys[new]: sorted, as keys are
            self.size += len(new)
            if len(self._index[1][0]) > _RECENT:
                merged = _inserted(self._index[0], *self._index[1])
                self._index = [merged, (merged[0][:0], merged[1][:0])]
        return len(new)

    def _lookup(self, keys: np.ndarray) -> np.ndarray:
        """(K,) the point of each voxel key (K,), -1 for a voxel not seen before."""
        slots = np.full(len(keys), -1, dtype=np.int64)
        for index_keys, index_slots in self._index:
            if len(index_keys):
                at = np.minimum(np.searchsorted(index_keys, keys), len(index_keys) - 1)
                hit = index_keys[at] == keys
                slots[hit] = index_slots[at[hit]]
        return slots

    def _put(self, slots: np.ndarray, points: np.ndarray, ranks: np.ndarray, sweep: int) -> None:
        self._points[slots] = points
        self._rank[slots] = ranks
        self._sweep[slots] = sweep

    def _grow(self, size: int) -> None:
        if size <= len(self._rank):
            return
        capacity = min(max(size, 2 * len(self._rank), 4096), self.config.max_points)
        self._points = np.concatenate([self._points, np.zeros((capacity - len(self._points), 3), np.float32)])
        self._rank = np.concatenate([self._rank, np.zeros(capacity - len(self._rank), np.float32)])
        self._sweep = np.concatenate([self._sweep, np.zeros(capacity - len(self._sweep), np.int32)])

    def points(self) -> np.ndarray:
        """(M, 3) float32, in ``map`` (a copy)."""
        return self._points[:self.size].copy()

    def sweeps(self) -> np.ndarray:
        """(M,) the index of the sweep that placed each point."""
        return self._sweep[:self.size].astype(np.int64)

    def near(self, xy: np.ndarray, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
        """The points within ``radius_m`` horizontally of any of the positions ``xy`` (P, 2) in ``map``: (M, 3)
        float32 (a copy) and the index of the sweep that placed each (M,)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        points, sweeps = self._points[:self.size], self._sweep[:self.size]
        if not len(xy) or not self.size:
            return np.zeros((0, 3), dtype=np.float32), np.zeros(0, dtype=np.int64)
        lo, hi = xy.min(axis=0) - radius_m, xy.max(axis=0) + radius_m
        box = np.flatnonzero(((points[:, :2] >= lo) & (points[:, :2] <= hi)).all(axis=1))
        distance, _ = cKDTree(xy).query(points[box, :2], distance_upper_bound=radius_m)
        keep = box[distance <= radius_m]
        return points[keep].copy(), sweeps[keep].astype(np.int64)

    def shifted(self, shifts: np.ndarray) -> np.ndarray:
        """(M, 3) float32: each point moved by its sweep's shift (K, 3), indexed by the sweeps' indices (the
        refinement moves each sweep to its refined pose, its attitude kept, as ``refinement.sweep_shifts`` says)."""
        return (self._points[:self.size] + shifts[self._sweep[:self.size]]).astype(np.float32)


def _inserted(index: tuple[np.ndarray, np.ndarray], keys: np.ndarray, slots: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """A sorted index (keys, slots) with sorted ``keys`` not in it and their ``slots`` inserted in order."""
    at = np.searchsorted(index[0], keys)
    return np.insert(index[0], at, keys), np.insert(index[1], at, slots)


def _best_per_voxel(keys: np.ndarray, ranks: np.ndarray) -> np.ndarray:
    """The index of each voxel's best-ranked point (the lowest rank, the first of equals), in order of the keys (one
    sort, as ``np.unique``'s, not two)."""
    order = np.argsort(keys, kind="stable")
    sorted_keys, sorted_ranks = keys[order], ranks[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = sorted_keys[1:] != sorted_keys[:-1]
    group = np.cumsum(first) - 1
    best = np.flatnonzero(sorted_ranks == np.minimum.reduceat(sorted_ranks, np.flatnonzero(first))[group])
    return order[best[np.r_[True, group[best[1:]] != group[best[:-1]]]]] if len(best) else order[:0]
