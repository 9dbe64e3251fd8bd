"""Command-line tools of lip_ros: bag play, record and process (rclpy), the rig (``lip_rig``), LIP training
(``lip_train``) and evaluation (``lip_eval``), the URDF generator. Each is a thin front end to the ROS-free code."""
