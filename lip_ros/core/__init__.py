"""ROS-free core of lip_ros: math, skeleton, and (later) segmentation, sync, calibration, networks."""
