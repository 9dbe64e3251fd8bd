"""fusion_node: the LIP graph in one process.

Subscribes to the Ouster cloud and the four DOT topics (SensorDataQoS),
validates every message through lip_msgs_py, runs :class:`lip_ros.pipeline.LipPipeline`
(segmentation, automatic A/T-pose calibration, IMU sync, the LIP network) and
publishes, for every frame with a pose, ``/lip/joint_states``,
``/lip/root_pose``, ``/lip/joint_poses`` and ``/lip/skeleton`` (reliable), all
stamped with the moment the performer was scanned. Every input is accounted
for on ``/diagnostics``: per-sensor rate, age and rejections, and the frames
with a pose, calibrating or skipped (by reason), and the calibration state.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import Imu, PointCloud2

from lip_msgs_py import (
    DiagnosticLevel,
    MalformedMessageError,
    RclpyBackend,
    cloud_to_array,
    diagnostic_array_to_msg,
    diagnostic_status_to_msg,
    msg_to_imu,
    read_header,
    rclpy_message_class,
)
from lip_ros.core.calibration import CalibrationError
from lip_ros.core.sensor_monitor import SensorMonitor
from lip_ros.middleware import use_lip_dds_profile
from lip_ros.nets.config import IMU_NAMES
from lip_ros.nets.lip_model import LipModel
from lip_ros.outputs import LIP_TOPICS, pose_messages
from lip_ros.pipeline import FrameResult, LipPipeline, Outcome, PipelineConfig

NODE_NAME = "fusion_node"


class ParameterError(ValueError):
    """A parameter value the node cannot run with."""


class FusionNode(Node):
    """The LIP graph in one node: inputs, pipeline, pose outputs, diagnostics."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self._read_parameters()
        self._backend = RclpyBackend()
        self._frame_id = p["frame_id"]
        self._monitors: dict[str, tuple[str, SensorMonitor]] = {}
        self._frames: Counter[str] = Counter()  # outcome or skip reason -> frames
        self._received_at: dict[int, float] = {}  # frame stamp -> steady time its cloud arrived
        self._latency_ms: deque[float] = deque(maxlen=200)  # cloud arrival -> pose published
        calibration_file = Path(p["calibration_file"]).expanduser() if p["calibration_file"] else None
        try:
            model = LipModel.load(Path(p["weights"]).expanduser() if p["weights"] else None)
        except (OSError, ValueError, RuntimeError) as exc:
            raise ParameterError(f"cannot load weights {p['weights'] or '(shipped)'}: {exc}") from exc
        try:
            self._pipeline = LipPipeline(model, PipelineConfig(calibration_file=calibration_file))
        except (OSError, ValueError, CalibrationError) as exc:
            raise ParameterError(f"cannot load calibration {calibration_file}: {exc}") from exc
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self._out = {
            topic: self.create_publisher(rclpy_message_class(msgtype), topic, reliable)
            for topic, msgtype in ((LIP_TOPICS.joint_states, "sensor_msgs/msg/JointState"),
                                   (LIP_TOPICS.root_pose, "geometry_msgs/msg/PoseStamped"),
                                   (LIP_TOPICS.joint_poses, "geometry_msgs/msg/PoseArray"),
                                   (LIP_TOPICS.skeleton, "visualization_msgs/msg/MarkerArray"))
        }
        self._add_input(p["lidar_name"], p["lidar_topic"], PointCloud2, p["lidar_rate_hz"], p["stale_after_s"],
                        self._on_cloud)
        for name, topic in zip(IMU_NAMES, p["imu_topics"]):
            self._add_input(name, topic, Imu, p["imu_rate_hz"], p["stale_after_s"],
                            lambda msg, name=name: self._on_imu(name, msg))
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", reliable)
        steady = Clock(clock_type=ClockType.STEADY_TIME)  # also ticks while a bag's /clock is paused or over
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics, clock=steady)
        self.create_timer(0.02, lambda: self._publish(self._pipeline.poll(self._now_ns())), clock=steady)
        self.get_logger().info(f"ready; {self._pipeline.calibration_status}")

    def _read_parameters(self) -> dict[str, Any]:
        d = self.declare_parameter
        values = {
            "lidar_name": d("lidar_name", "ouster").value,
            "lidar_topic": d("lidar_topic", "/ouster/points").value,
            "lidar_rate_hz": d("lidar_rate_hz", 10.0).value,
            "imu_topics": list(d("imu_topics", [f"/dot/{n}/imu" for n in IMU_NAMES]).value),
            "imu_rate_hz": d("imu_rate_hz", 60.0).value,
            "stale_after_s": d("stale_after_s", 1.0).value,
            "diagnostics_period_s": d("diagnostics_period_s", 1.0).value,
            "frame_id": d("frame_id", "os_lidar").value,
            "weights": d("weights", "").value,
            "calibration_file": d("calibration_file", "").value,
        }
        if len(values["imu_topics"]) != len(IMU_NAMES):
            raise ParameterError(f"imu_topics needs {len(IMU_NAMES)} topics, in the order {', '.join(IMU_NAMES)}; "
                                 f"got {len(values['imu_topics'])}")
        for key in ("lidar_rate_hz", "imu_rate_hz", "stale_after_s", "diagnostics_period_s"):
            if not values[key] > 0:
                raise ParameterError(f"{key} must be > 0, got {values[key]}")
        return values

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _add_input(self, name: str, topic: str, msg_type: type, rate_hz: float, stale_after_s: float,
                   handle: Callable[[Any], int]) -> None:
        monitor = SensorMonitor(name, expected_rate_hz=rate_hz, stale_after_s=stale_after_s)
        self._monitors[name] = (topic, monitor)

        def callback(msg: Any) -> None:
            now = self._now_ns() * 1e-9
            try:
                monitor.accept(now, handle(msg))
            except MalformedMessageError as exc:
                monitor.reject(now, str(exc).split(":")[0][:60])
                self.get_logger().warning(f"{name} ({topic}): message skipped: {exc}", throttle_duration_sec=5.0)

        self.create_subscription(msg_type, topic, callback, qos_profile_sensor_data)

    def _on_imu(self, name: str, msg: Imu) -> int:
        sample = msg_to_imu(msg)
        reason = self._pipeline.add_imu(name, sample)
        if reason is not None:
            raise MalformedMessageError(reason)
        return sample.stamp_ns

    def _on_cloud(self, msg: PointCloud2) -> int:
        stamp_ns = read_header(msg)[0]
        points = cloud_to_array(msg)
        self._received_at[stamp_ns] = time.monotonic()
        self._publish(self._pipeline.add_cloud(points, stamp_ns))
        self._publish(self._pipeline.poll(self._now_ns()))
        return stamp_ns

    def _publish(self, results: list[FrameResult]) -> None:
        for r in results:
            received = self._received_at.pop(r.frame_stamp_ns, None)
            if r.outcome == Outcome.POSE:
                self._frames[Outcome.POSE.value] += 1
                pose = r.pose
                for topic, (_, msg) in pose_messages(self._backend, LIP_TOPICS, self._pipeline.skeleton,
                                                     pose.stamp_ns, self._frame_id, pose.local_rot, pose.glob_rot,
                                                     pose.joint_pos).items():
                    self._out[topic].publish(msg)
                if received is not None:
                    self._latency_ms.append(1e3 * (time.monotonic() - received))
            else:
                key = r.outcome.value if r.outcome == Outcome.CALIBRATING else f"skipped: {r.reason.split(':')[0]}"
                self._frames[key] += 1
                self.get_logger().info(f"frame {r.frame_stamp_ns}: {r.outcome.value}: {r.reason}",
                                       throttle_duration_sec=2.0)

    def _latency_values(self) -> dict[str, str]:
        """Percentiles of the recent cloud-arrival-to-pose latencies."""
        if not self._latency_ms:
            return {}
        p50, p99 = np.percentile(np.array(self._latency_ms), [50, 99])
        return {"latency_ms_p50": f"{p50:.1f}", "latency_ms_p99": f"{p99:.1f}"}

    def _publish_diagnostics(self) -> None:
        now = self._now_ns()
        statuses = []
        for topic, monitor in self._monitors.values():
            r = monitor.report(now * 1e-9)
            values = {"rate_hz": f"{r.rate_hz:.2f}", "received": r.received, "accepted": r.accepted,
                      "out_of_order": r.out_of_order, "age_s": "none" if r.age_s is None else f"{r.age_s:.3f}"}
            values.update({f"rejected: {k}": v for k, v in r.rejected.items()})
            statuses.append(diagnostic_status_to_msg(self._backend, int(r.health), f"{NODE_NAME}: {r.name}",
                                                     r.message, hardware_id=topic, values=values))
        level = DiagnosticLevel.OK if self._pipeline.calibrated else DiagnosticLevel.WARN
        statuses.append(diagnostic_status_to_msg(
            self._backend, int(level), f"{NODE_NAME}: pipeline", self._pipeline.calibration_status,
            values={**{"frames " + k: v for k, v in sorted(self._frames.items())},
                    "frames pending": self._pipeline.pending, **self._latency_values()}))
        self._diag_pub.publish(diagnostic_array_to_msg(self._backend, now, statuses))


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros fusion_node``."""
    argv = sys.argv if argv is None else argv
    parser = argparse.ArgumentParser(prog=NODE_NAME, description=__doc__.split("\n\n")[0],
                                     epilog="ROS arguments go after --ros-args (remapping, -p name:=value, "
                                            "--params-file FILE, -p use_sim_time:=true).")
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
