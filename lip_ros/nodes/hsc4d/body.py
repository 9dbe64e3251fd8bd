"""hsc4d_body_node: the suit's 17 segments on the fused pelvis trajectory, as the contract's pose outputs in ``map``.

For each fused pelvis pose of ``hsc4d_trajectory_node`` (``/hsc4d/odometry``)
it waits (at most ``suit_wait_s``) until every suit segment has a sample at
that moment on the suit's clock (the pose's stamp plus the offset
``hsc4d_trajectory_node`` found from the jump, ``/hsc4d/suit_clock_offset``),
poses the body (:class:`lip_ros.hsc4d.suit_body.SuitBody`) and publishes
``/hsc4d/joint_states``, ``/hsc4d/root_pose`` and ``/hsc4d/joint_poses`` with
the pose's stamp. The skeleton is the contract's scaled by ``body_scale``;
with ``body_scale`` 0 it is scaled to the pelvis height of the first fused pose
(the wearer stands still in A-pose there, and ``map``'s origin is on the ground
under that pelvis), and the scale is logged and reported.
"""

from __future__ import annotations

import time
from collections import Counter, deque
from typing import Any

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu
from std_msgs.msg import Int64

from lip_msgs_py import DiagnosticLevel, MalformedMessageError, msg_to_imu, msg_to_odometry, rclpy_message_class
from lip_msgs_py.cdr import cdr_stamp, imu_samples
from lip_ros.core.rotations import quat_to_matrix
from lip_ros.core.skeleton import load_skeleton
from lip_ros.hsc4d.sensors import HSC4D_TOPICS
from lip_ros.hsc4d.suit_body import SuitBody, SuitBodyConfig
from lip_ros.nodes.base import (
    BETWEEN_NODES,
    IMU_INPUT,
    LATCHED,
    RELIABLE,
    GraphNode,
    LatencyWindow,
    Param,
    ParameterError,
    positive,
    run_nodes,
)
from lip_ros.nodes.hsc4d import HSC4D_PARAMS_FILE
from lip_ros.nodes.hsc4d.trajectory import TrajectoryNode
from lip_ros.outputs import pose_messages

__all__ = ["BodyNode", "main"]


def _segment_topics(value: Any) -> str | None:
    """Check: one topic per suit segment, in the skeleton's ``suit_imus`` order."""
    n = len(load_skeleton().suit_imus)
    ok = isinstance(value, (list, tuple)) and len(value) == n and all(isinstance(v, str) and v for v in value)
    return None if ok else f"must list {n} topics (the skeleton's suit_imus, in order), got {value!r}"


