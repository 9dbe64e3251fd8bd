"""rclpy nodes of the LIP branch: ``segmentation_node`` -> ``calibration_node`` -> ``pose_node``, and
:mod:`~lip_ros.nodes.lip.graph`, all three in one process (what ``fusion_node`` runs)."""

#: The LIP graph's parameter file in ``params/``: every LIP node's parameters and their defaults.
LIP_PARAMS_FILE = "lip.yaml"
