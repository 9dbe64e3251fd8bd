"""Imu, JointState, PoseStamped, PoseArray, Odometry, skeleton markers and diagnostics <-> numpy."""

from __future__ import annotations

import numpy as np
import pytest

from lip_msgs_py import (
    Diagnostic,
    DiagnosticLevel,
    MalformedMessageError,
    RclpyBackend,
    RosbagsBackend,
    diagnostic_array_to_msg,
    diagnostic_status_to_msg,
    imu_sample,
    imu_to_msg,
    joint_state_to_msg,
    msg_to_diagnostics,
    msg_to_imu,
    msg_to_joint_state,
    msg_to_odometry,
    msg_to_pose_array,
    msg_to_pose_stamped,
    odometry_to_msg,
    pose_array_to_msg,
    pose_stamped_to_msg,
    skeleton_to_markers,
    stamp_to_ns,
    tf_message,
    transform_stamped_to_msg,
)
from lip_msgs_py.markers import ADD, LINE_LIST, SPHERE_LIST
from lip_ros.core.skeleton import joint_state_names, load_skeleton

BACKENDS = [RclpyBackend(check_fields=True), RosbagsBackend()]
STAMP = 1_700_000_000_050_000_123
QUATERNION, VECTOR3 = "geometry_msgs/msg/Quaternion", "geometry_msgs/msg/Vector3"
RNG = np.random.default_rng(42)


@pytest.fixture(params=BACKENDS, ids=["rclpy", "rosbags"])
def backend(request):
    return request.param


def random_quats(n: int) -> np.ndarray:
    q = RNG.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def set_fields(msg, **values):
    for name, value in values.items():
        setattr(msg, name, value)
    return msg


# --- Imu -------------------------------------------------------------------


def test_imu_round_trip(backend):
    q = random_quats(1)[0]
    cov = np.diag([0.01, 0.02, 0.03])
    sample = imu_sample(STAMP, "left_wrist", q, [0.1, -0.2, 0.3], [0.0, 0.5, 9.81], cov, 2 * cov, 3 * cov)
    msg = imu_to_msg(backend, sample)
    assert stamp_to_ns(msg.header.stamp) == STAMP and msg.header.frame_id == "left_wrist"
    assert np.allclose([msg.orientation.x, msg.orientation.w], [q[0], q[3]], atol=1e-15, rtol=0)
    assert list(msg.linear_acceleration_covariance) == list((3 * cov).ravel())
    back = msg_to_imu(msg)
    assert back.stamp_ns == STAMP and back.frame_id == "left_wrist"
    assert back.has_orientation and back.has_gyro and back.has_accel
    assert np.allclose(back.quat, q, atol=1e-15, rtol=0)
    assert np.array_equal(back.gyro, [0.1, -0.2, 0.3]) and np.array_equal(back.accel, [0.0, 0.5, 9.81])
    assert np.array_equal(back.quat_cov, cov) and np.array_equal(back.accel_cov, 3 * cov)


def test_imu_components_not_provided_follow_rep145(backend):
    msg = imu_to_msg(backend, imu_sample(STAMP, "imu", gyro=[1.0, 2.0, 3.0]))
    assert msg.orientation_covariance[0] == -1.0 and msg.linear_acceleration_covariance[0] == -1.0
    assert msg.angular_velocity_covariance[0] == 0.0
    back = msg_to_imu(msg)
    assert not back.has_orientation and not back.has_accel and back.has_gyro
    assert np.isnan(back.quat).all() and np.isnan(back.accel_cov).all()
    assert np.array_equal(back.gyro, [1.0, 2.0, 3.0]) and np.array_equal(back.gyro_cov, np.zeros((3, 3)))


def test_imu_zero_quaternion_is_fine_when_flagged_not_provided(backend):
    msg = imu_to_msg(backend, imu_sample(STAMP, "imu", quat=[0, 0, 0, 1], accel=[0, 0, 9.8]))
    msg.orientation = backend.msg(QUATERNION, x=0.0, y=0.0, z=0.0, w=0.0)
    with pytest.raises(MalformedMessageError, match="zero quaternion"):
        msg_to_imu(msg)
    cov = np.zeros(9)
    cov[0] = -1.0
    msg.orientation_covariance = cov
    assert not msg_to_imu(msg).has_orientation


def test_imu_nearly_unit_quaternion_is_normalised(backend):
    msg = imu_to_msg(backend, imu_sample(STAMP, "imu", quat=[0, 0, 0, 1]))
    msg.orientation = backend.msg(QUATERNION, x=0.0, y=0.6, z=0.0, w=0.8004)
    raw = np.array([0, 0.6, 0, 0.8004])  # norm 1.00032
    assert np.allclose(msg_to_imu(msg).quat, raw / np.linalg.norm(raw), atol=1e-15, rtol=0)


