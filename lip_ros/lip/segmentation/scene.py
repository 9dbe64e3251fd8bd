"""The static scene seen by a static LiDAR: its ground plane and a per-pixel background range image.

Part of the performer segmentation (:mod:`lip_ros.lip.segmentation`), ROS-free.

The ground is one plane, fitted robustly (RANSAC, then least squares) to
returns below the sensor. The background is learned online per pixel of the
organized range image: the *farthest surface seen consistently*. A pixel's
background starts unknown (0); a return farther than the background (or any
return while it is unknown) becomes a candidate, and a candidate seen in
``confirm_frames`` consecutive returns of the pixel replaces the background. A
nearer candidate (something placed in the scene) only replaces it after
``absorb_frames``, so people, who move, never become background; a performer
who stands still from the first frame does, until the caller ``forget``s those
pixels once it has found the performer. No-return pixels (range 0) change
nothing. A return that matches no known background (unknown, or farther) is
not background either: what was learned there may have been a person who
stood still for a moment in front of the open sky.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GroundPlane", "fit_ground_plane", "BackgroundModel"]


@dataclass(frozen=True)
class GroundPlane:
    """The plane ``normal . p + offset = 0`` in L, ``normal`` (3,) unit and pointing up (to the sensor's side)."""

    normal: np.ndarray
    offset: float

    def height(self, xyz: np.ndarray) -> np.ndarray:
        """(...) signed height above the plane of points (..., 3)."""
        return xyz @ self.normal.astype(xyz.dtype) + xyz.dtype.type(self.offset)

    @classmethod
    def from_coefficients(cls, coefficients: tuple[float, float, float, float]) -> GroundPlane:
        """The plane ``a x + b y + c z + d = 0`` with (a, b, c) pointing up (any length)."""
        a, b, c, d = (float(v) for v in coefficients)
        norm = float(np.linalg.norm([a, b, c]))
        if not np.isfinite(norm) or norm == 0.0 or c <= 0.0:
            raise ValueError(f"ground plane {coefficients} needs a finite normal with a positive z component")
        return cls(np.array([a, b, c]) / norm, d / norm)


def fit_ground_plane(
    xyz: np.ndarray,
    tolerance: float,
    max_tilt_deg: float,
    min_points: int,
    rng: np.random.Generator,
    iterations: int = 128,
    sample: int = 4096,
) -> GroundPlane | None:
    """The dominant near-horizontal plane below the sensor in points (N, 3) of L (non-finite ignored), or None.

    RANSAC over ``iterations`` plane hypotheses from a ``sample`` of the points
    below the sensor (normal within ``max_tilt_deg`` of +z, sensor above the
    plane), scored by inliers within ``tolerance``; the best is refined by least
    squares on all its inliers. None if fewer than ``min_points`` inliers.
    """
    low = np.asarray(xyz, dtype=np.float64)
    low = low[np.isfinite(low).all(axis=1) & (low[:, 2] < 0.0)]
    if len(low) < max(min_points, 3):
        return None
    pool = low[rng.choice(len(low), min(sample, len(low)), replace=False)]
    tri = pool[rng.integers(0, len(pool), (iterations, 3))]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normal, axis=1)
    ok = norm > 1e-9
    normal = normal[ok] / norm[ok, None]
    normal *= np.sign(normal[:, 2:3] + 1e-12)
    offset = -np.einsum("ij,ij->i", normal, tri[ok, 0])
    ok = (normal[:, 2] >= np.cos(np.deg2rad(max_tilt_deg))) & (offset > 0.0)
    if not ok.any():
        return None
    normal, offset = normal[ok], offset[ok]
    best = int(np.argmax((np.abs(pool @ normal.T + offset) < tolerance).sum(axis=0)))
    plane = GroundPlane(normal[best], float(offset[best]))
    for _ in range(2):  # least-squares refinement on the inliers of all low points
        inliers = low[np.abs(plane.height(low)) < tolerance]
        if len(inliers) < max(min_points, 3):
            return None
        centre = inliers.mean(axis=0)
        n = np.linalg.svd(inliers - centre, full_matrices=False)[2][2]
        n = n if n[2] > 0.0 else -n
        plane = GroundPlane(n, float(-n @ centre))
    count = int((np.abs(plane.height(low)) < tolerance).sum())
    return plane if count >= min_points else None


class BackgroundModel:
    """Per-pixel background range (metres, 0 = unknown) of an organized LiDAR, learned online."""

    def __init__(
        self, shape: tuple[int, int], margin_m: float, margin_per_m: float, confirm_frames: int, absorb_frames: int
    ) -> None:
        self.shape = shape
        self.range = np.zeros(shape, dtype=np.float32)
        self._candidate = np.zeros(shape, dtype=np.float32)
        self._count = np.zeros(shape, dtype=np.uint16)
        self._margin = (np.float32(margin_m), np.float32(margin_per_m))
        self._confirm = confirm_frames
        self._absorb = absorb_frames

    def margin(self, range_m: np.ndarray) -> np.ndarray:
        """Range difference (m) that separates two surfaces at ``range_m``."""
        return self._margin[0] + self._margin[1] * range_m

    def classify(self, range_m: np.ndarray, cols: np.ndarray | slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """Masks (nearer, unexplained) (H, C) of the returns ``range_m`` (0 = none) in columns ``cols``: nearer
        than a known background by the margin; matching no background otherwise (unknown, or farther: what was
        taken for background has left)."""
        bg = self.range[:, cols]
        seen = range_m > 0.0
        margin = self.margin(bg)
        nearer = seen & (range_m < bg - margin)
        return nearer, seen & ~nearer & ((bg == 0.0) | (range_m > bg + margin))

    def update(self, range_m: np.ndarray, exclude: np.ndarray) -> None:
        """Learn from a full range image (H, W) (0 = no return), except at pixels ``exclude`` (H, W) bool."""
        bg, cand, count = self.range.reshape(-1), self._candidate.reshape(-1), self._count.reshape(-1)
        r = range_m.reshape(-1)
        seen = (r > 0.0) & ~exclude.reshape(-1)
        new = seen & ((np.abs(r - bg) > self.margin(np.maximum(r, bg))) | (bg == 0.0))
        count[np.flatnonzero(seen & ~new & (count > 0))] = 0  # the background again: a candidate must start over
        i = np.flatnonzero(new)
        ri, ci = r[i], count[i]
        repeat = (ci > 0) & (np.abs(ri - cand[i]) <= self.margin(ri))
        ci = np.where(repeat, np.minimum(ci, np.iinfo(np.uint16).max - 1) + 1, 1).astype(np.uint16)
        cand[i[~repeat]] = ri[~repeat]
        promote = ci >= np.where(cand[i] > bg[i], self._confirm, self._absorb)
        bg[i[promote]] = cand[i[promote]]
        ci[promote] = 0
        count[i] = ci

    def forget(self, mask: np.ndarray) -> None:
        """Make the background of pixels ``mask`` (H, W) bool unknown again."""
        self.range[mask] = 0.0
        self._count[mask] = 0
