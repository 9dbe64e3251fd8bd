"""sensor_msgs/Imu <-> ``ImuSample`` (validated numpy arrays, integer-ns stamp).

REP-145: a component whose covariance[0] is -1 is "not provided"; in an
``ImuSample`` its values and covariance are NaN. A covariance of all zeros
means "unknown" and is kept as zeros.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lip_msgs_py._validate import QUAT_UNIT_TOLERANCE, covariance_matrix, finite_array, unit_quaternions
from lip_msgs_py.backend import Backend
from lip_msgs_py.geometry import quat_of, quaternion_msg, vector3_msg, xyz_of
from lip_msgs_py.stamps import read_header

__all__ = ["ImuSample", "imu_sample", "imu_to_msg", "msg_to_imu", "imu_values"]

_NOT_PROVIDED = -1.0


@dataclass(frozen=True, eq=False)
class ImuSample:
    """One IMU measurement; components not provided are NaN (see ``has_*``)."""

    stamp_ns: int
    frame_id: str
    quat: np.ndarray  # (4,) xyzw unit quaternion: sensor frame in the sensor's inertial frame
    gyro: np.ndarray  # (3,) angular velocity, rad/s, sensor frame
    accel: np.ndarray  # (3,) specific force, m/s^2, sensor frame (gravity included)
    quat_cov: np.ndarray  # (3, 3) orientation covariance (rad^2)
    gyro_cov: np.ndarray  # (3, 3)
    accel_cov: np.ndarray  # (3, 3)

    @property
    def has_orientation(self) -> bool:
        """Whether the orientation was provided."""
        return not np.isnan(self.quat[0])

    @property
    def has_gyro(self) -> bool:
        """Whether the angular velocity was provided."""
        return not np.isnan(self.gyro[0])

    @property
    def has_accel(self) -> bool:
        """Whether the linear acceleration was provided."""
        return not np.isnan(self.accel[0])


def imu_sample(
    stamp_ns: int,
    frame_id: str,
    quat: Any = None,
    gyro: Any = None,
    accel: Any = None,
    quat_cov: Any = None,
    gyro_cov: Any = None,
    accel_cov: Any = None,
    unit_tolerance: float = QUAT_UNIT_TOLERANCE,
) -> ImuSample:
    """A validated ``ImuSample``: a component None = not provided; a covariance None = unknown (zeros).

    The quaternion is normalised when its norm is within ``unit_tolerance`` of 1.
    """
    absent = np.full((3, 3), np.nan)
    return ImuSample(
        stamp_ns=int(stamp_ns),
        frame_id=str(frame_id),
        quat=np.full(4, np.nan) if quat is None else unit_quaternions(quat, (), "Imu orientation", unit_tolerance),
        gyro=np.full(3, np.nan) if gyro is None else finite_array(gyro, (3,), "Imu angular_velocity"),
        accel=np.full(3, np.nan) if accel is None else finite_array(accel, (3,), "Imu linear_acceleration"),
        quat_cov=absent if quat is None else covariance_matrix(quat_cov, 3, "Imu orientation"),
        gyro_cov=absent if gyro is None else covariance_matrix(gyro_cov, 3, "Imu angular_velocity"),
        accel_cov=absent if accel is None else covariance_matrix(accel_cov, 3, "Imu linear_acceleration"),
    )


def msg_to_imu(msg: Any, unit_tolerance: float = QUAT_UNIT_TOLERANCE) -> ImuSample:
    """Validated ``ImuSample`` of an Imu message (REP-145 covariance[0] = -1: not provided)."""
    stamp_ns, frame_id = read_header(msg)
    parts = {}
    for key, values, cov in (
        ("quat", quat_of(msg.orientation), msg.orientation_covariance),
        ("gyro", xyz_of(msg.angular_velocity), msg.angular_velocity_covariance),
        ("accel", xyz_of(msg.linear_acceleration), msg.linear_acceleration_covariance),
    ):
        cov = np.asarray(cov, dtype=np.float64)
        provided = cov[0] != _NOT_PROVIDED
        parts[key], parts[key + "_cov"] = (values, cov) if provided else (None, None)
    return imu_sample(stamp_ns, frame_id, unit_tolerance=unit_tolerance, **parts)


def _covariance_field(provided: bool, cov: np.ndarray) -> np.ndarray:
    """The 9 message values of a covariance; REP-145 [-1, 0, ...] when not provided."""
    if provided:
        return cov.reshape(9)
    cov = np.zeros(9)
    cov[0] = _NOT_PROVIDED
    return cov


def imu_values(sample: ImuSample) -> np.ndarray:
    """The 37 numbers of a sample's Imu message in their order: orientation (xyzw) and its covariance, angular
    velocity and its covariance, linear acceleration and its covariance; a component not provided is zeros with
    covariance[0] = -1 (REP-145)."""
    return np.concatenate([
        part
        for provided, values, cov in ((sample.has_orientation, sample.quat, sample.quat_cov),
                                      (sample.has_gyro, sample.gyro, sample.gyro_cov),
                                      (sample.has_accel, sample.accel, sample.accel_cov))
        for part in ((values if provided else np.zeros(len(values))), _covariance_field(provided, cov))
    ])


def imu_to_msg(backend: Backend, sample: ImuSample) -> Any:
    """``sensor_msgs/msg/Imu`` of a sample; missing components are zeros with covariance[0] = -1."""
    v = imu_values(sample)
    return backend.msg(
        "sensor_msgs/msg/Imu",
        header=backend.header(sample.stamp_ns, sample.frame_id),
        orientation=quaternion_msg(backend, v[0:4]),
        orientation_covariance=v[4:13],
        angular_velocity=vector3_msg(backend, v[13:16]),
        angular_velocity_covariance=v[16:25],
        linear_acceleration=vector3_msg(backend, v[25:28]),
        linear_acceleration_covariance=v[28:37],
    )
