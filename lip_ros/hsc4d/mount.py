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
(:class:`MountYawEstimator`). The lever arm stays nominal (its error, a few
centimetres, moves the pelvis estimate as the body turns).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lip_ros.core.frames import hip_lidar_rotation
from lip_ros.core.rotations import axis_angle_to_matrix

__all__ = ["HipMountPrior", "rotation_between", "levelled_mount_rotation", "MountYawEstimator"]


@dataclass(frozen=True)
class HipMountPrior:
    """The nominal mounting: lever arm (m, the sensor's origin in the pelvis frame M: x left, y up, z forward)
    and tilt up (deg) of a sensor looking where the body faces."""

    lever_m: tuple[float, float, float] = (-0.15, 0.0, -0.1)
    tilt_up_deg: float = 30.0

    @property
    def R_M_L(self) -> np.ndarray:
        """(3, 3) the nominal sensor frame L in the pelvis frame M."""
        return hip_lidar_rotation(self.tilt_up_deg)

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

    @property
    def pelvis_in_lidar(self) -> np.ndarray:
        """(3,) the pelvis origin in L."""
        return -self.R_M_L.T @ np.asarray(self.lever_m)


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

