"""fusion_node: the LIP graph in one process.

At this stage of the project it is the graph's input stage: it subscribes to
the contract's LiDAR and IMU topics (SensorDataQoS), validates every message
through lip_msgs_py, accounts for each one (accepted or rejected with a
reason) and publishes per-sensor health on ``/diagnostics``. The pose stages
(segmentation, sync, calibration, networks) attach here as they land.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import Imu, PointCloud2

from lip_msgs_py import (
    MalformedMessageError,
    RclpyBackend,
    cloud_to_xyz,
    diagnostic_array_to_msg,
    diagnostic_status_to_msg,
    msg_to_imu,
    read_header,
)
from lip_ros.core.sensor_monitor import SensorMonitor
from lip_ros.middleware import use_lip_dds_profile

NODE_NAME = "fusion_node"
DEFAULT_IMUS = ("left_wrist", "right_wrist", "left_ankle", "right_ankle")


def _checked_cloud_stamp(msg: PointCloud2) -> int:
    """The cloud's stamp, after checking its layout by reading its points."""
    cloud_to_xyz(msg)
    return read_header(msg)[0]


class ParameterError(ValueError):
    """A parameter value the node cannot run with."""


class FusionNode(Node):
    """Input stage of the LIP graph: subscriptions, validation and sensor diagnostics."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self._read_parameters()
        self._backend = RclpyBackend()
        self._monitors: dict[str, tuple[str, SensorMonitor]] = {}
        self._add_input(p["lidar_name"], p["lidar_topic"], PointCloud2, p["lidar_rate_hz"], p["stale_after_s"],
                        _checked_cloud_stamp)
        for name, topic in zip(p["imu_names"], p["imu_topics"]):
            self._add_input(name, topic, Imu, p["imu_rate_hz"], p["stale_after_s"], lambda msg: msg_to_imu(msg).stamp_ns)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics",
                                               QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics)

    def _read_parameters(self) -> dict[str, Any]:
        d = self.declare_parameter
        values = {
            "lidar_name": d("lidar_name", "ouster").value,
            "lidar_topic": d("lidar_topic", "/ouster/points").value,
            "lidar_rate_hz": d("lidar_rate_hz", 10.0).value,
            "imu_names": list(d("imu_names", list(DEFAULT_IMUS)).value),
            "imu_topics": list(d("imu_topics", [f"/dot/{n}/imu" for n in DEFAULT_IMUS]).value),
            "imu_rate_hz": d("imu_rate_hz", 60.0).value,
            "stale_after_s": d("stale_after_s", 1.0).value,
            "diagnostics_period_s": d("diagnostics_period_s", 1.0).value,
        }
        if len(values["imu_names"]) != len(values["imu_topics"]):
            raise ParameterError(f"imu_names ({len(values['imu_names'])}) and imu_topics "
                                 f"({len(values['imu_topics'])}) must have the same length")
        for key in ("lidar_rate_hz", "imu_rate_hz", "stale_after_s", "diagnostics_period_s"):
            if not values[key] > 0:
                raise ParameterError(f"{key} must be > 0, got {values[key]}")
        return values

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _add_input(self, name: str, topic: str, msg_type: type, rate_hz: float, stale_after_s: float,
                   stamp_of: Callable[[Any], int]) -> None:
        monitor = SensorMonitor(name, expected_rate_hz=rate_hz, stale_after_s=stale_after_s)
        self._monitors[name] = (topic, monitor)

        def callback(msg: Any) -> None:
            now = self._now_s()
            try:
                monitor.accept(now, stamp_of(msg))
            except MalformedMessageError as exc:
                monitor.reject(now, str(exc).split(":")[0][:60])
                self.get_logger().warning(f"{name} ({topic}): message skipped: {exc}", throttle_duration_sec=5.0)

        self.create_subscription(msg_type, topic, callback, qos_profile_sensor_data)

    def _publish_diagnostics(self) -> None:
        now = self._now_s()
        statuses = []
        for topic, monitor in self._monitors.values():
            r = monitor.report(now)
            values = {"rate_hz": f"{r.rate_hz:.2f}", "received": r.received, "accepted": r.accepted,
                      "out_of_order": r.out_of_order, "age_s": "none" if r.age_s is None else f"{r.age_s:.3f}"}
            values.update({f"rejected: {k}": v for k, v in r.rejected.items()})
            statuses.append(diagnostic_status_to_msg(self._backend, int(r.health), f"{NODE_NAME}: {r.name}",
                                                     r.message, hardware_id=topic, values=values))
        self._diag_pub.publish(diagnostic_array_to_msg(self._backend, self.get_clock().now().nanoseconds, statuses))


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros fusion_node``."""
    argv = sys.argv if argv is None else argv
    parser = argparse.ArgumentParser(prog=NODE_NAME, description=__doc__.split("\n\n")[0],
                                     epilog="ROS arguments go after --ros-args (remapping, -p name:=value, "
                                            "--params-file params/lip_ros.yaml, use_sim_time).")
    parser.parse_args(rclpy.utilities.remove_ros_args(argv)[1:])
    use_lip_dds_profile()
    rclpy.init(args=argv)
    try:
        node = FusionNode()
    except ParameterError as exc:
        print(f"{NODE_NAME}: parameter error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
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
