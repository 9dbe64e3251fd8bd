"""rclpy nodes of the HSC4D branch: ``hsc4d_trajectory_node`` -> ``hsc4d_body_node``, and
:mod:`~lip_ros.nodes.hsc4d.graph`, both in one process (what ``fusion_node -p branch:=hsc4d`` runs)."""

#: The HSC4D graph's parameter file in ``params/``: every HSC4D node's parameters and their defaults.
HSC4D_PARAMS_FILE = "hsc4d.yaml"
