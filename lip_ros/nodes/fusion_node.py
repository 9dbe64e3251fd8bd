"""fusion_node: the whole LIP graph in one process.

Runs ``segmentation_node``, ``calibration_node`` and ``pose_node`` (each also
an executable of its own, to split the graph over processes or machines) in
one process, each node on its own thread with a single-threaded executor (and
one mutually exclusive callback group): the stages work in parallel on
consecutive frames while each stage sees its messages one at a time. Parameters come from the shipped
``params/lip.yaml`` and ``--ros-args`` (``-p name:=value`` applies to every
node that has the parameter, ``--params-file`` sections to the named node).
Being in one process, the graph also reports its latency from cloud receipt to
pose publication (``pose_node: frames``, ``graph_latency_ms_*``).
"""

from __future__ import annotations

from lip_ros.nodes.base import FrameArrivals, run_nodes
from lip_ros.nodes.calibration_node import CalibrationNode
from lip_ros.nodes.pose_node import PoseNode
from lip_ros.nodes.segmentation_node import SegmentationNode

__all__ = ["GRAPH", "main"]

#: The nodes of the LIP graph, in the order of the data.
GRAPH = (SegmentationNode, CalibrationNode, PoseNode)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros fusion_node``."""
    arrivals = FrameArrivals()
    factories = [lambda: SegmentationNode(arrivals), CalibrationNode, lambda: PoseNode(arrivals)]
    return run_nodes("fusion_node", __doc__.split("\n\n")[0], factories, GRAPH, argv)


if __name__ == "__main__":
    raise SystemExit(main())
