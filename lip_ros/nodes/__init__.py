"""rclpy nodes of lip_ros: thin wrappers (parameters, QoS, messages, diagnostics) around the core."""
