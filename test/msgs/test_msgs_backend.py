"""Backends, stamps, and CDR equivalence of rclpy and rosbags messages built by lip_msgs_py."""

from __future__ import annotations

import numpy as np
import pytest

from lip_msgs_py import (
    OUSTER_ORIGINAL_DTYPE,
    MalformedMessageError,
    RclpyBackend,
    RosbagsBackend,
    array_to_cloud,
    diagnostic_array_to_msg,
    diagnostic_status_to_msg,
    imu_sample,
    imu_to_msg,
    joint_state_to_msg,
    ns_to_sec_nanosec,
    odometry_to_msg,
    pose_array_to_msg,
    pose_stamped_to_msg,
    read_header,
    skeleton_to_markers,
    stamp_to_ns,
)
from lip_ros.core.skeleton import joint_state_names, load_skeleton

RCLPY, ROSBAGS = RclpyBackend(check_fields=True), RosbagsBackend()
STAMP = 1_700_000_000_050_000_123


@pytest.fixture(params=[RCLPY, ROSBAGS], ids=["rclpy", "rosbags"])
def backend(request):
    return request.param


# --- stamps ----------------------------------------------------------------


@pytest.mark.parametrize("ns", [0, 1, 999_999_999, 1_000_000_000, STAMP, -1, -1_500_000_000, (2**31 - 1) * 10**9])
def test_time_and_duration_round_trip(backend, ns):
    t = backend.time(ns)
    assert 0 <= t.nanosec < 10**9 and t.sec * 10**9 + t.nanosec == ns
    assert stamp_to_ns(t) == ns and stamp_to_ns(backend.duration(ns)) == ns


def test_stamp_errors(backend):
    with pytest.raises(MalformedMessageError, match="int32 seconds"):
        ns_to_sec_nanosec(2**31 * 10**9)
    with pytest.raises(MalformedMessageError, match="int32 seconds"):
        backend.time(-(2**31 + 1) * 10**9)
    with pytest.raises(MalformedMessageError, match="nanosec 1000000000 outside"):
        stamp_to_ns(backend.msg("builtin_interfaces/msg/Time", sec=1, nanosec=10**9))
    assert ns_to_sec_nanosec(-1) == (-1, 999_999_999)


def test_header(backend):
    msg = backend.msg("sensor_msgs/msg/Imu", header=backend.header(STAMP, "left_wrist"))
    assert read_header(msg) == (STAMP, "left_wrist")


# --- backends --------------------------------------------------------------


def test_backend_rejects_unknown_types_and_fields(backend):
    with pytest.raises(KeyError, match="unknown message type"):
        backend.msg("sensor_msgs/msg/NoSuchThing")
    with pytest.raises(TypeError, match="no field"):
        backend.msg("sensor_msgs/msg/Imu", orientation_cov=np.zeros(9))
    with pytest.raises(MalformedMessageError, match="needs 9 values, got 8"):
        backend.msg("sensor_msgs/msg/Imu", orientation_covariance=np.zeros(8))


def test_backend_converts_numpy_arrays_to_the_declared_types(backend):
    position = np.array([0.1, 0.2], dtype=np.float32)
    msg = backend.msg("sensor_msgs/msg/JointState", name=["a", "b"], position=position, effort=[1, 2])
    assert list(msg.position) == [float(np.float32(0.1)), float(np.float32(0.2))]
    assert list(msg.effort) == [1.0, 2.0] and len(msg.velocity) == 0
    position[0] = 7.0  # the message owns its values
    assert msg.position[0] != 7.0
    cov = backend.msg("sensor_msgs/msg/Imu", linear_acceleration_covariance=np.eye(3)).linear_acceleration_covariance
    assert np.asarray(cov).dtype == np.float64 and list(cov) == [1, 0, 0, 0, 1, 0, 0, 0, 1]


def test_rclpy_sequences_are_stdlib_arrays_and_rosbags_ones_numpy():
    data = np.arange(10, dtype=np.uint8)
    assert RCLPY.msg("sensor_msgs/msg/PointCloud2", data=data).data.tobytes() == data.tobytes()
    rosbags_data = ROSBAGS.msg("sensor_msgs/msg/PointCloud2", data=data).data
    assert rosbags_data.dtype == np.uint8 and np.array_equal(rosbags_data, data)


# --- CDR equivalence ---------------------------------------------------------

SKELETON = load_skeleton()
RNG = np.random.default_rng(7)
POSITIONS = RNG.normal(size=(24, 3))
QUATS = RNG.normal(size=(24, 4))
QUATS /= np.linalg.norm(QUATS, axis=1, keepdims=True)


def ouster_cloud_with_nans() -> np.ndarray:
    scan = np.zeros((128, 64), OUSTER_ORIGINAL_DTYPE)
    for c in "xyz":
        scan[c] = RNG.uniform(-10, 10, scan.shape)
    scan["t"] = np.arange(64) * 1_562_500
    scan["range"] = RNG.integers(1, 40000, scan.shape)
    miss = RNG.random(scan.shape) < 0.5
    for c in "xyz":
        scan[c][miss] = np.nan
    scan["range"][miss] = 0
    return scan


