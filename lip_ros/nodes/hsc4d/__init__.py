"""rclpy nodes of the HSC4D branch: ``hsc4d_trajectory_node`` -> ``hsc4d_body_node``, and
:mod:`~lip_ros.nodes.hsc4d.graph`, both in one process (what ``fusion_node -p branch:=hsc4d`` runs)."""

from rclpy.qos import QoSProfile, ReliabilityPolicy

#: The HSC4D graph's parameter file in ``params/``: every HSC4D node's parameters and their defaults.
HSC4D_PARAMS_FILE = "hsc4d.yaml"
#: Values of ``hsc4d_trajectory_node``'s ``frames`` status on /diagnostics that tools read (here, not in its module,
#: for tools that read /diagnostics without loading the graph): the suit's clock offset, and what the checks of the
#: mounting at the start found
OFFSET_VALUE = "suit clock offset (ms)"
MOUNT_SPIN_VALUE = "mounting's spin (the ground at the start)"
MOUNT_HIP_VALUE = "mounting's hip (the wearer's body at the start)"
#: ... and of ``hsc4d_body_node``'s: the frames waiting for the scene-aware optimisation
OPTIMISING_VALUE = "optimisation: frames waiting"
#: QoS of the fused odometry, published by the trajectory node and read by the body node in another process: after
#: the jump the poses of the sweeps held for it come 40-60 a second while the body node may be a second and a half
#: in its first optimisation (reliable with a history of 50 lost 12 poses at 20 Hz); both ends keep 200
FUSED_ODOMETRY_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
