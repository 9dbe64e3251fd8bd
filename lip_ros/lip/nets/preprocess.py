"""Network inputs of one LiDAR frame: normalised performer points and IMU readings in the view frame.

Points (the paper's section 4): subtract the arithmetic mean, then farthest
point sampling to a fixed count (``fpsample``, starting at the first point, so
the same cloud always gives the same sample); a cloud smaller than that is
tiled (repeated whole, then its first points), an empty one is the explicit
"no performer" case: zero points, ``present`` = 0, and the last seen mean
carried over.

View frame V (our addition): a rotation of L about z by the azimuth of the
point mean, so that the performer lies on +x of V. Points, bone orientations
and free accelerations enter the networks in V and their outputs are rotated
back to L, which makes the networks exactly invariant to where around the
LiDAR the performer is; only the view of the body (relative heading and the
range) matters. Gravity stays along -z.
"""

from __future__ import annotations

from dataclasses import dataclass

import fpsample
import numpy as np

__all__ = ["ACC_SCALE", "RANGE_SCALE", "FRAME_FEATURES", "IMU_FEATURES", "sample_points", "view_rotation",
           "FrameInput", "Preprocessor"]

#: Free accelerations are multiplied by this (m/s^2 -> about unit scale).
ACC_SCALE = 0.1
#: The horizontal range of the point mean is multiplied by this.
RANGE_SCALE = 0.1
#: Per-frame scalars beside the points: performer present (0/1), scaled range.
FRAME_FEATURES = 2
#: IMU input size: 4 bone rotations (row-major 3x3) then 4 free accelerations, in V.
IMU_FEATURES = 48


def sample_points(points: np.ndarray, num: int) -> np.ndarray:
    """(num, 3) points from a non-empty (N, 3) cloud: FPS if N > num, tiling if N < num."""
    n = len(points)
    if n == 0:
        raise ValueError("sample_points needs at least one point")
    if n > num:
        idx = fpsample.bucket_fps_kdline_sampling(np.ascontiguousarray(points, dtype=np.float32), num, h=5,
                                                  start_idx=0)
        return points[np.sort(idx)]
    return points[np.resize(np.arange(n), num)]


def view_rotation(mean: np.ndarray) -> np.ndarray:
    """R_L_V (3, 3): the rotation about z of L that turns +x towards the point ``mean``'s azimuth."""
    a = float(np.arctan2(mean[1], mean[0]))
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class FrameInput:
    """One frame as the networks see it, and what maps their outputs back to L."""

    points: np.ndarray  # (num, 3) float32 in V, mean-free (zeros if no performer)
    frame: np.ndarray  # (FRAME_FEATURES,) float32: present, scaled range
    imu: np.ndarray  # (IMU_FEATURES,) float32 in V
    mean: np.ndarray  # (3,) float64 point mean in L (the last seen one if no performer; NaN before any)
    R_L_V: np.ndarray  # (3, 3) float64

    @property
    def present(self) -> bool:
        """Whether the frame had performer points."""
        return bool(self.frame[0] > 0.5)


class Preprocessor:
    """Turns raw frames into :class:`FrameInput`, remembering the last point mean across frames."""

    def __init__(self, num_points: int) -> None:
        self.num_points = int(num_points)
        self.reset()

    def reset(self) -> None:
        """Forget the last point mean (a new sequence)."""
        self._mean = np.full(3, np.nan)

    def __call__(self, points: np.ndarray, imu_rot: np.ndarray, imu_acc: np.ndarray) -> FrameInput:
        """One frame: points (N, 3) in L (N may be 0), bone rotations (4, 3, 3) and free accelerations (4, 3) in L."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        points = points[np.isfinite(points).all(axis=1)]
        present = len(points) > 0
        if present:
            self._mean = points.mean(axis=0)
        known = np.isfinite(self._mean).all()
        R_L_V = view_rotation(self._mean) if known else np.eye(3)
        if present:
            local = sample_points((points - self._mean) @ R_L_V, self.num_points)
        else:
            local = np.zeros((self.num_points, 3))
        rng = float(np.hypot(self._mean[0], self._mean[1])) if known else 0.0
        rot_v = R_L_V.T @ np.asarray(imu_rot, dtype=np.float64)
        acc_v = np.asarray(imu_acc, dtype=np.float64) @ R_L_V
        return FrameInput(
            points=local.astype(np.float32),
            frame=np.array([float(present), rng * RANGE_SCALE], dtype=np.float32),
            imu=np.concatenate([rot_v.reshape(-1), ACC_SCALE * acc_v.reshape(-1)]).astype(np.float32),
            mean=self._mean.copy(),
            R_L_V=R_L_V,
        )
