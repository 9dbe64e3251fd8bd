"""rclpy nodes of the HSC4D branch (not built yet): thin wrappers around :mod:`lip_ros.hsc4d`, started by
``fusion_node`` when it runs that branch."""
