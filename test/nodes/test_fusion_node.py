"""fusion_node over real DDS: a separate process, fed by publishers in this one, accounts for every input on
/diagnostics."""

from __future__ import annotations

import subprocess
import time

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from helpers import console_script
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu, PointCloud2

from lip_msgs_py import OUSTER_ORIGINAL_DTYPE, RclpyBackend, array_to_cloud, msg_to_diagnostics

pytestmark = pytest.mark.ros  # DDS traffic or subprocesses

IMUS = ("left_wrist", "right_wrist", "left_ankle", "right_ankle")


def _imu(stamp_ns: int, quat: tuple[float, float, float, float]) -> Imu:
    msg = Imu()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    msg.header.frame_id = "dot"
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = quat
    msg.linear_acceleration.z = 9.81
    return msg


def test_fusion_node_accounts_for_every_input(ros_node) -> None:
    proc = subprocess.Popen([console_script("fusion_node"), "--ros-args", "-p", "diagnostics_period_s:=0.5"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        backend = RclpyBackend()
        imu_pubs = {n: ros_node.create_publisher(Imu, f"/dot/{n}/imu", qos_profile_sensor_data) for n in IMUS}
        cloud_pub = ros_node.create_publisher(PointCloud2, "/ouster/points", qos_profile_sensor_data)
        latest: list[DiagnosticArray] = []
        ros_node.create_subscription(DiagnosticArray, "/diagnostics", latest.append, 10)

        points = np.zeros((16, 64), dtype=OUSTER_ORIGINAL_DTYPE)  # small: big-cloud transport is a DDS matter
        points["x"][:, ::2] = np.nan
        bad_cloud = array_to_cloud(backend, points, 0, "os_lidar")
        bad_cloud.row_step -= 48  # data length no longer matches row_step * height
        deadline = time.monotonic() + 30.0  # the node process starts and DDS discovery completes
        while not all(p.get_subscription_count() for p in (*imu_pubs.values(), cloud_pub)):
            assert time.monotonic() < deadline and proc.poll() is None, "fusion_node did not subscribe"
            rclpy.spin_once(ros_node, timeout_sec=0.1)
        t_start = time.monotonic()
        k = 0
        while k < 240:  # 4 s at 60 Hz, on a fixed schedule
            stamp = time.time_ns()
            for n, pub in imu_pubs.items():
                quat = (0.0, 0.0, 0.0, 0.0) if n == "right_ankle" and k % 2 else (0.0, 0.0, 0.0, 1.0)
                pub.publish(_imu(stamp, quat))
            if k % 6 == 0:
                cloud_pub.publish(bad_cloud if k % 30 == 12 else array_to_cloud(backend, points, stamp, "os_lidar"))
            k += 1
            while (wait := t_start + k / 60 - time.monotonic()) > 0:
                rclpy.spin_once(ros_node, timeout_sec=wait)
        assert latest, "no /diagnostics from fusion_node: " + (proc.poll() is not None and proc.stdout.read() or "")
        report = {}
        for msg in latest:  # each node publishes its own statuses: the last of each name
            report.update((s.name, s) for s in msg_to_diagnostics(msg).statuses)
    finally:
        proc.terminate()
        out = proc.communicate(timeout=10)[0]

    assert {"segmentation_node: ouster", "segmentation_node: frames", "calibration_node: frames",
            "pose_node: frames", *(f"calibration_node: {n}" for n in IMUS)} <= set(report)
    # the tiny test clouds hold no performer: each accepted cloud is accounted for as a skipped frame
    frames = {k: int(v) for name, s in report.items() if name.endswith(": frames")
              for k, v in s.values.items() if k.startswith("frames ")}
    assert report["calibration_node: frames"].level == 1  # not calibrated
    assert int(report["calibration_node: frames"].values["pending"]) == 0
    assert frames and all(k.startswith("frames skipped") for k in frames)
    lidar = report["segmentation_node: ouster"]
    assert sum(frames.values()) == int(lidar.values["received"]) > 10  # the malformed ones included
    assert frames["frames skipped: malformed cloud"] >= 1
    for name in ("left_wrist", "right_wrist", "left_ankle"):
        status = report[f"calibration_node: {name}"]
        assert status.level == 0, status
        assert 40 < float(status.values["rate_hz"]) < 75
    ankle = report["calibration_node: right_ankle"]
    assert ankle.level == 1 and "rejected" in ankle.message
    rejected = int(next(v for k, v in ankle.values.items() if k.startswith("rejected")))
    assert rejected > 50 and int(ankle.values["accepted"]) > 50
    assert lidar.hardware_id == "/ouster/points"
    assert int(next(v for k, v in lidar.values.items() if k.startswith("rejected"))) >= 1
    assert "message skipped" in out  # the log says why
