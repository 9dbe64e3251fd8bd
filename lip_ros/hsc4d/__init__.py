"""The HSC4D branch, ROS-free: a hip-worn Ouster and a 17-IMU suit ("Human-centered 4D Scene Capture").

Partly built (its own issue). The live trajectory, :mod:`~lip_ros.hsc4d.trajectory`,
puts together: :mod:`~lip_ros.hsc4d.jump_sync` (the suit's clock from the
jump) with :mod:`~lip_ros.hsc4d.sweep_height` (the LiDAR's height from each
sweep's ground); :mod:`~lip_ros.hsc4d.pelvis_rotation` (the LiDAR's rotation
and vertical motion from the suit's pelvis IMU, less its gyro's bias from
:mod:`~lip_ros.hsc4d.gyro_bias`) and
:mod:`~lip_ros.hsc4d.suit_track` (its motion from the suit's own odometry);
:mod:`~lip_ros.hsc4d.lidar_odometry` (kiss-icp, the one module that imports
it); :mod:`~lip_ros.hsc4d.map_frame`; :mod:`~lip_ros.hsc4d.mount` (the nominal
mounting and its estimate); :mod:`~lip_ros.hsc4d.pose_graph` (gtsam, the one
module that imports it). :mod:`~lip_ros.hsc4d.suit_body` poses the suit's
segments on the fused pelvis; :mod:`~lip_ros.hsc4d.sensors` names the topics;
:mod:`~lip_ros.hsc4d.suit_restart` tells a new capture (a bag played again) from a clock step.
:mod:`~lip_ros.hsc4d.scene_optimisation` (torch, the one module that imports
it) moves the fused body onto the scene window by window (foot contact,
sliding, orientation, smoothness), the legs' length from the walk
(:mod:`~lip_ros.hsc4d.leg_scale`); live, each window is solved on a thread of
its own (:mod:`~lip_ros.hsc4d.background_optimiser`).
:mod:`~lip_ros.hsc4d.site_map` keeps the whole site's map;
:mod:`~lip_ros.hsc4d.resume` what a restarted trajectory goes on from;
:mod:`~lip_ros.hsc4d.refinement` refines a whole capture offline
(:mod:`~lip_ros.hsc4d.batch`: a bag through it).
:mod:`~lip_ros.hsc4d.evaluation` measures trajectory and body on rig captures
against the paper's baselines. Like :mod:`lip_ros.lip`
it uses :mod:`lip_ros.core` and never imports the other branch; its nodes go in
:mod:`lip_ros.nodes.hsc4d`.
"""
