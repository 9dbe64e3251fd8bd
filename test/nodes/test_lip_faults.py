"""The LIP graph over real DDS on faulty captures (lip_ros.rig.faults), judged as a user would from its outputs and
/diagnostics: no process fails or aborts, every frame is accounted for, no output is NaN, each fault is named on
/diagnostics while it lasts (stamped in data time), the poses resume with the first frame after it, and a clock
that steps back or ahead (a PTP step, a bag played again) loses nothing and keeps the calibration."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import DEMO_BAG, SPIN_UNTIL_SIGINT, console_script

from lip_msgs_py import msg_to_diagnostics, msg_to_pose_array, msg_to_pose_stamped
from lip_ros.bagio import bag_topics, read_messages
from lip_ros.lip.sensors import INPUT_TOPICS, LIDAR_TOPIC, LIP_TOPICS
from lip_ros.nodes.base import node_defaults
from lip_ros.nodes.lip import LIP_PARAMS_FILE
from lip_ros.rig.bag import write_capture_bag
from lip_ros.rig.capture import CaptureConfig, CaptureSession
from lip_ros.rig.faults import FaultSpec, read_fault_windows, write_faulty_bag
from lip_ros.tools.bag_play import CLOCK_QOS
from lip_ros.tools.process_bag import summarize_outputs

pytestmark = pytest.mark.ros  # DDS traffic and subprocesses

#: the demo bag's set-up, 30 s: calibration poses until about 5 s, then walking
CAPTURE = CaptureConfig(scenario="walk", seconds=30.0, seed=1, distance_m=6.0, columns=512,
                        azimuth_window_deg=(150.0, 210.0))
#: faults on the sensors, one after another (start, seconds of receive time), each named on /diagnostics by a
#: status whose name contains the first string and whose message contains the second
SENSOR_FAULTS = {
    "bad_imu_samples": ((7.0, 1.0), ("calibration_node: ", "non-finite")),
    "imu_reordered": ((9.0, 1.0), ("calibration_node: ", "duplicate stamp")),
    "imu_silent": ((11.0, 3.0), ("calibration_node: left_ankle", "no valid message")),
    "imus_silent": ((15.5, 1.0), ("calibration_node: frames", "skipped: IMU")),
    "imu_late": ((18.0, 1.0), ("calibration_node: ", "after their stamps")),
    "malformed_clouds": ((20.0, 0.5), ("segmentation_node: ouster", "rejected")),
    "blinded_clouds": ((21.5, 0.3), ("segmentation_node: frames", "no returns")),
    "empty_clouds": ((22.5, 0.2), ("segmentation_node: frames", "has no points")),
    "lidar_gap": ((23.5, 2.0), ("segmentation_node: ouster", "no valid message")),
    "lidar_drops": ((26.5, 3.0), ("segmentation_node: ouster", "missing")),
    "imu_ahead": ((26.5, 3.0), ("calibration_node: frames", "left_ankle stamped")),
}
#: the sensors' clock 5 s back at 12 s, and 5 s ahead again at 20 s (to the end)
CLOCK_FAULTS = {
    "clock_back": ((12.0, 100.0), ("segmentation_node: ouster", "stepped back")),
    "clock_forward": ((20.0, 100.0), ("calibration_node: left_wrist", "stepped ahead")),
}
REPORT_S = 2.5  # a fault's WARN may come this long after its last message (0.25 s reports, 2 s windows)
PERIOD_NS = 100_000_000  # of the LiDAR


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    bag = tmp_path_factory.mktemp("faults") / "capture"
    write_capture_bag(CaptureSession(CAPTURE), bag, progress=False)
    return bag


@pytest.fixture(scope="module", params=["sensors", "clock"])
def run(request: pytest.FixtureRequest, capture: Path) -> tuple[Path, Path, dict, subprocess.CompletedProcess]:
    """``lip_process_bag --paced`` on the capture with one group of faults: (faulty bag, outputs, faults,
    process)."""
    faults = SENSOR_FAULTS if request.param == "sensors" else CLOCK_FAULTS
    bag = capture.with_name(request.param)
    write_faulty_bag(capture, bag, [FaultSpec(kind, *window) for kind, (window, _) in faults.items()], seed=5)
    out = capture.with_name(f"{request.param}_outputs")
    proc = subprocess.run([console_script("lip_process_bag"), str(bag), str(out), "--paced"], capture_output=True,
                          text=True, timeout=240)
    return bag, out, faults, proc


def test_no_process_fails_and_every_frame_is_accounted_for(run) -> None:
    bag, out, faults, proc = run
    assert proc.returncode == 0, proc.stderr[-3000:]  # the tool checks that each of its processes ended with 0
    assert "Traceback" not in proc.stderr and "terminate called" not in proc.stderr, proc.stderr[-3000:]
    assert "not accounted for" not in proc.stdout, proc.stdout
    summary = summarize_outputs(bag, out)
    assert summary.received == summary.frames_in == bag_topics(bag)[LIDAR_TOPIC].count
    assert sum(summary.frames.values()) == summary.frames_in
    if "clock_back" in faults:  # a clock step loses no frame: only those before the lock, and the calibration
        # ... and the frames on their way from the segmentation when the DOTs' new time line overtakes them (they
        # wait on the old one for data that never comes), or a frame stamped on the new one before its DOTs' first
        # sample on it ("IMU": no sample before it; this capture has no IMU fault): docs/reliability.md "Clock
        # steps"; none alone, one paced (session 38), two, and once at least three, with the suite on two workers
        # (sessions 39, 40)
        skipped = {k: v for k, v in summary.frames.items()
                   if k.startswith("skipped: clock stepped back") or k == "skipped: IMU"}
        assert set(summary.frames) - set(skipped) == {"pose", "calibrating", "skipped: no_performer"}, summary.frames
        assert sum(skipped.values()) <= 3, summary.frames
        assert summary.frames["calibrating"] + summary.frames["skipped: no_performer"] <= 50


def test_no_output_is_nan(run) -> None:
    out = run[1]
    poses = [msg_to_pose_array(m.msg) for m in read_messages(out, [LIP_TOPICS.joint_poses])]
    assert len(poses) > 100
    assert all(np.isfinite(p.positions).all() and np.isfinite(p.quats).all() for p in poses)


def test_each_fault_is_on_diagnostics_while_it_lasts(run) -> None:
    bag, out, faults, _ = run
    statuses = [(d.stamp_ns, s) for d in (msg_to_diagnostics(m.msg) for m in read_messages(out, ["/diagnostics"]))
                for s in d.statuses if s.level > 0]
    for window in read_fault_windows(bag):
        name, text = faults[window.kind][1]
        named = [t for t, s in statuses if name in s.name and text in s.message
                 and window.start_ns <= t <= window.end_ns + REPORT_S * 1e9]
        assert named, f"{window.kind}: no WARN/ERROR on /diagnostics from '{name}' saying '{text}'"


@pytest.mark.parametrize("run", ["sensors"], indirect=True)
def test_a_silent_sensor_is_logged_when_its_silence_starts_and_when_it_ends(run) -> None:
    """The LiDAR's gap and the silent DOT: a WARN from the node that takes the sensor as it falls silent (1 s
    without a message: ``stale_after_s``), and a line with the silence's length as it comes back (from its last
    message before to its first after: the fault's length and up to a LiDAR period more, printed to 0.1 s; measured
    2.1 and 3.0 s)."""
    _, _, faults, proc = run
    for kind, node, name in (("lidar_gap", "segmentation_node", "ouster"), ("imu_silent", "calibration_node",
                                                                               "left_ankle")):
        seconds = faults[kind][0][1]
        assert re.search(rf"\[{node}\]: no valid message for: [^\n]*\b{name} \(", proc.stderr), kind
        back = re.findall(rf"\[{node}\]: receiving again after a silence of: [^\n]*\b{name} \([^)]*\) (\d+\.\d) s",
                          proc.stderr)
        assert any(seconds - 0.05 <= float(b) <= seconds + 0.2 for b in back), (kind, back)


@pytest.mark.parametrize("run", ["sensors"], indirect=True)  # the run with a silent DOT
def test_one_silent_dot_is_posed_through_for_max_silent_dot_s_then_skipped(run) -> None:
    """The first second of the 3 s silence posed with the DOT's bone held, said on /diagnostics; the rest skipped."""
    bag, out, _, _ = run
    window = next(w for w in read_fault_windows(bag) if w.kind == "imu_silent")
    poses = np.array([msg_to_pose_stamped(m.msg).stamp_ns for m in read_messages(out, [LIP_TOPICS.root_pose])])
    since = (poses[(poses >= window.start_ns) & (poses <= window.end_ns)] - window.start_ns) * 1e-9
    max_silent_s = node_defaults(LIP_PARAMS_FILE, "calibration_node")["max_silent_dot_s"]
    assert (since <= max_silent_s + 0.1).all(), since  # + the synchroniser's hold
    assert (since > 0.3).sum() >= 6, since  # 10 frames a second; the clouds in the window may also be faulty
    warned = [d.stamp_ns for d in (msg_to_diagnostics(m.msg) for m in read_messages(out, ["/diagnostics"]))
              for s in d.statuses if s.level > 0 and s.name == "calibration_node: frames"
              and "left_ankle x" in s.message and "bone held" in s.message]
    assert any(window.start_ns <= t <= window.start_ns + (max_silent_s + REPORT_S) * 1e9 for t in warned)