@pytest.mark.parametrize(
    "change, reason",
    [
        (lambda b: {"orientation": b.msg(QUATERNION, w=1.1)}, "norm 1.1 is not 1"),
        (lambda b: {"orientation": b.msg(QUATERNION, x=float("nan"))}, "Imu orientation: non-finite"),
        (lambda b: {"angular_velocity": b.msg(VECTOR3, x=float("nan"))}, "Imu angular_velocity: non-finite"),
        (lambda b: {"linear_acceleration": b.msg(VECTOR3, z=float("inf"))}, "Imu linear_acceleration: non-finite"),
        (lambda b: {"angular_velocity_covariance": np.full(9, np.nan)}, "angular_velocity covariance: non-finite"),
    ],
    ids=["non-unit", "nan-quat", "nan-gyro", "inf-accel", "nan-cov"],
)
def test_invalid_imu_messages_raise(backend, change, reason):
    msg = imu_to_msg(backend, imu_sample(STAMP, "imu", [0, 0, 0, 1], [0, 0, 0], [0, 0, 9.8]))
    assert msg_to_imu(msg).has_orientation  # valid before the change
    set_fields(msg, **change(backend))
    with pytest.raises(MalformedMessageError, match=reason):
        msg_to_imu(msg)


def test_imu_sample_rejects_bad_arrays():
    with pytest.raises(MalformedMessageError, match=r"expected shape \(3,\), got \(2,\)"):
        imu_sample(0, "imu", gyro=[1.0, 2.0])
    with pytest.raises(MalformedMessageError, match="not numeric"):
        imu_sample(0, "imu", accel=["a", "b", "c"])
    with pytest.raises(MalformedMessageError, match="covariance: expected shape"):
        imu_sample(0, "imu", accel=[0, 0, 9.8], accel_cov=np.eye(2))
    with pytest.raises(MalformedMessageError, match="tolerance 0.0001"):
        imu_sample(0, "imu", quat=[0, 0, 0, 1.001], unit_tolerance=1e-4)


# --- JointState --------------------------------------------------------------

SKELETON = load_skeleton()
NAMES = joint_state_names(SKELETON)


def test_joint_state_round_trip_with_skeleton_names(backend):
    angles = RNG.uniform(-np.pi, np.pi, 69)
    msg = joint_state_to_msg(backend, STAMP, "os_lidar", NAMES, angles)
    assert list(msg.name) == NAMES and len(msg.position) == 69 and len(msg.velocity) == 0
    assert NAMES[:3] == ["left_hip_rz", "left_hip_ry", "left_hip_rx"]
    back = msg_to_joint_state(msg)
    assert back.stamp_ns == STAMP and back.frame_id == "os_lidar"
    assert back.names == tuple(NAMES) and np.array_equal(back.positions, angles)
    reordered = msg_to_joint_state(msg, NAMES[::-1])
    assert np.array_equal(reordered.positions, angles[::-1])
    subset = msg_to_joint_state(msg, ["right_knee_ry"])
    assert subset.positions.tolist() == [angles[NAMES.index("right_knee_ry")]]


def test_joint_state_reader_returns_a_copy(backend):
    msg = joint_state_to_msg(backend, STAMP, "", ["a"], [1.0])
    positions = msg_to_joint_state(msg).positions
    positions[0] = 5.0
    assert msg.position[0] == 1.0


def test_joint_state_errors(backend):
    with pytest.raises(MalformedMessageError, match=r"expected shape \(69,\), got \(68,\)"):
        joint_state_to_msg(backend, 0, "", NAMES, np.zeros(68))
    with pytest.raises(MalformedMessageError, match="duplicate"):
        joint_state_to_msg(backend, 0, "", ["a", "a"], np.zeros(2))
    with pytest.raises(MalformedMessageError, match="non-finite"):
        joint_state_to_msg(backend, 0, "", ["a", "b"], [0.0, np.nan])
    msg = joint_state_to_msg(backend, 0, "", NAMES, np.zeros(69))
    with pytest.raises(MalformedMessageError, match=r"lacks 1 joint\(s\), e.g. \['pelvis_rz'\]"):
        msg_to_joint_state(msg, ["pelvis_rz"] + NAMES)
    msg.name = NAMES[:-1]
    with pytest.raises(MalformedMessageError, match=r"JointState position: expected shape \(68,\), got \(69,\)"):
        msg_to_joint_state(msg)


# --- PoseStamped, PoseArray, Odometry -----------------------------------------


