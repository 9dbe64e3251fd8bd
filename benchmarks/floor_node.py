"""The transport floor of the LIP graph: a node that only receives the Ouster cloud and publishes a PoseStamped.

It subscribes to the cloud as ``segmentation_node`` does (SensorDataQoS, the
message's bytes, whose header is read in place), and publishes on :data:`FLOOR_TOPIC` an
identity PoseStamped with the cloud's stamp (reliable, as ``/lip/root_pose``).
``bench_graph.py`` starts it beside the graph in the same run: the latency from
the player's publication to this pose's reception is what any node pays to
receive a cloud and answer, whatever it computes; the graph's latency above it
is the graph's own (the method, its hops between nodes, its waiting).

Run: python benchmarks/floor_node.py [--ros-args ...]   (bench_graph.py does)
"""

from __future__ import annotations

import sys

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2

from lip_msgs_py.cdr import cdr_stamp
from lip_msgs_py.stamps import NS_PER_S
from lip_ros.lip.sensors import LIDAR_TOPIC
from lip_ros.middleware import keep_message_buffers, use_lip_dds_profile

__all__ = ["FLOOR_TOPIC", "main"]

#: Where the pass-through answers each cloud.
FLOOR_TOPIC = "/bench/floor_pose"


def main() -> int:
    """Pass clouds through until SIGINT."""
    if not keep_message_buffers():  # as the graph's executables: a cloud's copies reuse the last one's memory
        print("floor_node: message buffers not kept (malloc options set by the user, or not glibc): the floor "
              "pays for page faults the graph may not", file=sys.stderr)
    use_lip_dds_profile()
    rclpy.init(args=sys.argv)
    node = rclpy.create_node("floor_node")
    pub = node.create_publisher(PoseStamped, FLOOR_TOPIC, QoSProfile(depth=10,
                                                                      reliability=ReliabilityPolicy.RELIABLE))

    def answer(data: bytes) -> None:
        pose = PoseStamped()
        pose.header.stamp.sec, pose.header.stamp.nanosec = divmod(cdr_stamp(data), NS_PER_S)
        pose.pose.orientation.w = 1.0
        pub.publish(pose)

    node.create_subscription(PointCloud2, LIDAR_TOPIC, answer, qos_profile_sensor_data, raw=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
