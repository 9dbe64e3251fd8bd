"""rclpy nodes of the LIP branch: ``segmentation_node`` -> ``calibration_node`` -> ``pose_node``, and
:mod:`~lip_ros.nodes.lip.graph`, all three in one process (what ``fusion_node`` runs)."""

#: The LIP graph's parameter file in ``params/``: every LIP node's parameters and their defaults.
LIP_PARAMS_FILE = "lip.yaml"
#: ``calibration_node``'s name, and the value of its ``<name>: frames`` status on /diagnostics with the DOT
#: latencies in use (here, not in its module, for tools that read /diagnostics without loading the graph)
CALIBRATION_NODE_NAME = "calibration_node"
DOT_LATENCY_VALUE = "DOT latency taken off (ms)"