SCAN = ouster_cloud_with_nans()

MESSAGES = {
    "sensor_msgs/msg/PointCloud2": lambda b: array_to_cloud(b, SCAN, STAMP, "os_lidar"),
    "sensor_msgs/msg/Imu": lambda b: imu_to_msg(b, imu_sample(STAMP, "imu", QUATS[0], [0.1, 0.2, 0.3], [0, 0, 9.8])),
    "geometry_msgs/msg/PoseStamped": lambda b: pose_stamped_to_msg(b, STAMP, "map", POSITIONS[0], QUATS[0]),
    "sensor_msgs/msg/JointState": (
        lambda b: joint_state_to_msg(b, STAMP, "os_lidar", joint_state_names(SKELETON), np.linspace(-1, 1, 69))
    ),
    "geometry_msgs/msg/PoseArray": lambda b: pose_array_to_msg(b, STAMP, "os_lidar", POSITIONS, QUATS),
    "visualization_msgs/msg/MarkerArray": (
        lambda b: skeleton_to_markers(b, STAMP, "os_lidar", POSITIONS, SKELETON.parents, lifetime_ns=100_000_000)
    ),
    "diagnostic_msgs/msg/DiagnosticArray": lambda b: diagnostic_array_to_msg(
        b, STAMP, [diagnostic_status_to_msg(b, 1, "lip: imu", "late", "dot-3", {"rate_hz": 59.9, "drops": 2})]
    ),
    "nav_msgs/msg/Odometry": lambda b: odometry_to_msg(b, STAMP, "map", "pelvis", POSITIONS[0], QUATS[0], [1, 0, 0]),
}
# Layouts without alignment padding (a 3-character frame id puts the float64s on 8-byte
# boundaries): there rclpy's bytes must equal rosbags' outright.
UNPADDED = ["sensor_msgs/msg/Imu", "geometry_msgs/msg/PoseStamped"]


def assert_same_cdr(type_name: str, rclpy_msg, rosbags_msg) -> None:
    """rclpy's and rosbags' encodings of two messages carry the same content.

    rmw_fastrtps' serialize_message (Jazzy, 8.4) leaves alignment padding uninitialised
    and may report a few bytes more than it wrote, so in general only the content
    can match: both decode (rclpy) to equal messages, rclpy's bytes decode
    (rosbags) and re-encode to rosbags' bytes, and they differ nowhere but in
    padding, where rosbags writes zeros.
    """
    a = RCLPY.serialize(rclpy_msg, type_name)
    b = ROSBAGS.serialize(rosbags_msg, type_name)
    assert RCLPY.deserialize(b, type_name) == RCLPY.deserialize(a, type_name)
    assert 0 <= len(a) - len(b) <= 8
    assert ROSBAGS.serialize(ROSBAGS.deserialize(a[: len(b)], type_name), type_name) == b
    a_head, b_all = np.frombuffer(a[: len(b)], np.uint8), np.frombuffer(b, np.uint8)
    assert not b_all[a_head != b_all].any()


@pytest.mark.parametrize("type_name", list(MESSAGES))
def test_rclpy_and_rosbags_messages_encode_the_same(type_name):
    build = MESSAGES[type_name]
    assert_same_cdr(type_name, build(RCLPY), build(ROSBAGS))


@pytest.mark.parametrize("type_name", UNPADDED)
def test_unpadded_messages_are_byte_identical(type_name):
    build = MESSAGES[type_name]
    assert RCLPY.serialize(build(RCLPY), type_name) == ROSBAGS.serialize(build(ROSBAGS), type_name)


def test_the_ouster_cloud_points_are_byte_identical_with_nans():
    build, cloud = MESSAGES["sensor_msgs/msg/PointCloud2"], "sensor_msgs/msg/PointCloud2"
    assert np.isnan(SCAN["x"]).mean() > 0.4
    a, b = RCLPY.serialize(build(RCLPY), cloud), ROSBAGS.serialize(build(ROSBAGS), cloud)
    assert len(a) == len(b)
    points = slice(len(b) - 48 * 64 * 128 - 1, len(b) - 1)  # the data, followed by is_dense
    assert a[points] == b[points] == SCAN.tobytes()


PACKAGES = {
    "builtin_interfaces", "std_msgs", "geometry_msgs", "sensor_msgs",
    "nav_msgs", "visualization_msgs", "diagnostic_msgs",
}  # fmt: skip
DEFAULT_TYPES = sorted(name for name in ROSBAGS.typestore.types if name.split("/")[0] in PACKAGES and "/msg/" in name)


@pytest.mark.parametrize("type_name", DEFAULT_TYPES)
def test_default_messages_agree_between_backends(type_name):
    assert_same_cdr(type_name, RCLPY.msg(type_name), ROSBAGS.msg(type_name))
