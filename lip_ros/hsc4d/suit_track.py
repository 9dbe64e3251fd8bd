"""The suit's own root trajectory (``/mocap/odometry``) as the hip LiDAR's motion between two LiDAR-clock times,
ROS-free.

The suit's dead reckoning drifts in heading and knows nothing of stairs or
slopes, but over one sweep (50-100 ms) its *relative* motion is good: the
pelvis's displacement and turn in the pelvis's own frame, T_P0_P1 = T_I_P0^-1
T_I_P1, where the suit's unknown, drifting heading cancels. The LiDAR, rigid to
the pelvis with the mounting T_M_L, moved by T_L0_L1 = T_M_L^-1 T_P0_P1 T_M_L.
The odometry uses it for its initial guess and to refuse registrations that
disagree with it (the paper's speed rule, :meth:`SuitTrack.horizontal_motion`
splits off the vertical, which the suit does not know). The samples are
stamped on the suit's clock and used once its offset from the LiDAR's is known
(from the jump), in a bounded buffer.
"""

from __future__ import annotations

from bisect import bisect_left
from collections import deque

import numpy as np

from lip_ros.core.rotations import geodesic_angle, nearest_axes_turn, quat_to_matrix
from lip_ros.hsc4d.mount import HipMountPrior

__all__ = ["SuitTrack", "Sample", "axes_columns", "odometry_axes", "pose_between"]

#: A suit odometry sample: its stamp (ns), the pelvis position (3,) and unit orientation (x, y, z, w).
Sample = tuple[int, np.ndarray, np.ndarray]


def pose_between(t_ns: int, earlier: Sample, later: Sample) -> np.ndarray:
    """T (4, 4) at ``t_ns`` between two samples: the position linearly, the orientation by normalised lerp."""
    (s0, p0, q0), (s1, p1, q1) = earlier, later
    w = (t_ns - s0) / (s1 - s0)
    q = (1.0 - w) * q0 + w * (q1 if q0 @ q1 >= 0.0 else -q1)
    out = np.eye(4)
    out[:3, :3] = quat_to_matrix(q / np.linalg.norm(q))
    out[:3, 3] = (1.0 - w) * p0 + w * p1
    return out


def odometry_axes(R_odometry: np.ndarray, R_I_P: np.ndarray, max_tilt_deg: float) -> tuple[float, np.ndarray | None]:
    """How far (deg) the suit odometry's pelvis up is from the pelvis IMU's at one moment (``R_odometry`` (3, 3),
    the odometry's orientation, and ``R_I_P``, the pelvis segment's, both in the suit's world), and, when farther
    than ``max_tilt_deg`` and the two differ by a turn of the axes within it (another axis convention: a ROS
    base_link's x forward, y left, z up, say), that turn: the segment's axes in the odometry's
    (``R_odometry @ axes`` is the segment's orientation); else None."""
    up = np.array([0.0, 0.0, 1.0])
    tilt = float(np.degrees(np.arccos(np.clip((R_I_P.T @ up) @ (R_odometry.T @ up), -1.0, 1.0))))
    if tilt <= max_tilt_deg:
        return tilt, None
    between = R_odometry.T @ R_I_P
    axes = nearest_axes_turn(between)
    return tilt, axes if np.degrees(geodesic_angle(axes, between)) <= max_tilt_deg else None


def axes_columns(axes: np.ndarray) -> str:
    """A turn of the axes (3, 3) as where each axis goes, e.g. "+y, +z, +x"."""
    return ", ".join("".join(("+" if v > 0 else "-") + "xyz"[i] for i, v in enumerate(c) if v) for c in axes.T)


