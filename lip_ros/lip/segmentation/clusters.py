"""Clustering of the returns of an organized range image, and cluster shape descriptors.

Part of the performer segmentation (:mod:`lip_ros.lip.segmentation`), ROS-free.

Two returns belong to the same cluster if a chain of neighbours joins them: a
neighbour lies at most ``reach`` rows and columns away in the image (so one
missing pixel does not split a thin limb) and within a 3D distance that grows
with the pixels' spacing at that range, ``link_m + link_spacing * r * angle``
(``angle`` the angle between the two beams). Columns wrap around when the
image is the full sweep. Components come from ``scipy.sparse.csgraph``; all
work is vectorised over the points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

__all__ = ["Clusters", "link_components", "describe_clusters"]


@dataclass(frozen=True)
class Clusters:
    """Descriptors of K clusters of points (horizontal quantities in the xy plane of L)."""

    labels: np.ndarray  # (N,) cluster index of each point
    count: np.ndarray  # (K,) points
    centroid: np.ndarray  # (K, 2) mean xy
    top: np.ndarray  # (K,) highest point above the ground (m)
    bottom: np.ndarray  # (K,) lowest point above the ground (m)
    left: np.ndarray  # (K,) horizontal extent to the left of the line of sight to the centroid (m)
    right: np.ndarray  # (K,) ... to its right
    depth: np.ndarray  # (K,) horizontal extent along that line (m)
    cut_below: np.ndarray | None = None  # (K,) bool: the lower edge is hidden (set by the segmenter; None: unknown)

    def __len__(self) -> int:
        return len(self.count)

    @property
    def width(self) -> np.ndarray:
        """(K,) horizontal extent across the line of sight (m)."""
        return self.left + self.right


def _forward_offsets(reach: int) -> np.ndarray:
    """(M, 2) pixel offsets (rows, cols) covering every neighbour pair within ``reach`` exactly once."""
    offsets = [(0, dc) for dc in range(1, reach + 1)]
    offsets += [(dr, dc) for dr in range(1, reach + 1) for dc in range(-reach, reach + 1)]
    return np.array(offsets, dtype=np.int64)


def link_components(
    rows: np.ndarray,
    cols: np.ndarray,
    xyz: np.ndarray,
    range_m: np.ndarray,
    grid: tuple[int, int],
    wrap: bool,
    pixel_angle: tuple[float, float],
    link_m: float,
    link_spacing: float,
    reach: int,
) -> tuple[np.ndarray, int]:
    """Cluster labels (N,) and their number for points at pixels (``rows``, ``cols``) of a ``grid`` (H, C).

    ``xyz`` (N, 3) and ``range_m`` (N,) are the points; ``pixel_angle`` the
    angles (rad) between neighbouring rows and columns; ``wrap``: column C-1
    neighbours column 0.
    """
    n = len(rows)
    if n == 0:
        return np.zeros(0, dtype=np.int64), 0
    height, width = grid
    index = np.full(grid, -1, dtype=np.int64)
    index[rows, cols] = np.arange(n)
    offsets = _forward_offsets(reach)
    r2 = rows[:, None] + offsets[:, 0]
    c2 = cols[:, None] + offsets[:, 1]
    if wrap:
        c2 %= width
        inside = r2 < height
    else:
        inside = (r2 < height) & (c2 >= 0) & (c2 < width)
    neighbour = np.full(r2.shape, -1, dtype=np.int64)
    neighbour[inside] = index[r2[inside], c2[inside]]
    head, which = np.nonzero(neighbour >= 0)
    tail = neighbour[head, which]
    spacing = np.hypot(offsets[:, 0] * pixel_angle[0], offsets[:, 1] * pixel_angle[1])
    limit = link_m + link_spacing * range_m[head] * spacing[which]
    square = np.zeros(len(head), dtype=xyz.dtype)
    for axis in np.ascontiguousarray(xyz.T):  # 1-D gathers: much faster than rows of (N, 3)
        d = axis[head] - axis[tail]
        square += d * d
    close = square <= limit * limit
    head, tail = head[close], tail[close]  # head ascending (np.nonzero's order): CSR rows as they are
    indptr = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(np.bincount(head, minlength=n), out=indptr[1:])
    graph = csr_matrix((np.ones(len(head)), tail.astype(np.int32), indptr), shape=(n, n))
    k, labels = connected_components(graph, directed=False)
    return labels.astype(np.int64), int(k)


def describe_clusters(labels: np.ndarray, k: int, xyz: np.ndarray, height: np.ndarray) -> Clusters:
    """Shape descriptors of the ``k`` clusters ``labels`` (N,) of points ``xyz`` (N, 3) with ground ``height`` (N,)."""
    count = np.bincount(labels, minlength=k)
    if k == 0:
        empty = np.zeros(0)
        return Clusters(labels, count, np.zeros((0, 2)), empty, empty, empty, empty, empty)
    safe = np.maximum(count, 1)
    centroid = np.stack([np.bincount(labels, xyz[:, a], minlength=k) / safe for a in (0, 1)], axis=1)
    azimuth = np.arctan2(centroid[:, 1], centroid[:, 0])
    along = np.stack([np.cos(azimuth), np.sin(azimuth)], axis=1)[labels]
    radial = np.einsum("ij,ij->i", xyz[:, :2], along)
    across = xyz[:, 1] * along[:, 0] - xyz[:, 0] * along[:, 1]  # to the left, seen from the sensor
    order = np.argsort(labels, kind="stable")
    starts = np.concatenate([[0], np.cumsum(count)[:-1]])

    def extent(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = values[order]
        return np.minimum.reduceat(v, starts), np.maximum.reduceat(v, starts)

    bottom, top = extent(height)
    radial_lo, radial_hi = extent(radial)
    across_lo, across_hi = extent(across)
    return Clusters(labels, count, centroid, top, bottom, across_hi, -across_lo, radial_hi - radial_lo)
