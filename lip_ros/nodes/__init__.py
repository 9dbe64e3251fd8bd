"""rclpy nodes of lip_ros: thin wrappers (parameters, QoS, messages, diagnostics) around the ROS-free code.

:mod:`~lip_ros.nodes.base` is what every node shares, :mod:`~lip_ros.nodes.lip`
and :mod:`~lip_ros.nodes.hsc4d` the nodes of each branch, and
:mod:`~lip_ros.nodes.fusion_node` the one command that starts a branch's graph.
"""