def test_pose_stamped_round_trip(backend):
    q = random_quats(1)[0]
    msg = pose_stamped_to_msg(backend, STAMP, "os_lidar", [1.0, 2.0, 3.0], q)
    assert np.isclose(msg.pose.orientation.w, q[3], atol=1e-15, rtol=0) and msg.pose.position.z == 3.0
    back = msg_to_pose_stamped(msg)
    assert back.stamp_ns == STAMP and back.frame_id == "os_lidar"
    assert np.array_equal(back.position, [1.0, 2.0, 3.0]) and np.allclose(back.quat, q, atol=1e-15, rtol=0)


def test_pose_writers_validate_quaternions(backend):
    msg = pose_stamped_to_msg(backend, 0, "os_lidar", np.zeros(3), [0.0, 0.0, 0.0, 1.0004])
    assert msg.pose.orientation.w == 1.0
    with pytest.raises(MalformedMessageError, match="PoseStamped orientation: zero quaternion"):
        pose_stamped_to_msg(backend, 0, "os_lidar", np.zeros(3), np.zeros(4))
    with pytest.raises(MalformedMessageError, match="PoseArray orientations: quaternion norm 2 is not 1"):
        pose_array_to_msg(backend, 0, "os_lidar", np.zeros((2, 3)), [[0, 0, 0, 1], [0, 0, 0, 2]])
    with pytest.raises(MalformedMessageError, match=r"PoseArray orientations: expected shape \(2, 4\), got \(3, 4\)"):
        pose_array_to_msg(backend, 0, "os_lidar", np.zeros((2, 3)), random_quats(3))


def test_pose_array_round_trip_of_24_joints(backend):
    positions, quats = RNG.normal(size=(24, 3)), random_quats(24)
    msg = pose_array_to_msg(backend, STAMP, "os_lidar", positions, quats)
    assert len(msg.poses) == 24 and msg.poses[5].position.y == positions[5, 1]
    assert np.isclose(msg.poses[23].orientation.x, quats[23, 0], atol=1e-15, rtol=0)
    back = msg_to_pose_array(msg, num_poses=24)
    assert back.stamp_ns == STAMP and back.frame_id == "os_lidar"
    assert np.array_equal(back.positions, positions) and np.allclose(back.quats, quats, atol=1e-15, rtol=0)
    with pytest.raises(MalformedMessageError, match="has 24 poses, expected 23"):
        msg_to_pose_array(msg, num_poses=23)
    empty = msg_to_pose_array(pose_array_to_msg(backend, 0, "os_lidar", np.zeros((0, 3)), np.zeros((0, 4))))
    assert empty.positions.shape == (0, 3) and empty.quats.shape == (0, 4)


def test_pose_array_reader_rejects_bad_orientation(backend):
    msg = pose_array_to_msg(backend, 0, "os_lidar", np.zeros((2, 3)), random_quats(2))
    msg.poses[1].orientation = backend.msg(QUATERNION, x=0.0, y=0.0, z=0.0, w=0.0)
    with pytest.raises(MalformedMessageError, match="zero quaternion"):
        msg_to_pose_array(msg)


def test_odometry_round_trip(backend):
    q = random_quats(1)[0]
    pose_cov = np.diag(np.arange(1.0, 7.0))
    twist = [0.5, 0, 0], [0, 0, 0.1]
    msg = odometry_to_msg(backend, STAMP, "map", "pelvis", [1, 2, 3], q, *twist, pose_cov, 2 * pose_cov)
    assert msg.child_frame_id == "pelvis" and msg.pose.covariance[7] == 2.0
    back = msg_to_odometry(msg)
    assert (back.stamp_ns, back.frame_id, back.child_frame_id) == (STAMP, "map", "pelvis")
    assert np.array_equal(back.position, [1, 2, 3]) and np.allclose(back.quat, q, atol=1e-15, rtol=0)
    assert np.array_equal(back.linear, [0.5, 0, 0]) and np.array_equal(back.angular, [0, 0, 0.1])
    assert np.array_equal(back.pose_cov, pose_cov) and np.array_equal(back.twist_cov, 2 * pose_cov)
    plain = msg_to_odometry(odometry_to_msg(backend, 0, "map", "pelvis", [0, 0, 0], [0, 0, 0, 1]))
    assert np.array_equal(plain.linear, np.zeros(3)) and np.array_equal(plain.twist_cov, np.zeros((6, 6)))


# --- skeleton markers --------------------------------------------------------


