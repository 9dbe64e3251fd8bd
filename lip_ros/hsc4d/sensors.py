"""The HSC4D branch's sensors and topic names (the contract's): the one source of every default topic.

The node parameters in ``params/hsc4d.yaml`` restate these (a test keeps them
equal); remap or set parameters to use other names.
"""

from __future__ import annotations

from lip_ros.outputs import PoseTopics

__all__ = ["HIP_LIDAR_TOPIC", "SUIT_ODOMETRY_TOPIC", "suit_imu_topic", "ODOMETRY_TOPIC", "MAP_TOPIC",
           "SUIT_CLOCK_OFFSET_TOPIC", "MAP_FRAME", "PELVIS_FRAME", "HSC4D_TOPICS", "OPTIMISED_ODOMETRY_TOPIC",
           "OPTIMISED_TOPICS", "REFINED_ODOMETRY_TOPIC", "REFINED_TOPICS", "REFINED_MAP_TOPIC", "SUIT_RATE_HZ"]

#: The hip-worn Ouster's PointCloud2.
HIP_LIDAR_TOPIC = "/hip/points"
#: The suit's own root trajectory (nav_msgs/Odometry, its clock).
SUIT_ODOMETRY_TOPIC = "/mocap/odometry"
#: The rate of each suit segment's IMU and of the suit's odometry (samples per second).
SUIT_RATE_HZ = 100.0


def suit_imu_topic(segment: str) -> str:
    """The sensor_msgs/Imu topic of one suit segment (``suit_imus`` of the skeleton)."""
    return f"/mocap/{segment}/imu"


#: Out: the fused pelvis trajectory (nav_msgs/Odometry in :data:`MAP_FRAME`).
ODOMETRY_TOPIC = "/hsc4d/odometry"
#: Out (latched): the map of the whole site seen so far (PointCloud2 in :data:`MAP_FRAME`).
MAP_TOPIC = "/hsc4d/map"
#: Out (latched), between the graph's nodes: the suit's clock offset once the jump gave it (std_msgs/Int64, ns;
#: suit stamp = LiDAR stamp + offset).
SUIT_CLOCK_OFFSET_TOPIC = "/hsc4d/suit_clock_offset"
#: The gravity-aligned frame of every output (z up, origin on the ground under the first pelvis position).
MAP_FRAME = "map"
#: The fused pelvis's frame (the odometry's child frame and the /tf child).
PELVIS_FRAME = "pelvis"
#: The fused body's pose outputs.
HSC4D_TOPICS = PoseTopics("/hsc4d/joint_states", "/hsc4d/root_pose", "/hsc4d/joint_poses")
#: Out, beyond the contract: the pelvis after the scene-aware optimisation (nav_msgs/Odometry in :data:`MAP_FRAME`),
#: a window of frames behind the fused one.
OPTIMISED_ODOMETRY_TOPIC = "/hsc4d/optimised/odometry"
#: Out, beyond the contract: the body after the scene-aware optimisation.
OPTIMISED_TOPICS = PoseTopics("/hsc4d/optimised/joint_states", "/hsc4d/optimised/root_pose",
                              "/hsc4d/optimised/joint_poses")
#: Written by ``lip_process_bag --refine`` (the offline refinement, lip_ros.hsc4d.refinement): the pelvis
#: (nav_msgs/Odometry in :data:`MAP_FRAME`), the body, and the site's map rebuilt from the refined trajectory (S_opt).
REFINED_ODOMETRY_TOPIC = "/hsc4d/refined/odometry"
REFINED_TOPICS = PoseTopics("/hsc4d/refined/joint_states", "/hsc4d/refined/root_pose", "/hsc4d/refined/joint_poses")
REFINED_MAP_TOPIC = "/hsc4d/refined/map"
