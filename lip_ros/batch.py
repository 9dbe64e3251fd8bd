"""Run the LIP pipeline over a recorded bag, in the order the messages were received (ROS-free)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path

from lip_msgs_py import MalformedMessageError, cloud_to_array, msg_to_imu, read_header
from lip_ros.bagio import read_messages
from lip_ros.nets.config import IMU_NAMES
from lip_ros.pipeline import FrameResult, LipPipeline

__all__ = ["DEFAULT_LIDAR_TOPIC", "DEFAULT_IMU_TOPICS", "replay_bag"]

DEFAULT_LIDAR_TOPIC = "/ouster/points"
DEFAULT_IMU_TOPICS = {name: f"/dot/{name}/imu" for name in IMU_NAMES}


def replay_bag(
    pipeline: LipPipeline,
    bag: str | Path,
    lidar_topic: str = DEFAULT_LIDAR_TOPIC,
    imu_topics: Mapping[str, str] = DEFAULT_IMU_TOPICS,
) -> Iterator[FrameResult]:
    """Feed a bag to ``pipeline`` message by message, in log-time order; one result per LiDAR frame."""
    imu_of_topic = {topic: name for name, topic in imu_topics.items()}
    for m in read_messages(bag, [lidar_topic, *imu_of_topic]):
        if m.topic == lidar_topic:
            stamp_ns = read_header(m.msg)[0]
            try:
                points = cloud_to_array(m.msg)
            except MalformedMessageError as exc:
                yield from pipeline.skip(stamp_ns, f"malformed cloud: {exc}")
            else:
                yield from pipeline.add_cloud(points, stamp_ns)
        else:
            try:
                sample = msg_to_imu(m.msg)
            except MalformedMessageError as exc:
                pipeline.reject_imu(imu_of_topic[m.topic], f"malformed: {exc}")
            else:
                pipeline.add_imu(imu_of_topic[m.topic], sample)
        yield from pipeline.poll()
    yield from pipeline.flush()