def test_skeleton_markers(backend):
    positions = RNG.normal(size=(24, 3))
    msg = skeleton_to_markers(
        backend, STAMP, "os_lidar", positions, SKELETON.parents, ns="gt", color=(1, 0, 0, 1),
        joint_color=(0, 1, 0, 0.5), line_width=0.03, joint_diameter=0.06, lifetime_ns=200_000_000,
    )  # fmt: skip
    bones, joints = msg.markers
    assert (bones.type, joints.type) == (LINE_LIST, SPHERE_LIST) and bones.action == joints.action == ADD
    assert (bones.ns, bones.id, joints.ns, joints.id) == ("gt", 0, "gt", 1)
    for m in (bones, joints):
        assert stamp_to_ns(m.header.stamp) == STAMP and m.header.frame_id == "os_lidar"
        assert stamp_to_ns(m.lifetime) == 200_000_000
        assert m.pose.orientation.w == 1.0
    assert bones.scale.x == 0.03 and joints.scale.z == 0.06
    assert (bones.color.r, bones.color.g, joints.color.g, joints.color.a) == (1.0, 0.0, 1.0, 0.5)
    ends = np.array([[p.x, p.y, p.z] for p in bones.points]).reshape(23, 2, 3)
    for j in range(1, 24):
        assert np.array_equal(ends[j - 1], positions[[SKELETON.parents[j], j]])
    assert np.array_equal([[p.x, p.y, p.z] for p in joints.points], positions)


def test_marker_constants_match_the_message_definition():
    from visualization_msgs.msg import Marker

    assert (Marker.LINE_LIST, Marker.SPHERE_LIST, Marker.ADD) == (LINE_LIST, SPHERE_LIST, ADD)


def test_skeleton_marker_errors(backend):
    with pytest.raises(MalformedMessageError, match="parents must be 24 integer indices"):
        skeleton_to_markers(backend, 0, "os_lidar", np.zeros((24, 3)), SKELETON.parents[:-1])
    with pytest.raises(MalformedMessageError, match="outside"):
        skeleton_to_markers(backend, 0, "os_lidar", np.zeros((24, 3)), SKELETON.parents, color=(2, 0, 0, 1))
    with pytest.raises(MalformedMessageError, match="non-finite"):
        skeleton_to_markers(backend, 0, "os_lidar", np.full((24, 3), np.nan), SKELETON.parents)


# --- diagnostics -------------------------------------------------------------


def test_diagnostics_round_trip(backend):
    statuses = [
        diagnostic_status_to_msg(backend, DiagnosticLevel.OK, "lip: lidar", "ok", "os1", {"rate_hz": 10.0, "drops": 0}),
        diagnostic_status_to_msg(backend, 2, "lip: calibration", "not calibrated", values={"state": "A-pose"}),
    ]
    msg = diagnostic_array_to_msg(backend, STAMP, statuses)
    back = msg_to_diagnostics(msg)
    assert back.stamp_ns == STAMP and back.frame_id == ""
    assert back.statuses == (
        Diagnostic(DiagnosticLevel.OK, "lip: lidar", "ok", "os1", {"rate_hz": "10.0", "drops": "0"}),
        Diagnostic(DiagnosticLevel.ERROR, "lip: calibration", "not calibrated", "", {"state": "A-pose"}),
    )


def test_diagnostic_level_is_validated(backend):
    with pytest.raises(MalformedMessageError, match="level 4"):
        diagnostic_status_to_msg(backend, 4, "x", "y")
    status = diagnostic_status_to_msg(backend, DiagnosticLevel.STALE, "x", "y")
    assert status.level in (3, b"\x03")  # rosbags: int, rclpy: one byte


# --- /tf ---------------------------------------------------------------------


def test_tf_message_of_the_pelvis_serialises():
    """rclpy here has no tf2_msgs (pose_node skips /tf, tested over DDS); the rosbags Jazzy typestore has it."""
    backend = RosbagsBackend()
    q = random_quats(1)[0]
    tf = tf_message(backend, [transform_stamped_to_msg(backend, STAMP, "os_lidar", "pelvis", [1.0, 2.0, 0.5], q)])
    back = backend.deserialize(backend.serialize(tf, "tf2_msgs/msg/TFMessage"), "tf2_msgs/msg/TFMessage")
    (t,) = back.transforms
    assert stamp_to_ns(t.header.stamp) == STAMP and (t.header.frame_id, t.child_frame_id) == ("os_lidar", "pelvis")
    np.testing.assert_allclose([t.transform.translation.x, t.transform.translation.y, t.transform.translation.z],
                               [1.0, 2.0, 0.5])
    r = t.transform.rotation
    np.testing.assert_allclose([r.x, r.y, r.z, r.w], q)
    with pytest.raises(MalformedMessageError):
        transform_stamped_to_msg(backend, STAMP, "os_lidar", "pelvis", [np.nan, 0.0, 0.0], q)
