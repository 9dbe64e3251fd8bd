"""The stage executables over real DDS: calibration services and latched state, start-up errors, wrong topic
types. Each node runs as its own process, as ``ros2 run lip_ros <node>`` would start it."""

from __future__ import annotations

import importlib.util
import signal
import subprocess
import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from helpers import DEMO_BAG, console_script
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState, PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from lip_msgs_py import (
    RclpyBackend,
    imu_sample,
    imu_to_msg,
    msg_to_diagnostics,
    msg_to_pose_stamped,
    stamp_to_ns,
    xyz_to_cloud,
)
from lip_ros.bagio import bag_span, read_messages
from lip_ros.core.urdf import URDF_FILE
from lip_ros.lip.batch import replay_bag
from lip_ros.lip.dot_latency import LatencyConfig
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.pipeline import LipPipeline, PipelineConfig
from lip_ros.lip.sensors import IMU_NAMES
from lip_ros.nodes.base import BETWEEN_NODES
from lip_ros.nodes.lip.calibration import DOT_LATENCY_VALUE
from lip_ros.resources import params_path
from lip_ros.tools.bag_play import CLOCK_QOS

pytestmark = pytest.mark.ros  # DDS traffic or subprocesses

RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture(scope="module")
def saved_calibration(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A calibration found on the demo bag (the batch pipeline saves it as the node would)."""
    path = tmp_path_factory.mktemp("calibration") / "calibration.yaml"
    pipeline = LipPipeline(LipModel.load(), PipelineConfig(calibration_file=path))
    for _ in replay_bag(pipeline, DEMO_BAG):
        pass
    assert path.is_file()
    return path


def _start(exe: str, *ros_args: str) -> subprocess.Popen:
    return subprocess.Popen([console_script(exe), "--ros-args", *ros_args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def _spin_until(node, done, proc: subprocess.Popen, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        assert proc.poll() is None, proc.stdout.read()
        assert time.monotonic() < deadline, "timed out"
        rclpy.spin_once(node, timeout_sec=0.1)


def _call(node, client, proc: subprocess.Popen) -> Trigger.Response:
    _spin_until(node, lambda: client.service_is_ready(), proc)
    future = client.call_async(Trigger.Request())
    _spin_until(node, future.done, proc)
    return future.result()


def test_calibration_state_is_latched_and_controlled_by_services(ros_node, saved_calibration, tmp_path):
    file = tmp_path / "calibration.yaml"
    file.write_bytes(saved_calibration.read_bytes())
    proc = _start("calibration_node", "-p", f"calibration_file:={file}")
    try:
        states: list[dict] = []
        time.sleep(2.0)  # subscribe late: the latched state must still arrive
        ros_node.create_subscription(String, "/lip/calibration", lambda m: states.append(yaml.safe_load(m.data)),
                                     LATCHED)
        _spin_until(ros_node, lambda: states, proc)
        assert states[-1]["state"] == "calibrated" and states[-1]["file"] == str(file)
        saved = yaml.safe_load(file.read_text())  # the calibration itself, in the file's layout
        assert states[-1]["calibration"].keys() == saved.keys()
        np.testing.assert_allclose(states[-1]["calibration"]["R_L_I"], saved["R_L_I"], atol=1e-12)

        start = _call(ros_node, ros_node.create_client(Trigger, "/lip/start_calibration"), proc)
        assert start.success and "T-pose" in start.message
        _spin_until(ros_node, lambda: states[-1]["state"] == "recalibrating", proc)
        assert file.is_file()  # in use until a new one is solved

        reset = _call(ros_node, ros_node.create_client(Trigger, "/lip/reset_calibration"), proc)
        assert reset.success
        _spin_until(ros_node, lambda: states[-1]["state"] == "calibrating", proc)
        assert states[-1]["calibration"] is None and not file.exists()
    finally:
        proc.terminate()
        proc.communicate(timeout=10)


@pytest.mark.parametrize(("exe", "args", "message"), [
    ("pose_node", ["-p", "weights:=/nonexistent/lip"], "cannot load weights /nonexistent/lip"),
    ("segmentation_node", ["-p", "lidar_rate_hz:=-1.0"], "lidar_rate_hz must be > 0"),
    ("segmentation_node", ["-p", "lidar_rate_hz:=fast"], "lidar_rate_hz"),
    ("calibration_node", ["-p", "imu_topics:=[/a, /b]"], "imu_topics needs 4 topics"),
    ("calibration_node", ["-p", "dot_latency_s:=[0.03, 0.04]"], "dot_latency_s must be a list of 0 or 4 finite"),
    ("pose_node", ["-p", "hri_body_id:=1st performer"], "hri_body_id must be letters, digits and underscores"),
    ("calibration_node", ["-p", "dot_latency_s:=[0.03, 0.04, -0.01, 0.02]"], "dot_latency_s must not be negative"),
    ("segmentation_node", ["-p", "lock_rule:=wave"], "lock_rule must be one of t_pose, still"),
    ("segmentation_node", ["-p", "lock_rule:=still"], "lock_rule 'still' needs expected_xy"),
    ("segmentation_node", ["-p", "expected_xy:=[1.0]"], "expected_xy must be a list of 0 or 2 finite numbers"),
    ("segmentation_node", ["-p", "ground_plane:=[0.0, 0.0, -1.0, 1.2]"], "needs a finite normal with a positive z"),
    ("fusion_node", ["--params-file", "BAD_PARAMS"], "unknown parameter(s) lidar_topics"),
])
def test_bad_start_up_is_one_clear_line_and_exit_2(exe, args, message, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("segmentation_node:\n  ros__parameters:\n    lidar_topics: /x\n")
    args = [str(bad) if a == "BAD_PARAMS" else a for a in args]
    proc = subprocess.run([console_script(exe), "--ros-args", *args], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


def test_an_input_of_another_type_stops_the_node_with_exit_2(ros_node):
    pub = ros_node.create_publisher(Imu, "/test/wrong_type", 10)
    proc = _start("segmentation_node", "-r", "/ouster/points:=/test/wrong_type", "-p", "diagnostics_period_s:=0.3")
    try:
        out = proc.communicate(timeout=30)[0]
    finally:
        pub.destroy()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2, out
    assert "/test/wrong_type is published as sensor_msgs/msg/Imu" in out and "Traceback" not in out, out


def test_a_restarted_graph_resumes_mid_capture(ros_node, tmp_path):
    """Kill fusion_node mid-capture and start it again: it resumes with the saved calibration and performer
    position (the A/T-pose is only at the start of the bag, so without them no pose could follow). The sensors
    stop while it is down and go on from there once it is up (a second player from where the first stopped): its
    start-up, seconds long and longer on a slower machine, takes nothing of the capture's 13 s."""
    files = {"calibration_file": tmp_path / "calibration.yaml", "performer_file": tmp_path / "performer.yaml"}
    args = ["-p", "use_sim_time:=true", "-p", "hri_body_id:=performer1",
            *(a for k, v in files.items() for a in ("-p", f"{k}:={v}"))]
    poses: list[tuple[object, int]] = []
    joint_states: list[JointState] = []
    hri_states: list[JointState] = []  # the ROS4HRI view (REP-155)
    run = [0]
    ros_node.create_subscription(PoseStamped, "/lip/root_pose",
                                 lambda m: poses.append((msg_to_pose_stamped(m), run[0])), RELIABLE)
    ros_node.create_subscription(JointState, "/lip/joint_states", joint_states.append, RELIABLE)
    ros_node.create_subscription(JointState, "/humans/bodies/performer1/joint_states", hri_states.append, RELIABLE)
    clock = [0]
    ros_node.create_subscription(Clock, "/clock", lambda m: clock.__setitem__(0, stamp_to_ns(m.clock)), CLOCK_QOS)
    inputs = ["/ouster/points", *(f"/dot/{n}/imu" for n in ("left_wrist", "right_wrist", "left_ankle", "right_ankle"))]

    def play(start_s: float) -> subprocess.Popen:
        return subprocess.Popen([console_script("lip_bag_play"), str(DEMO_BAG), "--clock", "--rate", "0.5",
                                 "--start", f"{start_s:.3f}", "--wait-for-subscribers", "--topics", *inputs],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    graph = _start("fusion_node", *args)
    player = play(0.0)
    log: list[str] = []
    try:
        _spin_until(ros_node, lambda: len(poses) >= 10 and all(f.is_file() for f in files.values()), graph, 90.0)
        graph.kill()  # a crash, not a clean shutdown
        graph.communicate(timeout=10)
        player.send_signal(signal.SIGINT)
        player.wait(timeout=30)
        run[0] = 1
        graph = _start("fusion_node", *args)
        reader = threading.Thread(target=lambda: log.extend(graph.stdout), daemon=True)
        reader.start()
        _spin_until(ros_node, lambda: sum("]: ready;" in line for line in log) == 2, graph, 90.0)  # its 2 nodes
        player = play((clock[0] - bag_span(DEMO_BAG)[0]) * 1e-9)
        _spin_until(ros_node, lambda: player.poll() is not None, graph, 90.0)
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            rclpy.spin_once(ros_node, timeout_sec=0.1)
    finally:
        graph.terminate()
        graph.wait(timeout=10)
        if run[0]:
            reader.join(timeout=10)
        out = "".join(log)
        if player.poll() is None:
            player.send_signal(signal.SIGINT)
            player.wait(timeout=30)
    assert "resuming: the performer was last seen" in out, out
    if importlib.util.find_spec("tf2_msgs") is None:  # no /tf without tf2_msgs: said once, and the graph goes on
        assert "tf2_msgs is not installed: nothing is broadcast on /tf" in out
    # a plain rclpy subscriber got JointStates that robot_state_publisher can use with the shipped URDF
    urdf_joints = [j.get("name") for j in ET.parse(params_path(URDF_FILE)).getroot().iter("joint")
                   if j.get("type") == "revolute"]
    assert len(joint_states) >= len(poses) - 5 and all(list(js.name) == urdf_joints for js in joint_states)
    by_stamp = {(m.header.stamp.sec, m.header.stamp.nanosec): list(m.position) for m in joint_states}
    hri = {(m.header.stamp.sec, m.header.stamp.nanosec): list(m.position) for m in hri_states}
    assert len(hri) >= len(by_stamp) - 1  # the kill may fall between the two publishes
    assert all(by_stamp[k] == v for k, v in hri.items())
    after = [p for p, r in poses if r == 1]
    assert len(after) >= 15, (len(poses), len(after), out[-3000:])
    truth = {p.stamp_ns: p.position for p in map(msg_to_pose_stamped,
                                                 (m.msg for m in read_messages(DEMO_BAG, ["/gt/root_pose"])))}
    stamps = np.array(sorted(truth))
    nearest = [int(stamps[np.argmin(np.abs(stamps - p.stamp_ns))]) for p in after]
    assert all(abs(k - p.stamp_ns) < 1_000_000 for k, p in zip(nearest, after))  # truth of the same moment
    errors = [np.linalg.norm(p.position - truth[k]) for k, p in zip(nearest, after)]
    assert np.mean(errors) < 0.10, np.mean(errors)


def test_segmentation_lock_parameters_are_taken(ros_node):
    """The lock rule, the expected position (integers are numbers too) and a given ground plane start the node."""
    statuses = []
    sub = ros_node.create_subscription(DiagnosticArray, "/diagnostics",
                                       lambda m: statuses.extend(s.name for s in m.status), 10)
    proc = _start("segmentation_node", "-p", "lock_rule:=still", "-p", "expected_xy:=[8, 0]",
                  "-p", "ground_plane:=[0.0, 0.0, 1.0, 1.2]", "-p", "diagnostics_period_s:=0.3")
    try:
        _spin_until(ros_node, lambda: "segmentation_node: frames" in statuses, proc)  # started, and running
    finally:
        ros_node.destroy_subscription(sub)
        proc.send_signal(signal.SIGINT)  # stopped cleanly: a killed node leaves its DDS shared memory behind
        out = proc.communicate(timeout=30)[0]
    assert proc.returncode == 0 and "Traceback" not in out and "parameter error" not in out, out


def test_a_lidar_on_another_clock_is_an_error_on_diagnostics(ros_node):
    """Performer clouds stamped on a sensor oscillator (1000 s since boot) and DOTs on ROS time: calibration_node
    skips every frame saying so, with an ERROR, instead of calibrating for ever."""
    backend = RclpyBackend()
    latest = {}
    sub = ros_node.create_subscription(
        DiagnosticArray, "/diagnostics", lambda m: latest.update((s.name, s) for s in msg_to_diagnostics(m).statuses),
        10)
    imu_pubs = [ros_node.create_publisher(Imu, f"/dot/{n}/imu", qos_profile_sensor_data) for n in IMU_NAMES]
    cloud_pub = ros_node.create_publisher(PointCloud2, "/lip/performer/points", RELIABLE)
    proc = _start("calibration_node", "-p", "diagnostics_period_s:=0.3")
    try:
        _spin_until(ros_node, lambda: all(p.get_subscription_count() for p in (*imu_pubs, cloud_pub)), proc)
        start, k = time.monotonic(), 0
        while k < 180:  # 3 s at 60 Hz
            stamp = time.time_ns()
            for name, pub in zip(IMU_NAMES, imu_pubs):
                pub.publish(imu_to_msg(backend, imu_sample(stamp, name, [0.0, 0.0, 0.0, 1.0], [0.0] * 3,
                                                           [0.0, 0.0, 9.81])))
            if k % 6 == 0:
                cloud_pub.publish(xyz_to_cloud(backend, np.zeros((50, 3), np.float32), 1000 * 10**9 + k * 10**7,
                                               "os_lidar"))
            k += 1
            while (wait := start + k / 60 - time.monotonic()) > 0:
                rclpy.spin_once(ros_node, timeout_sec=wait)
        _spin_until(ros_node, lambda: "clocks" in getattr(latest.get("calibration_node: frames"), "message", ""),
                    proc)
    finally:
        ros_node.destroy_subscription(sub)
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    assert proc.returncode == 0
    status = latest["calibration_node: frames"]
    assert status.level == 2 and status.message.startswith("clocks: the LiDAR frame is stamped -"), status
    assert int(status.values["frames skipped: clocks"]) >= 10
    assert "frames calibrating" not in status.values


def test_the_pose_node_feeds_the_network_at_the_rate_its_frames_are_stamped(ros_node):
    """An OS1 in a 20 Hz mode and pose_node left at its default lidar_rate_hz (10): from the performer frames'
    stamps it feeds the network (trained at 10 Hz) as two interleaved sequences, says so in its log and on
    /diagnostics, and poses every frame."""
    backend = RclpyBackend()
    latest = {}
    sub = ros_node.create_subscription(
        DiagnosticArray, "/diagnostics", lambda m: latest.update((s.name, s) for s in msg_to_diagnostics(m).statuses),
        10)
    poses = []
    pose_sub = ros_node.create_subscription(PoseStamped, "/lip/root_pose", poses.append, RELIABLE)
    bone_pubs = [ros_node.create_publisher(Imu, f"/lip/bones/{n}/imu", BETWEEN_NODES) for n in IMU_NAMES]
    cloud_pub = ros_node.create_publisher(PointCloud2, "/lip/performer/points", BETWEEN_NODES)
    proc = _start("pose_node", "-p", "diagnostics_period_s:=0.3")
    frames, rng = 30, np.random.default_rng(0)
    try:
        _spin_until(ros_node, lambda: all(p.get_subscription_count() for p in (*bone_pubs, cloud_pub)), proc, 60.0)
        start = time.monotonic()
        for k in range(frames):  # 20 Hz, stamped 50 ms apart
            stamp = 1_000_000_000 + k * 50_000_000
            for name, pub in zip(IMU_NAMES, bone_pubs, strict=True):
                pub.publish(imu_to_msg(backend, imu_sample(stamp, name, [0.0, 0.0, 0.0, 1.0], [0.0] * 3,
                                                           [0.0] * 3)))
            points = rng.normal([5.0, 0.0, 0.0], [0.15, 0.2, 0.5], (300, 3)).astype(np.float32)
            cloud_pub.publish(xyz_to_cloud(backend, points, stamp, "os_lidar"))
            while (wait := start + (k + 1) / 20 - time.monotonic()) > 0:
                rclpy.spin_once(ros_node, timeout_sec=wait)
        _spin_until(ros_node, lambda: len(poses) == frames and int(getattr(
            latest.get("pose_node: frames"), "values", {}).get("frames pose", 0)) == frames, proc)
    finally:
        ros_node.destroy_subscription(sub)
        ros_node.destroy_subscription(pose_sub)
        proc.send_signal(signal.SIGINT)
        out = proc.communicate(timeout=30)[0]
    assert proc.returncode == 0 and "Traceback" not in out, out
    assert "the 20 Hz frames (measured from their stamps) are fed to it as 2 interleaved sequences" in out, out
    status = latest["pose_node: frames"]
    assert status.values["interleaved sequences"] == "2" and status.values["sequences"] == "2", status


def test_the_dot_heading_reset_is_asked_for_whenever_a_calibration_starts(ros_node):
    """A DOT driver's heading reset (its Trigger service, faked here at the driver boundary) is called once the
    node is up and uncalibrated, and again for each calibration requested."""
    calls = []

    def reset(_request, response):
        calls.append(time.monotonic())
        response.success, response.message = True, "4 DOTs reset"
        return response

    ros_node.create_service(Trigger, "/test_dot/reset_heading", reset)
    statuses = {}
    sub = ros_node.create_subscription(
        DiagnosticArray, "/diagnostics", lambda m: statuses.update((s.name, s) for s in msg_to_diagnostics(m).statuses),
        10)
    proc = _start("calibration_node", "-p", "heading_reset_service:=/test_dot/reset_heading",
                  "-p", "diagnostics_period_s:=0.3", "-p", "dot_latency_s:=[0.03, 0.04, 0.05, 0.061]")
    try:
        _spin_until(ros_node, lambda: len(calls) == 1, proc)
        start = ros_node.create_client(Trigger, "/lip/start_calibration")
        assert _call(ros_node, start, proc).success
        _spin_until(ros_node, lambda: len(calls) == 2, proc)
        _spin_until(ros_node, lambda: "done" in str(getattr(statuses.get("calibration_node: frames"), "values", {})
                                                         .get("DOT heading reset", "")), proc)
        later = time.monotonic() + 1.5  # three more checks of the node's 0.5 s timer
        _spin_until(ros_node, lambda: time.monotonic() > later, proc)
        assert len(calls) == 2  # once per calibration started, not on every check
    finally:
        ros_node.destroy_subscription(sub)
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    assert proc.returncode == 0
    assert statuses["calibration_node: frames"].values["DOT heading reset"] == "done: 4 DOTs reset"
    assert statuses["calibration_node: frames"].values["DOT headings"] == "unknown"  # nothing calibrated
    assert (statuses["calibration_node: frames"].values[DOT_LATENCY_VALUE]
            == ", ".join(f"{n} {ms} (not estimated: 0 of {LatencyConfig().min_frames} frames scored)"
                         for n, ms in zip(IMU_NAMES, (30, 40, 50, 61))))
