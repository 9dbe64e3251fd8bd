"""The hip LiDAR's rotation over a sweep from the suit's pelvis IMU (the odometry's deskew and initial guess),
ROS-free.

The LiDAR is rigid to the pelvis: R_I_L(t) = R_I_M(t) R_M_L, with R_I_M the
pelvis segment's orientation the suit reports (in its inertial frame I) and
R_M_L the mounting. Between two times only the relative rotation matters,
R_Lref_L(t) = R_M_L^T R_Mref_M(t) R_M_L, so I's unknown heading cancels, and an
error of the mounting only turns the rotation axis a little; R_Mref_M is the
IMU's angular rate integrated, which the orientation output's own errors do not
reach (the rate taken in the frame whose orientation the message gives, as
REP 145 has sensor_msgs/Imu: a driver that reports the segment's orientation
must report the rate in the segment's frame too), less the gyro's bias
measured while the wearer stands still (:class:`lip_ros.hsc4d.gyro_bias.GyroBias`).
The suit's samples are stamped on its own clock: they are used once the offset is known
(:meth:`PelvisRotation.set_offset`, from the jump), from a bounded buffer
(:class:`lip_ros.core.imu_sync.ImuSynchronizer`).
"""

from __future__ import annotations

import numpy as np

from lip_ros.core.frames import GRAVITY
from lip_ros.core.imu_sync import ImuSampleLike, ImuSynchronizer, SyncConfig
from lip_ros.core.rotations import quat_to_matrix
from lip_ros.hsc4d.gyro_bias import GyroBias, GyroBiasConfig

__all__ = ["PelvisRotation"]

_PELVIS = "pelvis"
_STEP_NS = 5_000_000  # the IMU's acceleration is integrated and checked at this step


