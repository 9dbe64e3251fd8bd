"""The whole LIP graph in one process: what ``fusion_node`` runs for the LIP branch.

Runs ``segmentation_node``, ``calibration_node`` and ``pose_node`` (each also
an executable of its own, to split the graph over processes or machines) in
one process, each node on its own thread with a single-threaded executor (and
one mutually exclusive callback group). Between them the performer's points and
the bones go by direct calls (:class:`lip_ros.nodes.base.LocalTopics`; still
published over DDS for recorders and tools; ``direct_inputs:=false`` takes them
through DDS instead, the stages overlapping on consecutive frames): a frame runs from the cloud's
callback to its pose outputs on one thread, without a wake-up between the
stages, while the DOTs' samples are taken on the calibration node's thread
(each node's callbacks serialised by its own lock). Parameters come from the shipped
``params/lip.yaml`` and ``--ros-args`` (``-p name:=value`` applies to every
node that has the parameter, ``--params-file`` sections to the named node).
Being in one process, the graph also reports its latency from cloud receipt to
pose publication (``pose_node: frames``, ``graph_latency_ms_*``).
"""

from __future__ import annotations

from lip_ros.nodes.base import FrameArrivals, LocalTopics, run_nodes
from lip_ros.nodes.lip.calibration import CalibrationNode
from lip_ros.nodes.lip.pose import PoseNode
from lip_ros.nodes.lip.segmentation import SegmentationNode

__all__ = ["LIP_GRAPH", "run_lip_graph"]

#: The nodes of the LIP graph, in the order of the data.
LIP_GRAPH = (SegmentationNode, CalibrationNode, PoseNode)


def run_lip_graph(prog: str, description: str, argv: list[str] | None = None) -> int:
    """Run the LIP graph in this process until shutdown; the exit status (``prog``, ``description``: the
    command line's name and help)."""
    arrivals, topics = FrameArrivals(), LocalTopics()
    factories = [lambda: SegmentationNode(arrivals, local_topics=topics),
                 lambda: CalibrationNode(local_topics=topics), lambda: PoseNode(arrivals, local_topics=topics)]
    return run_nodes(prog, description, factories, LIP_GRAPH, argv)
