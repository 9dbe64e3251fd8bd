"""lip_msgs_py: ROS messages to and from numpy, for rclpy and rosbags message objects alike."""
