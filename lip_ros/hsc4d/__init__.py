"""The HSC4D branch, ROS-free: a hip-worn Ouster and a 17-IMU suit ("Human-centered 4D Scene Capture").

Not built yet (its own issue). What goes here: LiDAR odometry and mapping
(kiss-icp, wrapped in one module), time sync by the jump, LiDAR-to-pelvis
extrinsics, the pose graph fusing the LiDAR trajectory with the suit's motion
(gtsam, wrapped in one module) and the scene-aware optimisation (foot
contact, sliding, smoothness). Like :mod:`lip_ros.lip` it uses
:mod:`lip_ros.core` and never imports the other branch; its nodes go in
:mod:`lip_ros.nodes.hsc4d`.
"""
