"""fusion_node's HSC4D graph over real DDS, fed bad input by publishers in this process: nothing crashes, every
cloud is accounted for on /diagnostics, every rejected suit sample counted by its reason, and the graph says what
it waits for."""

from __future__ import annotations

import subprocess
import time

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from helpers import console_script
from nav_msgs.msg import Odometry
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu, PointCloud2

from lip_msgs_py import OUSTER_ORIGINAL_DTYPE, RclpyBackend, array_to_cloud, msg_to_diagnostics, odometry_to_msg
from lip_ros.hsc4d.sensors import HIP_LIDAR_TOPIC, SUIT_ODOMETRY_TOPIC, suit_imu_topic

pytestmark = pytest.mark.ros  # DDS traffic and subprocesses


def _imu(stamp_ns: int, quat: tuple[float, float, float, float]) -> Imu:
    msg = Imu()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = quat
    msg.linear_acceleration.z = 9.81
    return msg


def test_bad_input_is_skipped_and_reported(ros_node) -> None:
    proc = subprocess.Popen([console_script("fusion_node"), "--ros-args", "-p", "branch:=hsc4d",
                             "-p", "diagnostics_period_s:=0.5", "-p", "hold_s:=1.0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        backend = RclpyBackend()
        pelvis = ros_node.create_publisher(Imu, suit_imu_topic("pelvis"), qos_profile_sensor_data)
        odometry = ros_node.create_publisher(Odometry, SUIT_ODOMETRY_TOPIC, qos_profile_sensor_data)
        clouds = ros_node.create_publisher(PointCloud2, HIP_LIDAR_TOPIC, qos_profile_sensor_data)
        latest: list[DiagnosticArray] = []
        ros_node.create_subscription(DiagnosticArray, "/diagnostics", latest.append, 10)
        points = np.zeros((16, 64), dtype=OUSTER_ORIGINAL_DTYPE)  # small, no ground: no jump is ever seen
        points["x"], points["y"], points["z"] = 5.0, np.linspace(-2, 2, 64), np.linspace(-1, 1, 16)[:, None]
        empty = points.copy()
        empty["x"] = np.nan
        deadline = time.monotonic() + 60.0  # both nodes up (the body node, a process of its own, imports torch)
        while not (all(p.get_subscription_count() for p in (pelvis, odometry, clouds))
                   and any(s.name == "hsc4d_body_node: frames" for m in latest for s in m.status)):
            assert time.monotonic() < deadline and proc.poll() is None, "fusion_node did not start"
            rclpy.spin_once(ros_node, timeout_sec=0.1)
        t_start, k = time.monotonic(), 0
        while k < 400:  # 4 s at 100 Hz
            stamp = time.time_ns()
            pelvis.publish(_imu(stamp, (0.0, 0.0, 0.0, 0.0) if k % 4 == 1 else (0.0, 0.0, 0.0, 1.0)))
            msg = odometry_to_msg(backend, stamp, "mocap_world", "pelvis", [0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0])
            if k % 4 == 2:
                msg.pose.pose.position.x = float("nan")
            odometry.publish(msg)
            if k % 10 == 0:
                cloud = array_to_cloud(backend, empty if k % 100 == 30 else points, stamp, "hip_lidar")
                if k % 100 == 60:
                    cloud.row_step -= 48  # data length no longer matches row_step * height
                clouds.publish(cloud)
            k += 1
            while (wait := t_start + k / 100 - time.monotonic()) > 0:
                rclpy.spin_once(ros_node, timeout_sec=wait)
        end = time.monotonic() + 1.5  # the last diagnostics
        while time.monotonic() < end:
            rclpy.spin_once(ros_node, timeout_sec=0.1)
        assert proc.poll() is None, "the graph stopped"
        report = {}
        for msg in latest:
            report.update((s.name, s) for s in msg_to_diagnostics(msg).statuses)
    finally:
        proc.terminate()
        out = proc.communicate(timeout=20)[0]
    assert "Traceback" not in out, out
    trajectory = report["hsc4d_trajectory_node: frames"]
    assert trajectory.level == 1 and "waiting for the jump" in trajectory.message, trajectory
    assert trajectory.values["suit clock offset (ms)"] == "unknown"
    frames = {k.removeprefix("frames "): int(v) for k, v in trajectory.values.items() if k.startswith("frames ")}
    lidar = report["hsc4d_trajectory_node: hip lidar"]
    received = int(lidar.values["received"])
    assert received >= 30 and sum(frames.values()) + int(trajectory.values["pending"]) == received, frames
    assert frames["skipped: malformed cloud"] >= 3 and frames["skipped: empty cloud"] >= 3
    assert frames["skipped: held too long (no jump)"] >= 10  # hold_s 1: at most ~11 held
    assert int(trajectory.values["pending"]) <= 12
    for name in ("suit pelvis imu", "suit odometry"):
        status = report[f"hsc4d_trajectory_node: {name}"]
        rejected = sum(int(v) for k, v in status.values.items() if k.startswith("rejected"))
        assert rejected >= 80 and int(status.values["accepted"]) >= 250, status
    assert "message skipped" in out  # the log says why
    body = report["hsc4d_body_node: frames"]
    assert body.level == 1 and body.message == "no pose yet"
