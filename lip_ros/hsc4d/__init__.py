"""The HSC4D branch, ROS-free: a hip-worn Ouster and a 17-IMU suit ("Human-centered 4D Scene Capture").

Being built (its own issue). Here so far: :mod:`~lip_ros.hsc4d.jump_sync`,
the suit's clock against the LiDAR's from the jump;
:mod:`~lip_ros.hsc4d.mount`, the nominal hip mounting;
:mod:`~lip_ros.hsc4d.pelvis_rotation`, the LiDAR's rotation over a sweep from
the suit's pelvis IMU; :mod:`~lip_ros.hsc4d.lidar_odometry`, LiDAR odometry
and mapping on kiss-icp (the one module that imports it). To come:
LiDAR-to-pelvis extrinsics, the pose graph fusing the LiDAR trajectory with
the suit's motion (gtsam, wrapped in one module) and the scene-aware
optimisation (foot contact, sliding, smoothness). Like :mod:`lip_ros.lip` it
uses :mod:`lip_ros.core` and never imports the other branch; its nodes go in
:mod:`lip_ros.nodes.hsc4d`.
"""
