"""segmentation_node: the Ouster cloud in, the performer's points out.

Subscribes to the LiDAR (SensorDataQoS; the message's bytes, read in place
by ``lip_msgs_py.cdr.cloud_msg``), finds the performer
(:class:`lip_ros.lip.segmentation.PerformerSegmenter`) and publishes their
points as an unorganized ``x y z`` PointCloud2 on ``performer_topic``
(reliable), stamped with the frame's pose time (header.stamp + the mean ``t``
of the performer's points, when the pose holds), in the cloud's frame. Frames
without a performer (none yet, lost, empty, unreadable) end here, each
counted by reason on /diagnostics.

With ``performer_file`` set, the performer's position is written there (at
most once a second) and read at start-up: a restarted node locks onto the
person nearest to it at once instead of waiting for a T-pose.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import yaml
from geometry_msgs.msg import PoseStamped
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import PointCloud2

from lip_msgs_py import DiagnosticLevel, MalformedMessageError, cloud_to_array, read_header, xyz_to_cloud
from lip_msgs_py.cdr import cloud_msg
from lip_ros.lip.segmentation import LOCK_RULES, PerformerSegmenter, SegmentationConfig, SegmentationStatus
from lip_ros.nodes.base import (
    LATCHED,
    FrameArrivals,
    GraphNode,
    LatencyWindow,
    Param,
    ParameterError,
    numbers,
    positive,
    run_nodes,
)
from lip_ros.nodes.lip import LIP_PARAMS_FILE
from lip_ros.nodes.lip.ground import GROUND_PARAM, describe_level, ground_message

__all__ = ["SegmentationNode", "main"]


class SegmentationNode(GraphNode):
    """Performer segmentation of every LiDAR frame."""

    NAME = "segmentation_node"
    PARAMS_FILE = LIP_PARAMS_FILE
    PARAMS = {
        "lidar_name": Param("name of the LiDAR in diagnostics"),
        "lidar_topic": Param("the Ouster PointCloud2 input"),
        "performer_topic": Param("output: the performer's points, stamped with the pose time"),
        "performer_file": Param("the performer's last position: read at start to resume, written while tracking "
                                "('' = none)"),
        "lock_rule": Param("how the performer is found: " + ", ".join(LOCK_RULES) + " (t_pose: the calibration's "
                           "T-pose; still: standing still near expected_xy)",
                           lambda v: None if v in LOCK_RULES else f"must be one of {', '.join(LOCK_RULES)}, got {v!r}"),
        "expected_xy": Param("where the performer calibrates, [x, y] m in the LiDAR frame ([] = anywhere)",
                             numbers(0, 2), any_type=True),
        "expected_radius_m": Param("the performer is looked for within this of expected_xy", positive),
        "ground_plane": Param("the ground, [a, b, c, d] with a x + b y + c z + d = 0 in the LiDAR frame "
                              "([] = fitted to the first frame)", numbers(0, 4), any_type=True),
        "ground_topic": GROUND_PARAM,
    }

    def __init__(self, arrivals: FrameArrivals | None = None, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        p = self.params
        self._performer_file = Path(p["performer_file"]).expanduser() if p["performer_file"] else None
        try:
            config = SegmentationConfig(
                lock_rule=p["lock_rule"], expected_xy=tuple(map(float, p["expected_xy"])) or None,
                expected_radius_m=p["expected_radius_m"], ground_plane=tuple(map(float, p["ground_plane"])) or None,
                resume_xy=self._read_position())
        except ValueError as exc:
            raise ParameterError(str(exc)) from exc
        self._segmenter = PerformerSegmenter(config)
        self._saved_at = 0.0
        self._arrivals = arrivals
        self._latency = LatencyWindow()
        self._last_status = "no frame yet"
        self._pub = self.create_between_publisher(PointCloud2, p["performer_topic"])
        self._ground_pub = self.create_publisher(PoseStamped, p["ground_topic"], LATCHED)
        self._ground_sent = False
        # raw: read in place (rclpy's message object of a 1024-column cloud costs about 10 ms to build)
        self.add_input(p["lidar_name"], p["lidar_topic"], PointCloud2, p["lidar_rate_hz"], self._on_cloud, raw=True,
                       # ouster-ros stamps the sweep's start
                       stamped_at=1.0 / p["lidar_rate_hz"], count_missing=True)

    def _on_cloud(self, data: bytes) -> int:
        received = time.monotonic()
        msg = cloud_msg(data)
        if msg is None:  # not plain little-endian CDR: deserialised in full
            try:
                msg = deserialize_message(data, PointCloud2)
            except RuntimeError as exc:
                self._last_status = f"malformed cloud: {exc}"
                self.count_frame("skipped: malformed cloud", f"unreadable message: {exc}")
                raise MalformedMessageError(f"PointCloud2 CDR: {exc}") from exc
        stamp_ns, frame_id = read_header(msg)
        try:
            points = cloud_to_array(msg)
        except MalformedMessageError as exc:
            self._last_status = f"malformed cloud: {exc}"
            self.count_frame("skipped: malformed cloud", f"{stamp_ns}: {exc}")
            raise
        seg = self._segmenter.process(points, stamp_ns)
        if seg.clock_step_ns:
            self.get_logger().warning(f"the LiDAR's stamps stepped back {seg.clock_step_ns * 1e-9:.1f} s (a clock "
                                      "step, or a bag played again): tracking goes on from this frame")
        ground = self._segmenter.ground
        if ground is not None and not self._ground_sent:  # before the first performer cloud it levels
            self._ground_pub.publish(ground_message(self.backend, stamp_ns, frame_id, ground))
            self._ground_sent = True
            self.get_logger().info(f"ground fitted: the LiDAR is {ground.offset:.2f} m above it; "
                                   f"{describe_level(self._segmenter.level)}")
        self._last_status = f"{seg.status.value}: {seg.reason}" if seg.reason else seg.status.value
        if seg.status != SegmentationStatus.OK:
            self.count_frame(f"skipped: {seg.status.value}", f"{stamp_ns}: {self._last_status}")
            self._segmenter.learn()
            return stamp_ns
        if self._arrivals is not None:
            self._arrivals.mark(seg.pose_stamp_ns, received)
        self._latency.add(time.monotonic() - received)  # before publishing, which runs the rest of a composed graph
        self._pub.publish(xyz_to_cloud(self.backend, seg.points, seg.pose_stamp_ns, frame_id))
        self._segmenter.learn()  # the background, once the frame is out
        if self._performer_file is not None and received - self._saved_at >= 1.0:
            self._save_position(seg.position, seg.pose_stamp_ns)
            self._saved_at = received
        return stamp_ns

    def _read_position(self) -> tuple[float, float] | None:
        """The position saved by an earlier run, if any."""
        if self._performer_file is None or not self._performer_file.is_file():
            return None
        try:
            x, y = yaml.safe_load(self._performer_file.read_text(encoding="utf-8"))["xy"]
        except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
            self.get_logger().warning(f"ignoring performer_file {self._performer_file}: {exc}")
            return None
        self.get_logger().info(f"resuming: the performer was last seen at ({x:.2f}, {y:.2f}) m")
        return float(x), float(y)

    def _save_position(self, xy: Any, stamp_ns: int) -> None:
        """Write the position atomically (a crash never leaves half a file)."""
        tmp = self._performer_file.with_name(self._performer_file.name + ".tmp")
        tmp.write_text(yaml.safe_dump({"xy": [float(xy[0]), float(xy[1])], "stamp_ns": int(stamp_ns)}),
                       encoding="utf-8")
        os.replace(tmp, self._performer_file)

    def frame_status(self) -> tuple[DiagnosticLevel, str, dict[str, Any]]:
        """Level, message and values of the frames status: the last frame's segmentation state."""
        level = DiagnosticLevel.OK if self._last_status == SegmentationStatus.OK.value else DiagnosticLevel.WARN
        ground = self._segmenter.ground
        return level, self._last_status, {"performer clouds published": self._latency.count,
                                          "performer locked": self._segmenter.locked,
                                          "scan layout": self._segmenter.layout_description,
                                          "ground": "not found yet" if ground is None else (
                                              f"{ground.offset:.2f} m below the LiDAR; "
                                              f"{describe_level(self._segmenter.level)}"),
                                          **self._latency.values("latency_ms")}


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros segmentation_node``."""
    return run_nodes(SegmentationNode.NAME, __doc__.split("\n\n")[0], [SegmentationNode], [SegmentationNode], argv)


if __name__ == "__main__":
    raise SystemExit(main())
