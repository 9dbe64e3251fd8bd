"""Synthetic capture rig: body motion, LiDAR ray casting, IMU physics, noise, bags (ROS-free)."""