class SuitTrack:
    """The last ``capacity`` suit odometry samples; positions interpolated linearly and orientations by
    normalised lerp between samples at most ``max_gap_ns`` apart (100 Hz: the turn between two is tiny)."""

    def __init__(self, mount: HipMountPrior | None = None, capacity: int = 1024,
                 max_gap_ns: int = 50_000_000) -> None:
        if capacity < 2 or max_gap_ns <= 0:
            raise ValueError(f"capacity {capacity} and max_gap_ns {max_gap_ns} must be >= 2 and > 0")
        self.mount = mount or HipMountPrior()
        self.max_gap_ns = int(max_gap_ns)
        self._samples: deque[Sample] = deque(maxlen=capacity)
        self._stamps: deque[int] = deque(maxlen=capacity)  # the samples' stamps, searched by bisection
        self.offset_ns: int | None = None
        self.T_M_L = self.mount.T_M_L  #: the mounting used: the nominal one until :meth:`set_mount`
        self._T_L_M = self.mount.T_L_M
        self.axes: np.ndarray | None = None  #: the pelvis's axes in the odometry's orientation's, if not the same
        self.stride_scale = 1.0  #: the suit's horizontal steps times this in :meth:`horizontal_motion` (LiDAR per suit)

    def set_mount(self, T_M_L: np.ndarray) -> None:
        """Use this sensor pose (4, 4) in the pelvis frame from now on (e.g. levelled with gravity at the start)."""
        self.T_M_L = np.array(T_M_L, dtype=np.float64)
        self._T_L_M = np.linalg.inv(self.T_M_L)

    def set_offset(self, offset_ns: int) -> None:
        """The suit's clock is ``offset_ns`` ahead of the LiDAR's (suit stamp = LiDAR stamp + offset)."""
        self.offset_ns = int(offset_ns)

    def add(self, stamp_ns: int, position: np.ndarray, quat: np.ndarray) -> str | None:
        """One sample on the suit's clock: the pelvis position (3,) and orientation (x, y, z, w) in the suit's
        world; why it was rejected (not finite, not a unit quaternion, not after the newest), None if kept."""
        position = np.asarray(position, dtype=np.float64)
        quat = np.asarray(quat, dtype=np.float64)
        if not (np.isfinite(position).all() and np.isfinite(quat).all()):
            return "not finite"
        norm = float(np.linalg.norm(quat))
        if abs(norm - 1.0) > 1e-3:
            return f"quaternion norm {norm:.3g}"
        if self._samples and stamp_ns <= self._samples[-1][0]:
            return "not after the newest sample"
        self._samples.append((int(stamp_ns), position, quat / norm))
        self._stamps.append(int(stamp_ns))
        return None

    def pelvis(self, t_ns: int) -> np.ndarray | None:
        """T_I_P (4, 4) at the LiDAR-clock time ``t_ns``; None without the offset or two samples around it."""
        if self.offset_ns is None or len(self._samples) < 2:
            return None
        t = int(t_ns) + self.offset_ns
        hi = bisect_left(self._stamps, t)
        if hi == 0 or hi == len(self._stamps):
            if hi == 0 and self._stamps[0] == t:
                hi = 1
            else:
                return None
        earlier, later = self._samples[hi - 1], self._samples[hi]
        if later[0] - earlier[0] > self.max_gap_ns:
            return None
        out = pose_between(t, earlier, later)
        if self.axes is not None:  # an odometry oriented in other axes than the pelvis segment's
            out[:3, :3] = out[:3, :3] @ self.axes
        return out

    def lidar_motion(self, t0_ns: int, t1_ns: int) -> np.ndarray | None:
        """T_L0_L1 (4, 4): the LiDAR at ``t1_ns`` in the LiDAR at ``t0_ns`` as the suit has it; None if unknown."""
        a, b = self.pelvis(t0_ns), self.pelvis(t1_ns)
        return None if a is None or b is None else self._lidar_between(a, b)

    def up_in_lidar(self, t_ns: int) -> np.ndarray | None:
        """(3,) gravity's up in the LiDAR frame at ``t_ns`` (the suit's z, through the mounting); None if
        unknown."""
        a = self.pelvis(t_ns)
        return None if a is None else self._up_in_lidar(a)

    def horizontal_motion(self, t0_ns: int, t1_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The LiDAR's displacement from ``t0_ns`` to ``t1_ns`` in the LiDAR frame at ``t0_ns``, the pelvis's
        horizontal step (in the suit's world, z up; the pose graph scales the pelvis frame's x and z, the same while
        the pelvis stands upright) scaled by :attr:`stride_scale`, with its vertical part removed, and that frame's
        up (3,) each; None if unknown."""
        a, b = self.pelvis(t0_ns), self.pelvis(t1_ns)
        if a is None or b is None:
            return None
        b[:2, 3] = a[:2, 3] + self.stride_scale * (b[:2, 3] - a[:2, 3])  # the suit's world: z up
        d, up = self._lidar_between(a, b)[:3, 3], self._up_in_lidar(a)
        return d - (d @ up) * up, up

    def _lidar_between(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """T_L0_L1 (4, 4) from the pelvis poses ``a`` at t0 and ``b`` at t1 (4, 4; the suit's world)."""
        return self._T_L_M @ np.linalg.inv(a) @ b @ self.T_M_L

    def _up_in_lidar(self, a: np.ndarray) -> np.ndarray:
        """(3,) gravity's up in the LiDAR frame where the pelvis pose is ``a`` (4, 4)."""
        return self._T_L_M[:3, :3] @ a[:3, :3].T @ np.array([0.0, 0.0, 1.0])
