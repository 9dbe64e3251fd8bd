"""The hip LiDAR's height above the ground it stands on, from one sweep alone (for the jump sync), ROS-free.

Before the suit's clock is known the odometry has no IMU to deskew with, and
the jump (a vertical hop of 0.2-0.4 m in 0.3-0.5 s) is exactly where the
constant-velocity model fails. The jump's height curve does not need the
odometry: the wearer jumps in place on the ground where the A-pose stood, so
each sweep's ground plane (RANSAC in a frame levelled with the body's axis,
which for a standing wearer is gravity's to a few degrees) gives the sensor's
height above it, at the mean time of the plane's points (the ground is seen
behind and beside the wearer, in a part of the sweep only).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lip_ros.core.frames import UP_M, level_rotation
from lip_ros.core.ground_plane import fit_ground_plane
from lip_ros.hsc4d.mount import HipMountPrior

__all__ = ["SweepHeightConfig", "sweep_height"]


@dataclass(frozen=True)
class SweepHeightConfig:
    """Which points may be the ground under the wearer."""

    radius_m: float = 5.0  # horizontal distance from the sensor
    tolerance_m: float = 0.04
    # of the plane from the body's axis through the nominal mounting: a mounting 20 deg off its nominal tilt, and the
    # wearer leaning in the A-pose, still find the ground (at 20 deg a mounting 18 deg off lost the jump)
    max_tilt_deg: float = 35.0
    min_points: int = 100

    def __post_init__(self) -> None:
        if not (self.radius_m > 0.0 and self.tolerance_m > 0.0 and 0.0 < self.max_tilt_deg < 90.0
                and self.min_points >= 3):
            raise ValueError(f"invalid {self}")


def sweep_height(points: np.ndarray, point_ns: np.ndarray, rng: np.random.Generator,
                 mount: HipMountPrior | None = None, config: SweepHeightConfig | None = None
                 ) -> tuple[int, float] | None:
    """(time ns, height m) of the sensor above the ground plane in one sweep's points (N, 3) in L, seen at
    ``point_ns`` (N,), the wearer's own returns removed; None if no ground plane is found."""
    c = config or SweepHeightConfig()
    m = mount or HipMountPrior()
    R_L_V = level_rotation(m.R_M_L.T @ UP_M)  # V: z along the body's axis
    local = np.asarray(points, dtype=np.float64) @ R_L_V
    near = np.hypot(local[:, 0], local[:, 1]) <= c.radius_m
    plane = fit_ground_plane(local[near], c.tolerance_m, c.max_tilt_deg, c.min_points, rng)
    if plane is None:
        return None
    on = np.abs(plane.height(local)) < c.tolerance_m
    on &= near
    return int(np.mean(np.asarray(point_ns)[on].astype(np.float64))), float(plane.offset)
