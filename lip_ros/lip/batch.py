"""Run the LIP pipeline over a recorded bag, in the order the messages were received (ROS-free).

:func:`replay_bag` is the reference: rosbags message objects, one message at
a time, as a node receives them. :func:`process_bag_batch` gives the same results
several times faster, for batch tools that take the results as they come but
need no live pace: the bag is read and decompressed ahead in a thread into
reused buffers (:mod:`lip_ros.bagstream`); clouds and IMU samples are decoded
from the CDR bytes without message objects (:mod:`lip_msgs_py.cdr`); the IMU
samples between two clouds are validated together
(:meth:`~lip_ros.lip.pipeline.LipPipeline.add_imus`); and with a pipeline built
with ``pose_batch`` > 1 (:data:`POSE_BATCH`) the network runs over that many
posed frames per forward.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from lip_msgs_py import ImuSample, MalformedMessageError, cloud_to_array, msg_to_imu, read_header
from lip_msgs_py.cdr import cloud_msg, imu_samples
from lip_ros.bagio import RawMessage, jazzy_typestore, read_messages
from lip_ros.bagstream import stream_raw
from lip_ros.lip.pipeline import FrameResult, LipPipeline
from lip_ros.lip.sensors import IMU_TOPICS, LIDAR_TOPIC

__all__ = ["POSE_BATCH", "replay_bag", "process_bag_batch"]

#: ``LipPipeline(pose_batch=...)`` for batch processing: posed frames per network forward (6.4 s at 10 Hz).
POSE_BATCH = 64

_CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
_IMU_TYPE = "sensor_msgs/msg/Imu"


def replay_bag(
    pipeline: LipPipeline,
    bag: str | Path,
    lidar_topic: str = LIDAR_TOPIC,
    imu_topics: Mapping[str, str] = IMU_TOPICS,
) -> Iterator[FrameResult]:
    """Feed a bag to ``pipeline`` message by message, in log-time order; one result per LiDAR frame."""
    imu_of_topic = {topic: name for name, topic in imu_topics.items()}
    for m in read_messages(bag, [lidar_topic, *imu_of_topic]):
        if m.topic == lidar_topic:
            yield from _add_cloud(pipeline, m.msg)
            continue
        sample = _imu_sample(m.msg)
        if isinstance(sample, MalformedMessageError):
            pipeline.reject_imu(imu_of_topic[m.topic], f"malformed: {sample}")
        else:
            pipeline.add_imu(imu_of_topic[m.topic], sample)
        yield from pipeline.poll()
    yield from pipeline.flush()


def process_bag_batch(
    pipeline: LipPipeline,
    bag: str | Path,
    lidar_topic: str = LIDAR_TOPIC,
    imu_topics: Mapping[str, str] = IMU_TOPICS,
) -> Iterator[FrameResult]:
    """:func:`replay_bag`'s results (poses equal up to float rounding), faster (see the module); results come
    in groups when ``pipeline.pose_batch`` > 1."""
    imu_of_topic = {topic: name for name, topic in imu_topics.items()}
    imus: list[RawMessage] = []  # since the last cloud, copied out of the read-ahead buffers
    for m in stream_raw(bag, [lidar_topic, *imu_of_topic]):
        if m.topic == lidar_topic:
            yield from _add_imus(pipeline, imus, imu_of_topic)
            imus = []
            yield from _add_cloud(pipeline, _cloud(m))
        else:
            imus.append(RawMessage(m.topic, m.log_ns, bytes(m.data), m.msgtype))
    yield from _add_imus(pipeline, imus, imu_of_topic)
    yield from pipeline.flush()


def _add_cloud(pipeline: LipPipeline, msg: Any) -> Iterator[FrameResult]:
    """One PointCloud2 (a message object or :class:`lip_msgs_py.cdr.CloudMsg`) into the pipeline, then a poll."""
    stamp_ns = read_header(msg)[0]
    try:
        points = cloud_to_array(msg)
    except MalformedMessageError as exc:
        yield from pipeline.skip(stamp_ns, f"malformed cloud: {exc}")
    else:
        yield from pipeline.add_cloud(points, stamp_ns)
    yield from pipeline.poll()


def _imu_sample(msg: Any) -> ImuSample | MalformedMessageError:
    """The sample of an Imu message object, or why it is malformed."""
    try:
        return msg_to_imu(msg)
    except MalformedMessageError as exc:
        return exc


def _cloud(m: RawMessage) -> Any:
    """The cloud of a raw message: decoded in place if plain, else deserialised by rosbags."""
    msg = cloud_msg(m.data) if m.msgtype == _CLOUD_TYPE else None
    return msg if msg is not None else jazzy_typestore().deserialize_cdr(m.data, m.msgtype)


def _add_imus(pipeline: LipPipeline, imus: list[RawMessage], imu_of_topic: Mapping[str, str]) -> list[FrameResult]:
    """Raw IMU messages in arrival order into the pipeline, each followed by a poll; the frames that came out."""
    decoded = imu_samples([m.data if m.msgtype == _IMU_TYPE else b"" for m in imus])
    names, samples = [], []
    for m, sample in zip(imus, decoded, strict=True):
        if sample is None:  # not plain: through rosbags and msg_to_imu, as replay_bag
            sample = _imu_sample(jazzy_typestore().deserialize_cdr(m.data, m.msgtype))
        if isinstance(sample, MalformedMessageError):  # no poll needed: a rejected message changes nothing
            pipeline.reject_imu(imu_of_topic[m.topic], f"malformed: {sample}")
        else:
            names.append(imu_of_topic[m.topic])
            samples.append(sample)
    return pipeline.add_imus(names, samples) if samples else []
