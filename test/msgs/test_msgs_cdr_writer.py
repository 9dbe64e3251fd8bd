"""The pose outputs written straight to CDR decode to the messages the object writers build, and validate alike."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from scipy.spatial.transform import Rotation

from lip_msgs_py import (
    Backend,
    MalformedMessageError,
    RclpyBackend,
    RosbagsBackend,
    imu_sample,
    imu_to_msg,
    joint_state_to_msg,
    msg_to_joint_state,
    msg_to_pose_array,
    pose_array_to_msg,
    pose_stamped_to_msg,
    rclpy_message_class,
    skeleton_to_markers,
)
from lip_msgs_py.cdr import imu_samples
from lip_msgs_py.cdr_writer import imu_cdr, joint_state_cdr, pose_array_cdr, pose_stamped_cdr, skeleton_markers_cdr
from lip_ros.core.skeleton import forward_kinematics, joint_state_names, load_skeleton
from lip_ros.lip.sensors import LIP_TOPICS
from lip_ros.outputs import GT_TOPICS, pose_cdr, pose_messages

RNG = np.random.default_rng(7)
SKELETON = load_skeleton()
RCLPY, ROSBAGS = RclpyBackend(), RosbagsBackend()


def _quats(n: int) -> np.ndarray:
    q = RNG.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _same_message(raw: bytes, type_name: str, build: Callable[[Backend], Any]) -> None:
    """``raw`` decodes in rclpy to the message ``build`` makes with rclpy (as that reads after its own
    serialisation), and is byte for byte what rosbags writes of the message ``build`` makes with rosbags."""
    cls = rclpy_message_class(type_name)
    assert deserialize_message(raw, cls) == deserialize_message(serialize_message(build(RCLPY)), cls)
    assert raw == bytes(ROSBAGS.serialize(build(ROSBAGS), type_name))


# frame ids of every length modulo 8 move the fields after them across the alignments; stamps before 1970 too
@pytest.mark.parametrize("frame_id", ["", "a", "ab", "abc", "os_lidar", "map_1234", "pelvis_frame"])
@pytest.mark.parametrize("stamp_ns", [0, 1_700_000_000_050_000_123, -1_500_000_000])
def test_the_four_pose_messages_decode_to_the_object_writers_messages(frame_id, stamp_ns):
    positions, quats = RNG.normal(size=(24, 3)), _quats(24)
    names, angles = joint_state_names(SKELETON), RNG.normal(size=69)
    cases = [
        ("geometry_msgs/msg/PoseStamped", pose_stamped_cdr(stamp_ns, frame_id, positions[0], quats[0]),
         lambda b: pose_stamped_to_msg(b, stamp_ns, frame_id, positions[0], quats[0])),
        ("geometry_msgs/msg/PoseArray", pose_array_cdr(stamp_ns, frame_id, positions, quats),
         lambda b: pose_array_to_msg(b, stamp_ns, frame_id, positions, quats)),
        ("sensor_msgs/msg/JointState", joint_state_cdr(stamp_ns, frame_id, names, angles),
         lambda b: joint_state_to_msg(b, stamp_ns, frame_id, names, angles)),
        ("visualization_msgs/msg/MarkerArray",
         skeleton_markers_cdr(stamp_ns, frame_id, positions, SKELETON.parents, lifetime_ns=1_250_000_000),
         lambda b: skeleton_to_markers(b, stamp_ns, frame_id, positions, SKELETON.parents, lifetime_ns=1_250_000_000)),
    ]
    for type_name, raw, build in cases:
        _same_message(raw, type_name, build)


def test_the_values_read_back_exactly():
    positions, quats = RNG.normal(size=(24, 3)), _quats(24)
    raw = pose_array_cdr(5, "os_lidar", positions, quats)
    poses = msg_to_pose_array(ROSBAGS.deserialize(raw, "geometry_msgs/msg/PoseArray"), 24)
    assert poses.stamp_ns == 5 and poses.frame_id == "os_lidar"
    np.testing.assert_array_equal(poses.positions, positions)
    np.testing.assert_allclose(poses.quats, quats, atol=1e-15)
    names, angles = joint_state_names(SKELETON), RNG.normal(size=69)
    state = msg_to_joint_state(ROSBAGS.deserialize(joint_state_cdr(5, "x", names, angles),
                                                   "sensor_msgs/msg/JointState"))
    assert state.names == tuple(names)
    np.testing.assert_array_equal(state.positions, angles)


@pytest.mark.parametrize("write, args, reason", [
    (pose_stamped_cdr, (np.array([0.0, np.nan, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])), "non-finite"),
    (pose_stamped_cdr, (np.zeros(3), np.zeros(4)), "zero quaternion"),
    (pose_array_cdr, (np.zeros((24, 3)), np.tile([0.0, 0.0, 0.0, 2.0], (24, 1))), "not 1"),
    (pose_array_cdr, (np.zeros((24, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (23, 1))), "expected shape"),
    (joint_state_cdr, (["a", "a"], np.zeros(2)), "duplicate"),
    (joint_state_cdr, (["a", "b"], np.zeros(3)), "expected shape"),
    (skeleton_markers_cdr, (np.zeros((3, 3)), np.array([-1, 0, 5])), "parents"),
    (skeleton_markers_cdr, (np.full((2, 3), np.inf), np.array([-1, 0])), "non-finite"),
])
def test_bad_arrays_raise_as_with_the_object_writers(write, args, reason):
    with pytest.raises(MalformedMessageError, match=reason):
        write(1, "os_lidar", *args)


@pytest.mark.parametrize("topics", [LIP_TOPICS, GT_TOPICS], ids=["with markers", "without"])
def test_pose_cdr_gives_pose_messages_as_bytes(topics):
    rot = Rotation.random(24, random_state=3).as_matrix()
    glob, pos = forward_kinematics(SKELETON, rot)
    args = (SKELETON, 123, "os_lidar", rot, glob, pos)
    raw = pose_cdr(topics, *args)
    assert raw.keys() == pose_messages(RCLPY, topics, *args).keys()
    for topic, data in raw.items():
        _same_message(data, pose_messages(RCLPY, topics, *args)[topic][0],
                      lambda b, topic=topic: pose_messages(b, topics, *args)[topic][1])


@pytest.mark.parametrize("given", [("quat", "gyro", "accel"), ("quat", "accel"), ("quat",), ("accel",)])
def test_imu_decodes_to_the_object_writers_message_and_reads_back(given):
    values = {"quat": _quats(1)[0], "gyro": RNG.normal(size=3), "accel": RNG.normal(size=3)}
    covs = {"quat_cov": np.diag([0.01, 0.02, 0.03]), "accel_cov": np.eye(3) * 0.5}
    sample = imu_sample(1_700_000_000_000_000_001, "left_wrist", **{k: values[k] for k in given},
                        **{k: v for k, v in covs.items() if k[:-4] in given})
    raw = imu_cdr(sample)
    _same_message(raw, "sensor_msgs/msg/Imu", lambda b: imu_to_msg(b, sample))
    back = imu_samples([raw])[0]  # the live nodes' reader of these bytes
    for k in ("quat", "gyro", "accel", "quat_cov", "gyro_cov", "accel_cov"):
        np.testing.assert_array_equal(getattr(back, k), getattr(sample, k))
