"""The ground as a plane, fitted robustly (RANSAC, then least squares) to returns below a sensor (ROS-free)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GroundPlane", "fit_ground_plane"]


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