class PelvisRotation:
    """The suit's pelvis orientations, buffered (``capacity`` samples), as the LiDAR's rotation over time once
    the suit's clock offset is set; use an instance as :data:`lip_ros.hsc4d.lidar_odometry.SweepRotation`."""

    def __init__(self, R_M_L: np.ndarray, capacity: int = 512, max_gap_ns: int = 50_000_000,
                 bias: GyroBiasConfig | None = None) -> None:
        self.R_M_L = np.asarray(R_M_L, dtype=np.float64)
        self._sync = ImuSynchronizer([_PELVIS], SyncConfig(capacity=capacity, max_gap_ns=max_gap_ns))
        self.offset_ns: int | None = None
        self.max_gap_ns = int(max_gap_ns)  #: samples further apart than this are not interpolated between
        self.gyro_bias = GyroBias(bias, max_gap_ns)  #: taken off the rate integrated in :meth:`__call__`

    def set_offset(self, offset_ns: int) -> None:
        """The suit's clock is ``offset_ns`` ahead of the LiDAR's (suit stamp = LiDAR stamp + offset)."""
        self._sync.set_latency(_PELVIS, int(offset_ns))
        self.offset_ns = int(offset_ns)

    def add(self, sample: ImuSampleLike) -> str | None:
        """One pelvis sample (stamped on the suit's clock); why it was rejected, None if kept."""
        reason = self._sync.add(_PELVIS, sample)
        if reason is None:
            self.gyro_bias.add(int(sample.stamp_ns), np.asarray(sample.gyro, dtype=np.float64))
        return reason

    def rotation_of_lidar(self, t_ns: np.ndarray) -> np.ndarray:
        """R_I_L (N, 3, 3) at LiDAR-clock times ``t_ns`` (N,); NaN where the buffer does not bracket them or the
        offset is not known."""
        t = np.asarray(t_ns, dtype=np.int64)
        out = np.full((t.size, 3, 3), np.nan)
        if self.offset_ns is None:
            return out
        quat = self._sync.orientations(_PELVIS, t + self.offset_ns)  # asked at the stamps the suit would give
        ok = np.isfinite(quat).all(axis=1)
        out[ok] = quat_to_matrix(quat[ok]) @ self.R_M_L
        return out

    def vertical_shift(self, v_ns: int, v_mps: float, t0_ns: int, t1_ns: int, step_ns: int = _STEP_NS
                       ) -> float | None:
        """How far the pelvis rises from ``t0_ns`` to ``t1_ns`` (LiDAR clock; m) if its vertical velocity was
        ``v_mps`` at ``v_ns``: the IMU's vertical acceleration (its specific force turned into the suit's
        gravity-aligned frame, less gravity) integrated twice, in steps of ``step_ns``; None where unknown. Over
        a sweep or two this is what carries a jump or a stair step that a constant velocity misses."""
        start, end = min(v_ns, t0_ns), max(t0_ns, t1_ns)
        t = np.unique(np.concatenate([np.arange(start, end, step_ns, dtype=np.int64), [v_ns, t0_ns, t1_ns, end]]))
        accel = self._acceleration(t)
        if accel is None:
            return None
        up = accel[:, 2]
        dt = np.diff(t) * 1e-9
        velocity = np.concatenate([[0.0], np.cumsum(0.5 * (up[1:] + up[:-1]) * dt)])
        velocity += v_mps - velocity[np.searchsorted(t, v_ns)]
        height = np.concatenate([[0.0], np.cumsum(0.5 * (velocity[1:] + velocity[:-1]) * dt)])
        return float(height[np.searchsorted(t, t1_ns)] - height[np.searchsorted(t, t0_ns)])

    def still(self, t_ns: int, window_s: float, max_accel_mps2: float, max_rate_rad_s: float) -> bool:
        """Whether the pelvis stood still over the ``window_s`` up to ``t_ns`` (LiDAR clock), a zero-velocity
        detector (after Skog et al. 2010, SHOE) on the IMU's own readings: at every ``_STEP_NS`` its specific force
        within ``max_accel_mps2`` of gravity along the window's mean direction and its angular rate under
        ``max_rate_rad_s``; False where unknown. The suit's orientation is not used, so its tilt error does not
        count as acceleration (1 deg leaks 0.17 m/s^2 of gravity sideways); the rate catches a wearer turning
        while moving on steadily, whose acceleration turns with the pelvis."""
        if self.offset_ns is None:
            return False
        stamp = np.arange(int(t_ns) - int(window_s * 1e9), int(t_ns) + 1, _STEP_NS, dtype=np.int64) + self.offset_ns
        force = self._sync.specific_forces(_PELVIS, stamp)
        rate = self._sync.angular_rates(_PELVIS, stamp)
        mean = force.mean(axis=0)
        size = float(np.linalg.norm(mean))
        if not (np.isfinite(size) and size > 0.0 and np.isfinite(rate).all()):
            return False
        return bool((np.linalg.norm(force - GRAVITY / size * mean, axis=1) < max_accel_mps2).all()
                    and (np.linalg.norm(rate, axis=1) < max_rate_rad_s).all())

    def _acceleration(self, t_ns: np.ndarray) -> np.ndarray | None:
        """The pelvis's acceleration (N, 3; m/s^2) in the suit's gravity-aligned frame at LiDAR-clock times
        ``t_ns`` (N,): its specific force turned into that frame, less gravity; None if any is unknown."""
        if self.offset_ns is None:
            return None
        stamp = t_ns + self.offset_ns
        quat = self._sync.orientations(_PELVIS, stamp)
        force = self._sync.specific_forces(_PELVIS, stamp)
        if not (np.isfinite(quat).all() and np.isfinite(force).all()):
            return None
        accel = np.einsum("nab,nb->na", quat_to_matrix(quat), force)
        accel[:, 2] -= GRAVITY
        return accel

    def __call__(self, t_ns: np.ndarray, ref_ns: int) -> np.ndarray:
        """R_Lref_L (N, 3, 3): the LiDAR at ``t_ns`` in the LiDAR at ``ref_ns``, the pelvis IMU's angular rate, less
        its bias measured standing still (:attr:`gyro_bias`), integrated between (over 0.1 s the rig's suit's
        orientations are 0.075 deg off at the median, the rate 0.005 deg); from its orientations where the samples
        between leave a gap; NaN where unknown."""
        t = np.asarray(t_ns, dtype=np.int64)
        if self.offset_ns is None:
            return np.full((t.size, 3, 3), np.nan)
        turned = self._sync.relative_rotations(_PELVIS, t + self.offset_ns, int(ref_ns) + self.offset_ns,
                                               self.gyro_bias.value)
        out = np.einsum("ba,nbc,cd->nad", self.R_M_L, turned, self.R_M_L)
        gap = ~np.isfinite(out).all(axis=(1, 2))
        if gap.any():
            rot = self.rotation_of_lidar(np.append(t[gap], ref_ns))
            out[gap] = np.einsum("ba,nbc->nac", rot[-1], rot[:-1])
        return out