def test_the_poses_resume_with_the_first_frame_after_each_fault(run) -> None:
    bag, out, _, _ = run
    poses = np.array(sorted(msg_to_pose_stamped(m.msg).stamp_ns for m in read_messages(out, [LIP_TOPICS.root_pose])))
    for window in read_fault_windows(bag):
        after = poses[poses > window.end_ns]
        if after.size == 0:  # the fault lasts to the end of the capture (the clock steps)
            continue
        # a pose holds at its frame's start plus the performer's mean scan time: within the next frame
        assert after[0] - window.end_ns <= 2 * PERIOD_NS, f"{window.kind}: first pose {after[0] - window.end_ns} ns"


def test_a_bag_played_again_is_posed_again_with_the_same_calibration(capture: Path, tmp_path: Path,
                                                                      ros_node) -> None:
    """``lip_bag_play --loop``: /clock and every stamp go back to the start. The graph keeps its calibration (no
    frame of the second pass is calibrating), finds the performer again by the T-pose and poses the second pass;
    player, recorder and graph stop on SIGTERM with status 0, the recorder's bag complete."""
    import rclpy
    from rosgraph_msgs.msg import Clock

    clock: list[int] = []
    ros_node.create_subscription(Clock, "/clock", lambda m: clock.append(m.clock.sec * 10**9 + m.clock.nanosec),
                                 CLOCK_QOS)
    node = subprocess.Popen([console_script("fusion_node"), "--ros-args", "-p", "use_sim_time:=true",
                             "-p", "diagnostics_period_s:=0.5", "-p", f"calibration_file:={tmp_path / 'cal.yaml'}"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    recorder = subprocess.Popen([console_script("lip_bag_record"), str(tmp_path / "out"), "--topics",
                                 LIP_TOPICS.root_pose, "/diagnostics"], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
    player = subprocess.Popen([console_script("lip_bag_play"), str(capture), "--clock", "--loop",
                               "--wait-for-subscribers", "--rate", "2", "--paced-by", LIP_TOPICS.root_pose,
                               "--topics", *INPUT_TOPICS],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline and player.poll() is None:  # until 25 s into the second pass
            rclpy.spin_once(ros_node, timeout_sec=0.1)
            rewound = np.flatnonzero(np.diff(clock) < 0)
            if rewound.size and clock[-1] - clock[rewound[0] + 1] >= 25 * 10**9:
                break
        assert rewound.size, "the player did not play the bag again"
        time.sleep(2.0)  # the last frames through the graph, the last diagnostics to the recorder
    finally:
        codes = {}
        for proc in (player, recorder, node):  # SIGTERM, as a process manager stops them (lip_process_bag: SIGINT)
            proc.send_signal(signal.SIGTERM)
            codes[Path(str(proc.args[0])).name] = proc.wait(timeout=30)
    log = node.stdout.read()
    assert set(codes.values()) == {0}, codes
    assert "Traceback" not in log and "terminate called" not in log, log[-3000:]
    assert "stepped back" in log  # said in the log
    stamps = [msg_to_pose_stamped(m.msg).stamp_ns for m in read_messages(tmp_path / "out", [LIP_TOPICS.root_pose])]
    back = np.flatnonzero(np.diff(stamps) < 0)
    assert back.size == 1, "the second pass was not posed"
    first, second = stamps[: back[0] + 1], stamps[back[0] + 1 :]
    assert len(second) >= len(first) * 0.7, (len(first), len(second))  # 25 of the 30 s, from the T-pose on
    calibrating = []  # (stamp, frames calibrating so far), in the order reported
    for m in read_messages(tmp_path / "out", ["/diagnostics"]):
        d = msg_to_diagnostics(m.msg)
        calibrating += [(d.stamp_ns, int(s.values.get("frames calibrating", 0))) for s in d.statuses
                        if s.name == "calibration_node: frames"]
    rewind = np.flatnonzero(np.diff([t for t, _ in calibrating]) < 0)[0]
    assert calibrating[rewind][1] > 10 and calibrating[-1][1] == calibrating[rewind][1]  # none in the second pass


def test_lip_process_bag_stops_cleanly_on_sigterm(capture: Path, tmp_path: Path) -> None:
    """SIGTERM mid-run: the player, graph and recorder are stopped, what was recorded is summarised (a complete
    bag), status 0, and the summary says it was cut short."""
    proc = subprocess.Popen([console_script("lip_process_bag"), str(capture), str(tmp_path / "out")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    played = []  # stderr up to the player's progress 3 s into the capture (after start-up, however long it takes)
    for line in proc.stderr:
        played.append(line)
        if re.match(r"lip_bag_play: +([3-9]|\d\d+)\.\d / ", line):
            break
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    err = "".join(played) + err
    assert proc.returncode == 0, err[-3000:]
    assert "interrupted (SIGINT or SIGTERM)" in out and "Traceback" not in err and "terminate called" not in err
    assert bag_topics(tmp_path / "out")["/diagnostics"].count > 0  # the recorder closed its bag


SLOW_CONSUMER = """
import sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from lip_msgs_py import rclpy_message_class
rclpy.init()
node = rclpy.create_node("slow_consumer")
got = [0]
def slow(_msg):
    got[0] += 1
    time.sleep(2.0)  # a consumer twenty times slower than the LiDAR
for topic, msgtype in zip(sys.argv[1::2], sys.argv[2::2]):
    node.create_subscription(rclpy_message_class(msgtype), topic, slow,
                             QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
""" + SPIN_UNTIL_SIGINT + """
print("received", got[0], flush=True)
"""


def test_a_slow_consumer_of_the_outputs_does_not_slow_the_graph(tmp_path: Path) -> None:
    """A reliable subscriber to every pose output that takes 2 s per message (20x slower than the LiDAR): the
    graph neither waits for it nor loses a frame; the recorder still gets every pose, in time."""
    outputs = {LIP_TOPICS.joint_states: "sensor_msgs/msg/JointState",
               LIP_TOPICS.root_pose: "geometry_msgs/msg/PoseStamped",
               LIP_TOPICS.joint_poses: "geometry_msgs/msg/PoseArray",
               LIP_TOPICS.skeleton: "visualization_msgs/msg/MarkerArray"}
    slow = subprocess.Popen([sys.executable, "-c", SLOW_CONSUMER, *(a for kv in outputs.items() for a in kv)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert slow.stdout.readline().strip() == "ready"
        proc = subprocess.run([console_script("lip_process_bag"), str(DEMO_BAG), str(tmp_path / "out"), "--paced"],
                              capture_output=True, text=True, timeout=180)
    finally:
        slow.send_signal(signal.SIGINT)
        out, err = slow.communicate(timeout=30)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = summarize_outputs(DEMO_BAG, tmp_path / "out")
    assert summary.received == summary.frames_in and sum(summary.frames.values()) == summary.frames_in
    assert summary.frames["pose"] == bag_topics(tmp_path / "out")[LIP_TOPICS.root_pose].count > summary.frames_in / 2
    # the graph's own latency, not the consumer's: waiting on it would add 2 s a frame at least (the demo bag's p50
    # is about 20 ms on an idle machine, 74 ms on one twice as slow sharing it with the tests, 340 ms / p90 650 ms
    # with the suite on two workers, session 39)
    assert summary.latency_ms["p50"] < 1000 and summary.latency_ms["p90"] < 2000, summary.latency_ms
    received = int(out.split("received")[-1])
    assert received > 5, (out, err[-2000:])  # it was subscribed and served, at its own pace


def test_a_graph_killed_during_a_fault_resumes_with_what_it_saved(capture: Path, tmp_path: Path, ros_node) -> None:
    """fusion_node killed (SIGKILL, a crash) while a DOT is silent, and started again: it resumes at once with the
    calibration and the performer's position it saved (the calibration poses are long past), and poses the rest of
    the faulty capture, its later faults handled as in one run."""
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rosgraph_msgs.msg import Clock

    from lip_ros.bagio import bag_span
    from lip_ros.nodes.base import RELIABLE

    bag = tmp_path / "sensors"
    write_faulty_bag(capture, bag, [FaultSpec(kind, *window) for kind, (window, _) in SENSOR_FAULTS.items()], seed=5)
    start_ns = bag_span(bag)[0]
    kill_at_ns = start_ns + 12 * 10**9  # imu_silent: 11-14 s
    args = ["--ros-args", "-p", "use_sim_time:=true", "-p", f"calibration_file:={tmp_path / 'calibration.yaml'}",
            "-p", f"performer_file:={tmp_path / 'performer.yaml'}"]
    clock, poses, run = [0], [], [0]  # poses: (stamp, position, run)
    ros_node.create_subscription(Clock, "/clock", lambda m: clock.__setitem__(0, m.clock.sec * 10**9
                                                                                + m.clock.nanosec), CLOCK_QOS)
    ros_node.create_subscription(PoseStamped, LIP_TOPICS.root_pose, lambda m: poses.append((
        msg_to_pose_stamped(m).stamp_ns, msg_to_pose_stamped(m).position, run[0])), RELIABLE)

    def start() -> subprocess.Popen:
        return subprocess.Popen([console_script("fusion_node"), *args], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)

    restarted, ready = [], []  # the restarted graph's log lines; the clock as each of its nodes said it was ready

    def read_log(proc: subprocess.Popen) -> None:
        for line in proc.stdout:
            restarted.append(line)
            if "]: ready;" in line:
                ready.append(clock[0])

    graph = start()
    player = subprocess.Popen([console_script("lip_bag_play"), str(bag), "--clock", "--wait-for-subscribers",
                               "--topics", *INPUT_TOPICS], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    logs = []
    try:
        deadline = time.monotonic() + 120.0
        while clock[0] < kill_at_ns and time.monotonic() < deadline:
            rclpy.spin_once(ros_node, timeout_sec=0.1)
        assert clock[0] >= kill_at_ns, "the player did not get 12 s into the capture"
        graph.kill()  # a crash: nothing saved at exit
        logs.append(graph.communicate(timeout=10)[0])
        run[0], killed_at = 1, clock[0]
        graph = start()
        reader = threading.Thread(target=read_log, args=(graph,), daemon=True)
        reader.start()
        while player.poll() is None and time.monotonic() < deadline:
            rclpy.spin_once(ros_node, timeout_sec=0.1)
        end = time.monotonic() + 3.0  # the last frames through the graph
        while time.monotonic() < end:
            rclpy.spin_once(ros_node, timeout_sec=0.1)
    finally:
        graph.send_signal(signal.SIGINT)
        if run[0]:
            graph.wait(timeout=30)
            reader.join(timeout=10)
            logs.append("".join(restarted))
        else:
            logs.append(graph.communicate(timeout=30)[0])
        if player.poll() is None:
            player.send_signal(signal.SIGINT)
            player.wait(timeout=30)
    print("the restarted graph's log:\n" + logs[-1])  # in full in the report of a failure
    assert graph.returncode == 0, logs[-1][-3000:]
    assert not any("Traceback" in log or "terminate called" in log for log in logs), logs[-1][-3000:]
    assert "resuming: the performer was last seen" in logs[1], logs[1][-3000:]
    # the restarted graph's poses: one the killed graph published just before the kill can reach this node after it
    # (session 61's two failures: one pose, stamped before the kill); the restarted graph subscribes seconds after the
    # kill, so the clouds it gets were published, and stamped, after it
    after = [(stamp, position) for stamp, position, r in poses if r == 1 and stamp > killed_at]
    assert np.isfinite(np.array([p for _, p in after])).all()
    # started again, it poses the next frame it can: the first within 6 s of its nodes being ready (its start-up
    # takes seconds of the capture, more on a slower machine; 2.8 s after the kill here once: the DOT is silent until
    # 2 s after it), and then all but the frames the later faults hit (measured 105 poses of the 180 frames left
    # after the kill; 42 with the suite on two workers, its start-up later, session 39): a third of those after it
    # was ready at least
    assert len(ready) == 2, logs[-1][-3000:]  # the calibration and pose nodes
    up_at = max(killed_at, *ready)
    assert after and after[0][0] - up_at < 6 * 10**9, (len(after), after[0][0] - up_at if after else None)
    frames_left = (bag_span(bag)[1] - up_at) / 1e8  # 10 Hz
    assert len(after) >= frames_left / 3, (len(after), frames_left, logs[-1][-3000:])  # the restarted graph's log
