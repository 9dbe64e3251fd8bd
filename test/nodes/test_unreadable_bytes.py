"""Bytes that are not a message of their type (a bridge or a bad writer; DDS itself delivers typed data) are
rejected as malformed by the LIP nodes that read their inputs' bytes, never raised out of the callback."""

from __future__ import annotations

import pytest
import rclpy

from lip_msgs_py import MalformedMessageError
from lip_ros.nodes.lip.calibration import CalibrationNode
from lip_ros.nodes.lip.segmentation import SegmentationNode

pytestmark = pytest.mark.ros

_GARBAGE = b"\x00\x00\x00\x00\x01"  # a CDR encapsulation header that is not little-endian, then one byte


def test_unreadable_dot_and_cloud_bytes_are_rejected_as_malformed() -> None:
    rclpy.init()
    nodes = [CalibrationNode(), SegmentationNode()]
    try:
        with pytest.raises(MalformedMessageError, match="Imu CDR"):
            nodes[0]._on_imu("left_wrist", _GARBAGE)
        with pytest.raises(MalformedMessageError, match="PointCloud2 CDR"):
            nodes[1]._on_cloud(_GARBAGE)
        assert nodes[1].frames["skipped: malformed cloud"] == 1
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
