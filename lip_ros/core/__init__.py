"""The shared, ROS-free base of both branches: rotations, frames, the contract skeleton and its kinematics
(numpy and torch), the URDF, the capsule body surface, IMU synchronisation, exact-stamp joins, sensor health
bookkeeping, the accuracy metrics and the column azimuths of organized LiDAR clouds. It imports neither branch."""
