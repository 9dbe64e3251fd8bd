"""The HSC4D rig's LiDAR, worn on the hip: its pose follows the pelvis of the performer who carries it.

A :class:`HipMount` places the sensor rigidly in the pelvis frame (the
contract's model frame M at the pelvis: x the body's left, y up, z forward):
by default 0.15 m to the right of the pelvis and 0.1 m behind its centre
(outside the hip capsules), looking forward and tilted up 30 deg, as the
HSC4D rig's. :meth:`HipMount.poses` turns a performer's motion into the
sensor poses of :meth:`lip_ros.rig.lidar.OusterModel.scan_moving`, which casts
each column from the pose at its time and lets the performer's own body
block and return rays.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lip_ros.core.frames import hip_lidar_rotation
from lip_ros.core.rotations import axis_angle_to_matrix, rot_z
from lip_ros.rig.lidar import SensorPoses
from lip_ros.rig.trajectory import Trajectory

__all__ = ["HipMount"]


@dataclass(frozen=True)
class HipMount:
    """The LiDAR's pose in the pelvis frame: lever arm (m, in M), tilt up about L's y axis (deg), spin about L's z
    (deg: where its +x points, 0 where the body faces) and a small misalignment."""

    lever_m: np.ndarray = field(default_factory=lambda: np.array([-0.15, 0.0, -0.1]))
    tilt_up_deg: float = 30.0
    misalignment: np.ndarray = field(default_factory=lambda: np.zeros(3))  # rad, a rotation vector in L
    spin_deg: float = 0.0

    @property
    def R_M_L(self) -> np.ndarray:
        """(3, 3) the sensor frame L in the pelvis frame M: looking where the body faces, tilted up, turned by the
        misalignment, and spun about its own axis (as :func:`hip_lidar_rotation` spins it)."""
        return hip_lidar_rotation(self.tilt_up_deg) @ axis_angle_to_matrix(self.misalignment) @ rot_z(
            np.radians(self.spin_deg))

    @property
    def T_M_L(self) -> np.ndarray:
        """(4, 4) the sensor pose in the pelvis frame."""
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = self.R_M_L, self.lever_m
        return out

    def perturbed(self, rng: np.random.Generator, lever_m: float = 0.03, tilt_deg: float = 5.0,
                  turn_deg: float = 3.0) -> HipMount:
        """This mounting as a real one differs from its nominal values: the lever arm off by up to ``lever_m``
        per axis, the tilt by up to ``tilt_deg``, turned by up to ``turn_deg`` about each axis (uniform)."""
        return HipMount(self.lever_m + rng.uniform(-lever_m, lever_m, 3),
                        self.tilt_up_deg + float(rng.uniform(-tilt_deg, tilt_deg)),
                        self.misalignment + np.radians(rng.uniform(-turn_deg, turn_deg, 3)), self.spin_deg)

    def poses(self, motion: Trajectory, start_ns: int = 0) -> SensorPoses:
        """The sensor's poses (R_W_L, p_W_L) at stamps (ns; ``start_ns`` is the motion's time 0) of ``motion``."""

        def at(t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            body = motion.sample((np.asarray(t_ns) - start_ns) * 1e-9)
            R_W_M = body.local_rot[:, 0]
            return R_W_M @ self.R_M_L, body.root_pos + R_W_M @ self.lever_m

        return at
