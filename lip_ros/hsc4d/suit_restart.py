"""A new capture on the same sensors, told from a clock step: a bag played again, the suit's driver restarted
(ROS-free).

A clock that steps back (:mod:`lip_ros.core.clock`) is either the same capture
going on (a PTP step: the wearer is where they were a moment before) or a new
one (a bag played in a loop: the wearer is back where the capture began, and
the suit's own odometry with them). The suit's odometry tells the two apart:
across the step the pelvis it places cannot move farther than it can between
two samples. :class:`SuitRestart` watches that stream and says when a step
back comes with a jump of the pelvis: a new capture, which the HSC4D nodes
start again from (its jump syncs the clocks again). A loop whose end is within
the limits of its start goes on as one capture, which is where the wearer then
is; a step whose samples around it were lost for long may be taken for a new
capture (a PTP step at walking speed: after about 0.3 s of lost samples).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lip_ros.core.clock import stepped_back
from lip_ros.core.rotations import geodesic_angle, quat_to_matrix

__all__ = ["SuitRestartConfig", "SuitRestart"]


@dataclass(frozen=True)
class SuitRestartConfig:
    """How far the suit's pelvis may move across a clock step back and still be the same capture."""

    #: metres: a run covers this in about 0.1 s, a walk in 0.3 s (the suit's samples are 10 ms apart)
    max_move_m: float = 0.5
    #: degrees: a spin turns the pelvis this far in about 0.1 s
    max_turn_deg: float = 45.0

    def __post_init__(self) -> None:
        if not (self.max_move_m > 0.0 and 0.0 < self.max_turn_deg < 180.0):
            raise ValueError(f"invalid {self}")


class SuitRestart:
    """Watches the suit's own odometry (pelvis position and orientation, on its own clock) for a new capture."""

    def __init__(self, config: SuitRestartConfig | None = None) -> None:
        self.config = config or SuitRestartConfig()
        self._last: tuple[int, np.ndarray, np.ndarray] | None = None  # stamp, position, quaternion of the last sample

    def add(self, stamp_ns: int, position: np.ndarray, quat: np.ndarray) -> str | None:
        """One sample of the suit's odometry as its clock stamped it: why a new capture begins with it (its clock
        stepped back and the pelvis jumped), or None. Samples that are not finite, or whose quaternion is zero, are
        passed over (their stream rejects them)."""
        position, quat = np.asarray(position, dtype=np.float64), np.asarray(quat, dtype=np.float64)
        norm = float(np.linalg.norm(quat))
        if not (np.isfinite(position).all() and np.isfinite(quat).all() and norm > 0.0):
            return None
        last, self._last = self._last, (int(stamp_ns), position, quat / norm)
        if last is None:
            return None
        step_ns = stepped_back(int(stamp_ns), last[0])
        if not step_ns:  # every sample but at a step: nothing more to do
            return None
        moved = float(np.linalg.norm(position - last[1]))
        turned = float(np.degrees(geodesic_angle(quat_to_matrix(last[2]), quat_to_matrix(quat / norm))))
        if moved <= self.config.max_move_m and turned <= self.config.max_turn_deg:
            return None
        return (f"the suit's clock stepped back {step_ns * 1e-9:.3f} s and its pelvis jumped {moved:.2f} m, "
                f"{turned:.0f} deg (more than {self.config.max_move_m:g} m or {self.config.max_turn_deg:g} deg)")
