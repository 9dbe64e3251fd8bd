"""What the rig's parts exchange: a body pose over time, in the LiDAR frame L."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lip_ros.core.skeleton import Skeleton, forward_kinematics


@dataclass
class BodyPose:
    """Poses of one performer at T times (see docs/conventions.md).

    ``local_rot[:, 0]`` is the pelvis orientation in L, ``root_pos`` the pelvis
    position in L.
    """

    root_pos: np.ndarray  # (T, 3)
    local_rot: np.ndarray  # (T, 24, 3, 3)

    def global_pose(self, skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations (T, 24, 3, 3) and joint positions (T, 24, 3) in L."""
        return forward_kinematics(skeleton, self.local_rot, self.root_pos)


class Trajectory(Protocol):
    """A performer's motion as a continuous function of time."""

    skeleton: Skeleton  # the performer's (scaled) skeleton

    def sample(self, t: np.ndarray) -> BodyPose:
        """Pose at times ``t`` (seconds since the capture started, float64, shape (T,))."""
        ...
