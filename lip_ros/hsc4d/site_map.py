"""The map of the whole site, live (``/hsc4d/map``) and for the offline refinement (ROS-free).

The live odometry registers against kiss-icp's local map round the wearer
(bounded by its range). :class:`SiteMap` keeps every part of the site a capture
saw: each posed sweep's deskewed points placed by its pose in ``map``, one point per
voxel (the first to land in it), each remembering the sweep that placed it.
Rebuilding the map from another trajectory (the paper's S_opt, from the
refined one) is then moving each point by its own sweep's correction
(:meth:`SiteMap.moved`): the points stay as the sensor saw them, only where
each sweep stood changes, and no sweep has to be kept. Bounded: points past
``max_points`` are not kept and are counted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SiteMapConfig", "SiteMap"]

_BITS = 21  # per axis of a voxel's key: +-2^20 voxels (105 km at 0.1 m)
_RECENT = 200_000  # keys held in a set before they are merged into the sorted array


@dataclass(frozen=True)
class SiteMapConfig:
    """The voxel size, the farthest point kept from the sensor (farther ones are sparse and the least accurate)
    and the most points kept (20 B each)."""

    voxel_m: float = 0.1
    max_range_m: float = 30.0
    max_points: int = 4_000_000

    def __post_init__(self) -> None:
        if not (self.voxel_m > 0.0 and self.max_range_m > 0.0 and self.max_points > 0):
            raise ValueError(f"invalid {self}")


class SiteMap:
    """Points (float32, in ``map``) one per voxel, each with the index of the sweep that placed it."""

    def __init__(self, config: SiteMapConfig | None = None) -> None:
        self.config = config or SiteMapConfig()
        self._sorted = np.zeros(0, dtype=np.int64)  # the voxels' keys, merged
        self._recent: set[int] = set()  # ... and those added since
        self._points: list[np.ndarray] = []
        self._sweeps: list[int] = []  # the sweep of each chunk of points
        self.size = 0  #: points kept
        self.refused = 0  #: points in new voxels not kept: the map was full

    def _voxel_keys(self, points: np.ndarray) -> np.ndarray:
        cells = np.floor(points / self.config.voxel_m).astype(np.int64) + (1 << (_BITS - 1))
        return (cells[:, 0] << (2 * _BITS)) | (cells[:, 1] << _BITS) | cells[:, 2]

    def add(self, points_L: np.ndarray, T_map_L: np.ndarray, sweep: int) -> int:
        """A sweep's points (N, 3) in the sensor frame L, placed by its pose ``T_map_L`` (4, 4); how many landed
        in voxels not seen before (kept while there is room)."""
        points_L = np.asarray(points_L, dtype=np.float64)
        near = np.einsum("na,na->n", points_L, points_L) <= self.config.max_range_m**2
        points = points_L[near] @ T_map_L[:3, :3].T + T_map_L[:3, 3]
        keys, first = np.unique(self._voxel_keys(points), return_index=True)
        at = np.minimum(np.searchsorted(self._sorted, keys), max(len(self._sorted) - 1, 0))
        new = self._sorted[at] != keys if len(self._sorted) else np.ones(len(keys), dtype=bool)
        new[new] = np.fromiter((k not in self._recent for k in keys[new].tolist()), dtype=bool,
                               count=int(new.sum()))
        room = self.config.max_points - self.size
        if new.sum() > room:
            self.refused += int(new.sum()) - room
            new[np.flatnonzero(new)[room:]] = False
        if new.any():
            self._recent.update(keys[new].tolist())
            if len(self._recent) > _RECENT:
                recent = np.fromiter(self._recent, dtype=np.int64, count=len(self._recent))
                self._sorted = np.sort(np.concatenate([self._sorted, recent]))
                self._recent.clear()
            self._points.append(points[first[new]].astype(np.float32))
            self._sweeps.append(int(sweep))
            self.size += int(new.sum())
        return int(new.sum())

    def points(self) -> np.ndarray:
        """(M, 3) float32, in ``map``."""
        return np.concatenate(self._points) if self._points else np.zeros((0, 3), np.float32)

    def sweeps(self) -> np.ndarray:
        """(M,) the index of the sweep that placed each point."""
        return np.repeat(np.array(self._sweeps, dtype=np.int64), [len(p) for p in self._points])

    def moved(self, corrections: np.ndarray) -> np.ndarray:
        """(M, 3) float32: each point moved by its sweep's correction T_map'_map (K, 4, 4), indexed by the sweeps'
        indices (the refined pose times the inverse of the pose the point was placed with)."""
        out = []
        for points, sweep in zip(self._points, self._sweeps, strict=True):
            C = corrections[sweep]
            out.append((points @ C[:3, :3].T + C[:3, 3]).astype(np.float32))
        return np.concatenate(out) if out else np.zeros((0, 3), np.float32)
