"""The LIP branch, ROS-free: a static Ouster and four DOTs on the wrists and ankles ("LiDAR-aid Inertial Poser").

:mod:`~lip_ros.lip.sensors` (the DOTs, their order and the default topics),
:mod:`~lip_ros.lip.segmentation` (the performer's points),
:mod:`~lip_ros.lip.calibration` (A/T-pose calibration),
:mod:`~lip_ros.lip.stages` (the IMU stage and the pose stage that the nodes run),
:mod:`~lip_ros.lip.pipeline` (every stage in one object), :mod:`~lip_ros.lip.batch`
(a bag through it), :mod:`~lip_ros.lip.nets` (the networks),
:mod:`~lip_ros.lip.train` and :mod:`~lip_ros.lip.evaluation`. It uses
:mod:`lip_ros.core`, never :mod:`lip_ros.hsc4d`.
"""
