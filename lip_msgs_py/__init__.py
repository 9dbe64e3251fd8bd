"""lip_msgs_py: ROS messages to and from numpy, for rclpy and rosbags message objects alike.

Readers (``cloud_to_xyz``, ``msg_to_imu``, ``msg_to_pose_array``, ...) are
duck-typed and accept either kind of message. Writers take a backend:
``RclpyBackend()`` for rclpy publishers, ``RosbagsBackend(typestore)`` for bag
writing. Stamps are integer nanoseconds. Every layout or value violation raises
``MalformedMessageError`` (a ValueError) with the reason. The package does not
depend on ``lip_ros``: pass skeleton names and parents in, e.g.
``lip_ros.core.skeleton.joint_state_names(skeleton)`` and ``skeleton.parents``.
"""

from lip_msgs_py.backend import Backend, RclpyBackend, RosbagsBackend, rclpy_message_class
from lip_msgs_py.diagnostics import (
    Diagnostic,
    DiagnosticLevel,
    StampedDiagnostics,
    diagnostic_array_to_msg,
    diagnostic_status_to_msg,
    msg_to_diagnostics,
)
from lip_msgs_py.errors import MalformedMessageError
from lip_msgs_py.imu import ImuSample, imu_sample, imu_to_msg, msg_to_imu
from lip_msgs_py.markers import skeleton_to_markers
from lip_msgs_py.ouster import OUSTER_ORIGINAL_DTYPE
from lip_msgs_py.point_cloud2 import (
    XYZ_DTYPE,
    array_to_cloud,
    cloud_dtype,
    cloud_to_array,
    cloud_to_xyz,
    cloud_to_xyz_time,
    xyz_to_cloud,
)
from lip_msgs_py.pose import (
    StampedJointState,
    StampedOdometry,
    StampedPose,
    StampedPoses,
    joint_state_to_msg,
    msg_to_joint_state,
    msg_to_odometry,
    msg_to_pose_array,
    msg_to_pose_stamped,
    odometry_to_msg,
    pose_array_to_msg,
    pose_stamped_to_msg,
)
from lip_msgs_py.stamps import ns_to_sec_nanosec, read_header, stamp_to_ns
from lip_msgs_py.tf import tf_message, transform_stamped_to_msg

__all__ = [
    "Backend",
    "RclpyBackend",
    "RosbagsBackend",
    "rclpy_message_class",
    "MalformedMessageError",
    "stamp_to_ns",
    "ns_to_sec_nanosec",
    "read_header",
    "OUSTER_ORIGINAL_DTYPE",
    "XYZ_DTYPE",
    "cloud_dtype",
    "cloud_to_array",
    "cloud_to_xyz",
    "cloud_to_xyz_time",
    "array_to_cloud",
    "xyz_to_cloud",
    "ImuSample",
    "imu_sample",
    "imu_to_msg",
    "msg_to_imu",
    "StampedJointState",
    "StampedPose",
    "StampedPoses",
    "StampedOdometry",
    "joint_state_to_msg",
    "msg_to_joint_state",
    "pose_stamped_to_msg",
    "msg_to_pose_stamped",
    "pose_array_to_msg",
    "msg_to_pose_array",
    "transform_stamped_to_msg",
    "tf_message",
    "odometry_to_msg",
    "msg_to_odometry",
    "skeleton_to_markers",
    "DiagnosticLevel",
    "Diagnostic",
    "StampedDiagnostics",
    "diagnostic_status_to_msg",
    "diagnostic_array_to_msg",
    "msg_to_diagnostics",
]
