"""What the HSC4D method knows of the hip LiDAR's mounting before it estimates it (ROS-free)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lip_ros.core.frames import hip_lidar_rotation

__all__ = ["HipMountPrior"]


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
    def pelvis_in_lidar(self) -> np.ndarray:
        """(3,) the pelvis origin in L."""
        return -self.R_M_L.T @ np.asarray(self.lever_m)
