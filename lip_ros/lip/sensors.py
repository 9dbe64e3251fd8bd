"""The LIP branch's sensors and topic names: the one source of the DOT order and of every default topic.

The node parameters in ``params/lip.yaml`` and the contract skeleton's
``lip_imus`` restate these (a test keeps them equal); remap or set
parameters to use other names.
"""

from __future__ import annotations

from lip_ros.outputs import PoseTopics

__all__ = ["IMU_NAMES", "LIDAR_TOPIC", "IMU_TOPICS", "INPUT_TOPICS", "LIP_TOPICS"]

#: The four DOTs in network input order (the paper's lw, rw, la, ra).
IMU_NAMES = ("left_wrist", "right_wrist", "left_ankle", "right_ankle")

#: The static Ouster's PointCloud2 (ouster-ros' default topic).
LIDAR_TOPIC = "/ouster/points"

#: Each DOT's sensor_msgs/Imu topic, by name, in the order of :data:`IMU_NAMES`.
IMU_TOPICS = {name: f"/dot/{name}/imu" for name in IMU_NAMES}

#: Every input topic of the LIP graph: the LiDAR, then the DOTs.
INPUT_TOPICS = (LIDAR_TOPIC, *IMU_TOPICS.values())

#: The pose outputs of the LIP graph.
LIP_TOPICS = PoseTopics("/lip/joint_states", "/lip/root_pose", "/lip/joint_poses", "/lip/skeleton")