class BodyNode(GraphNode):
    """The fused body of the HSC4D graph."""

    NAME = "hsc4d_body_node"
    PARAMS_FILE = HSC4D_PARAMS_FILE
    PARAMS = {
        "suit_imu_topics": Param("input: the suit's 17 segment sensor_msgs/Imu topics, in the skeleton's suit_imus "
                                 "order", _segment_topics),
        "suit_rate_hz": TrajectoryNode.PARAMS["suit_rate_hz"],
        "odometry_topic": Param("input: the fused pelvis trajectory of hsc4d_trajectory_node"),
        "offset_topic": Param("input (latched): the suit's clock offset of hsc4d_trajectory_node"),
        "body_scale": Param("the performer's size relative to the contract skeleton (0 = from the standing pelvis "
                            "height of the first fused pose)", lambda v: None if v >= 0 else f"must be >= 0, got {v}"),
        "suit_wait_s": Param("a pose waits at most this long after arriving for every segment's sample", positive),
        "max_waiting_poses": Param("poses that may wait for the suit; the oldest goes on with what there is",
                                   positive),
        "max_imu_gap_s": Param("widest gap between two suit samples interpolated across", positive),
    }

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        p = self.params
        gap_ns = int(p["max_imu_gap_s"] * 1e9)
        try:
            self.body = SuitBody(load_skeleton(), SuitBodyConfig(body_scale=p["body_scale"] or 1.0,
                                                                 max_gap_ns=gap_ns, max_hold_ns=gap_ns))
        except ValueError as exc:
            raise ParameterError(str(exc)) from exc
        self._scale_from_height = p["body_scale"] == 0
        self._offset_ns: int | None = None
        self._waiting: deque[tuple[int, str, np.ndarray, float]] = deque()  # stamp, frame, T_map_P, received
        self._degraded = 0
        self._latency = LatencyWindow()  # fused pose received -> body published
        self._out = {topic: self.create_publisher(rclpy_message_class(msgtype), topic, RELIABLE)
                     for topic, msgtype in ((HSC4D_TOPICS.joint_states, "sensor_msgs/msg/JointState"),
                                            (HSC4D_TOPICS.root_pose, "geometry_msgs/msg/PoseStamped"),
                                            (HSC4D_TOPICS.joint_poses, "geometry_msgs/msg/PoseArray"))}
        self.create_subscription(Int64, p["offset_topic"], self._on_offset, LATCHED, callback_group=self.group)
        self.add_input("fused odometry", p["odometry_topic"], Odometry, p["lidar_rate_hz"], self._on_odometry,
                       BETWEEN_NODES)
        self._raw: dict[str, list[bytes]] = {s: [] for s in self.body.segments}  # not decoded yet
        self._newest: dict[str, int] = {}  # each segment's newest stamp received
        self._rejected: Counter[str] = Counter()  # suit samples, by reason
        for segment, topic in zip(self.body.segments, p["suit_imu_topics"]):
            self.add_input(f"suit {segment}", topic, Imu, p["suit_rate_hz"],
                           lambda data, segment=segment: self._on_imu(segment, data), IMU_INPUT, raw=True)
        self.create_timer(0.02, self._drain, self.group, clock=self.steady)

    def _on_offset(self, msg: Int64) -> None:
        self._offset_ns = int(msg.data)
        self._drain()

    def _on_imu(self, segment: str, data: bytes) -> int:
        """Keep a suit sample's bytes (decoded in a batch when a pose needs them) and its stamp."""
        stamp_ns = cdr_stamp(data)
        raw = self._raw[segment]
        raw.append(data)
        if len(raw) > self.body.config.capacity:  # no pose asked for a while: keep the newest
            del raw[: len(raw) - self.body.config.capacity]
        self._newest[segment] = max(stamp_ns, self._newest.get(segment, stamp_ns))
        if self._waiting:
            self._drain()
        return stamp_ns

    def _decode(self) -> None:
        """Decode and buffer every segment's samples received since the last time."""
        for segment, raw in self._raw.items():
            if not raw:
                continue
            samples = []
            for data, sample in zip(raw, imu_samples(raw), strict=True):
                try:  # a message that is not plain little-endian CDR: deserialised and checked in full
                    samples.append(sample if sample is not None else msg_to_imu(deserialize_message(data, Imu)))
                except (MalformedMessageError, RuntimeError) as exc:
                    self._rejected[str(exc).split(":")[0][:60]] += 1
            for reason in self.body.add(segment, samples):
                if reason is not None:
                    self._rejected[reason] += 1
            raw.clear()

    def _on_odometry(self, msg: Odometry) -> int:
        odometry = msg_to_odometry(msg)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = quat_to_matrix(odometry.quat), odometry.position
        self._waiting.append((odometry.stamp_ns, odometry.frame_id, T, time.monotonic()))
        while len(self._waiting) > self.params["max_waiting_poses"]:
            self._pose(*self._waiting.popleft())
        self._drain()
        return odometry.stamp_ns

    def _drain(self) -> None:
        now = time.monotonic()
        while self._waiting:
            stamp_ns, _, _, received = self._waiting[0]
            covered = self._offset_ns is not None and self._covered(stamp_ns + self._offset_ns)
            if not covered and now - received < self.params["suit_wait_s"]:
                return
            self._pose(*self._waiting.popleft())

    def _covered(self, suit_ns: int) -> bool:
        """Whether every segment has sent a sample at or after ``suit_ns``."""
        return len(self._newest) == len(self._raw) and min(self._newest.values()) >= suit_ns

    def _pose(self, stamp_ns: int, frame_id: str, T_map_P: np.ndarray, received: float) -> None:
        """Pose and publish the body at one fused pelvis pose, or count why not."""
        if self._offset_ns is None:
            self.count_frame("skipped: no suit clock offset", f"{stamp_ns}: none received on "
                                                              f"{self.params['offset_topic']}")
            return
        if self._scale_from_height:
            self._scale_from_height = False
            try:
                scale = self.body.scale_to_pelvis_height(float(T_map_P[2, 3]))
            except ValueError as exc:
                self.get_logger().warning(f"body left at the contract's size: {exc}")
            else:
                self.get_logger().info(f"body scaled to the standing pelvis height {T_map_P[2, 3]:.3f} m: "
                                       f"{scale:.3f} x the contract skeleton")
        self._decode()
        pose, reason = self.body.pose(stamp_ns + self._offset_ns, T_map_P)
        if pose is None:
            self.count_frame("skipped: suit data missing", f"{stamp_ns}: {reason}")
            return
        if reason:
            self._degraded += 1
            self.get_logger().info(f"pose at {stamp_ns} with held suit data: {reason}", throttle_duration_sec=2.0)
        for topic, (_, msg) in pose_messages(self.backend, HSC4D_TOPICS, self.body.skeleton, stamp_ns, frame_id,
                                             pose.local_rot, pose.glob_rot, pose.joints).items():
            self._out[topic].publish(msg)
        self.count_frame("pose")
        self._latency.add(time.monotonic() - received)

    def frame_status(self) -> tuple[DiagnosticLevel, str, dict[str, Any]]:
        """Poses published, the body's scale, poses waiting, latencies."""
        level = DiagnosticLevel.OK if self.frames["pose"] else DiagnosticLevel.WARN
        return level, "posing" if self.frames["pose"] else "no pose yet", {
            "body scale": f"{self.body.skeleton.scale:.3f}", "poses with held suit data": self._degraded,
            "pending": len(self._waiting), **{f"suit samples rejected: {k}": v for k, v in self._rejected.items()},
            **self._latency.values("latency_ms")}


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros hsc4d_body_node``."""
    return run_nodes(BodyNode.NAME, __doc__.split("\n\n")[0], [BodyNode], [BodyNode], argv)


if __name__ == "__main__":
    raise SystemExit(main())
