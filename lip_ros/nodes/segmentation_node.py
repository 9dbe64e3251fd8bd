"""segmentation_node: the Ouster cloud in, the performer's points out.

Subscribes to the LiDAR (SensorDataQoS), finds the performer
(:class:`lip_ros.core.segmentation.PerformerSegmenter`) and publishes their
points as an unorganized ``x y z`` PointCloud2 on ``performer_topic``
(reliable), stamped with the frame's pose time (header.stamp + the mean ``t``
of the performer's points, when the pose holds), in the cloud's frame. Frames
without a performer (none yet, lost, empty, unreadable) end here, each
counted by reason on /diagnostics.
"""

from __future__ import annotations

import time
from typing import Any

from sensor_msgs.msg import PointCloud2

from lip_msgs_py import DiagnosticLevel, MalformedMessageError, cloud_to_array, read_header, xyz_to_cloud
from lip_ros.core.segmentation import PerformerSegmenter, SegmentationStatus
from lip_ros.nodes.base import RELIABLE, FrameArrivals, LatencyWindow, LipNode, Param, run_nodes

__all__ = ["SegmentationNode", "main"]


class SegmentationNode(LipNode):
    """Performer segmentation of every LiDAR frame."""

    NAME = "segmentation_node"
    PARAMS = {
        "lidar_name": Param("name of the LiDAR in diagnostics"),
        "lidar_topic": Param("the Ouster PointCloud2 input"),
        "performer_topic": Param("output: the performer's points, stamped with the pose time"),
    }

    def __init__(self, arrivals: FrameArrivals | None = None, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        p = self.params
        self._segmenter = PerformerSegmenter()
        self._arrivals = arrivals
        self._latency = LatencyWindow()
        self._last_status = "no frame yet"
        self._pub = self.create_publisher(PointCloud2, p["performer_topic"], RELIABLE)
        self.add_input(p["lidar_name"], p["lidar_topic"], PointCloud2, p["lidar_rate_hz"], self._on_cloud)

    def _on_cloud(self, msg: PointCloud2) -> int:
        received = time.monotonic()
        stamp_ns, frame_id = read_header(msg)
        try:
            points = cloud_to_array(msg)
        except MalformedMessageError:
            self.count_frame("skipped: malformed cloud")
            raise
        seg = self._segmenter.process(points, stamp_ns)
        self._last_status = f"{seg.status.value}: {seg.reason}" if seg.reason else seg.status.value
        if seg.status != SegmentationStatus.OK:
            self.count_frame(f"skipped: {seg.status.value}", f"{stamp_ns}: {self._last_status}")
            return stamp_ns
        if self._arrivals is not None:
            self._arrivals.mark(seg.pose_stamp_ns, received)
        self._pub.publish(xyz_to_cloud(self.backend, seg.points, seg.pose_stamp_ns, frame_id))
        self._latency.add(time.monotonic() - received)
        return stamp_ns

    def frame_status(self) -> tuple[DiagnosticLevel, str, dict[str, Any]]:
        """Level, message and values of the frames status: the last frame's segmentation state."""
        level = DiagnosticLevel.OK if self._last_status == SegmentationStatus.OK.value else DiagnosticLevel.WARN
        return level, self._last_status, {"performer clouds published": self._latency.count,
                                          "performer locked": self._segmenter.locked,
                                          **self._latency.values("latency_ms")}


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros segmentation_node``."""
    return run_nodes(SegmentationNode.NAME, __doc__.split("\n\n")[0], [SegmentationNode], [SegmentationNode], argv)


if __name__ == "__main__":
    raise SystemExit(main())
