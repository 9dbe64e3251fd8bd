"""lip_bag_play and lip_bag_record over real DDS (separate processes), their QoS mapping and their errors."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import rclpy
from helpers import DEMO_BAG, console_script
from mcap.reader import make_reader
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from std_msgs.msg import Int64, String

from lip_msgs_py import stamp_to_ns
from lip_ros.bagio import (
    RELIABLE_QOS,
    SENSOR_QOS,
    RawMessage,
    bag_qos,
    bag_span,
    bag_topics,
    jazzy_typestore,
    mcap_writer,
    read_messages,
    read_raw,
)
from lip_ros.tools.bag_play import LOOP_GAP_NS
from lip_ros.tools.bag_qos import common_qos, qos_to_bag, qos_to_rclpy

pytestmark = pytest.mark.ros  # DDS traffic or subprocesses

START_S = 8.0  # round trip: the last 5 s of the demo bag
TIMEOUT_S = 60


def _by_topic(messages: list[RawMessage]) -> dict[str, list[RawMessage]]:
    out: dict[str, list[RawMessage]] = defaultdict(list)
    for m in messages:
        out[m.topic].append(m)
    return out


def _stop(proc: subprocess.Popen, sig: signal.Signals) -> tuple[int, str, str]:
    """Signal a recorder to stop; its status, stdout and stderr."""
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=TIMEOUT_S)
    return proc.returncode, out, err


@dataclass(frozen=True)
class Session:
    """One play -> record run."""

    bag: Path
    play: subprocess.CompletedProcess
    record_status: int
    record_out: str
    start_ns: int
    played: list[str]


def _play_and_record(out: Path, play_args: list[str], record_topics: list[str],
                     stop_with: signal.Signals = signal.SIGINT) -> Session:
    """Record ``record_topics`` while ``lip_bag_play`` plays the demo bag with ``play_args``, then stop the recorder."""
    recorder = subprocess.Popen([console_script("lip_bag_record"), str(out), "--topics", *record_topics],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        play = subprocess.run([console_script("lip_bag_play"), str(DEMO_BAG), "--wait-for-subscribers", *play_args],
                              capture_output=True, text=True, timeout=TIMEOUT_S)
        time.sleep(0.5)  # the last messages reach the recorder
    finally:
        status, rec_out, _ = _stop(recorder, stop_with)
    assert play.returncode == 0, play.stderr
    start_s = float(play_args[play_args.index("--start") + 1])
    played = play_args[play_args.index("--topics") + 1:] if "--topics" in play_args else list(bag_topics(DEMO_BAG))
    return Session(out, play, status, rec_out, bag_span(DEMO_BAG)[0] + round(start_s * 1e9), played)


@pytest.fixture(scope="module")
def round_trip(tmp_path_factory: pytest.TempPathFactory) -> Session:
    """All demo topics (clouds included) from START_S on, at rate 1, with /clock."""
    out = tmp_path_factory.mktemp("record") / "round_trip"
    return _play_and_record(out, ["--start", str(START_S), "--clock"], [*bag_topics(DEMO_BAG), "/clock"])


def test_recorder_closes_a_bag_that_rosbags_and_mcap_read(round_trip: Session) -> None:
    assert round_trip.record_status == 0
    assert "wrote" in round_trip.record_out
    counts = {t: i.count for t, i in bag_topics(round_trip.bag).items()}
    with open(next(round_trip.bag.glob("*.mcap")), "rb") as f:
        mcap_counts: dict[str, int] = defaultdict(int)
        for schema, channel, _ in make_reader(f).iter_messages():
            assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
            assert schema.data, "message definitions are needed by Foxglove and ros2 bag"
            mcap_counts[channel.topic] += 1
    assert mcap_counts == counts


def test_round_trip_keeps_every_message_byte_for_byte(round_trip: Session) -> None:
    original = _by_topic(list(read_raw(DEMO_BAG, start_ns=round_trip.start_ns)))
    recorded = _by_topic(list(read_raw(round_trip.bag)))
    assert set(original) == set(round_trip.played)
    for topic, msgs in original.items():
        got = recorded[topic]
        assert len(got) == len(msgs), f"{topic}: {len(got)} of {len(msgs)} messages arrived"
        assert [m.data for m in got] == [m.data for m in msgs], topic


def test_round_trip_keeps_timing_and_qos(round_trip: Session) -> None:
    original = read_raw(DEMO_BAG, start_ns=round_trip.start_ns)
    recorded = read_raw(round_trip.bag, round_trip.played)
    offsets: list[float] = []
    first: tuple[int, int] | None = None
    by_payload = {(m.topic, m.data): m.log_ns for m in recorded}
    for m in original:
        rec_ns = by_payload[(m.topic, m.data)]
        first = first or (m.log_ns, rec_ns)
        offsets.append(((rec_ns - first[1]) - (m.log_ns - first[0])) * 1e-6)
    dev = np.abs(np.array(offsets) - np.median(offsets))  # ms, each message against the bag's spacing
    assert np.percentile(dev, 95) < 30 and np.percentile(dev, 99) < 150, np.percentile(dev, [95, 99, 100])
    topics = bag_topics(round_trip.bag)
    for topic, info in bag_topics(DEMO_BAG).items():  # as the player offered it
        assert topics[topic].reliability == info.reliability, topic


def test_clock_carries_bag_time(round_trip: Session) -> None:
    clock = [(m.log_ns, stamp_to_ns(m.msg.clock)) for m in read_messages(round_trip.bag, ["/clock"])]
    log_ns, bag_ns = np.array(clock).T
    first_data = next(read_raw(round_trip.bag, round_trip.played))
    original_first = next(read_raw(DEMO_BAG, start_ns=round_trip.start_ns))
    span_s = (log_ns[-1] - log_ns[0]) * 1e-9
    assert 30 < len(clock) / span_s < 50  # 40 Hz
    assert np.all(np.diff(bag_ns) > 0)
    expected = original_first.log_ns + (log_ns - first_data.log_ns)  # bag time at the moment of publication
    assert np.median(np.abs(bag_ns - expected)) < 30e6


def test_rate_two_plays_in_half_the_time(tmp_path: Path) -> None:
    topics = ["/gt/root_pose", "/dot/left_wrist/imu"]
    session = _play_and_record(tmp_path / "rate2", ["--rate", "2", "--start", "7", "--topics", *topics], topics,
                               stop_with=signal.SIGTERM)
    assert session.record_status == 0 and "wrote" in session.record_out
    original = list(read_raw(DEMO_BAG, topics, session.start_ns))
    recorded = list(read_raw(session.bag, topics))
    assert len(recorded) == len(original)
    ratio = (recorded[-1].log_ns - recorded[0].log_ns) / (original[-1].log_ns - original[0].log_ns)
    assert 0.45 < ratio < 0.55, ratio
    assert set(bag_topics(session.bag)) == set(topics)  # nothing else was played


SLOW_GRAPH = """
import sys, time, rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2
reports = sys.argv[1]  # "poses", "counts" (on /diagnostics, as every lip_ros node does for its inputs) or "nothing"
depth, period = int(sys.argv[2]), float(sys.argv[3])  # of its cloud queue; of its reports (s)
rclpy.init()
node = rclpy.create_node("slow_graph")
pose = node.create_publisher(PoseStamped, "/slow/pose", QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
diagnostics = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
got, last = [0], [0.0]
def take(cloud):
    got[0] += 1
    time.sleep(0.25)  # a graph 2.5 times slower than the LiDAR
    last[0] = time.monotonic()
    msg = PoseStamped()
    msg.header = cloud.header
    if reports == "poses":
        pose.publish(msg)
def report():
    status = DiagnosticStatus(name="slow_graph: lidar", hardware_id="/ouster/points",
                              values=[KeyValue(key="received", value=str(got[0]))])
    diagnostics.publish(DiagnosticArray(status=[status]))
if reports == "counts":
    node.create_timer(period, report)
node.create_subscription(PointCloud2, "/ouster/points", take, QoSProfile(depth=depth,
                         reliability=qos_profile_sensor_data.reliability))
print("ready", flush=True)
while not got[0] or time.monotonic() - last[0] < 3.0:  # until 3 s without a cloud: its backlog worked off
    rclpy.spin_once(node, timeout_sec=0.1)
print("received", got[0], flush=True)
"""


@pytest.mark.parametrize(("reports", "depth", "period_s", "args"), [
    ("poses", 5, 0.5, []),  # a best-effort queue of 5, as LIP's segmentation node
    ("counts", 20, 0.5, []),  # 2 s, as HSC4D's trajectory node, reported every 0.5 s (lip_process_bag)
    ("counts", 5, 0.25, ["--unreceived", "4"]),  # LIP's queue, reported as lip_process_bag has it
    ("nothing", 5, 0.5, []),
], ids=["poses", "counts", "counts into a queue of 5", "nothing"])
def test_paced_by_the_graph_every_cloud_reaches_a_slow_graph(reports: str, depth: int, period_s: float,
                                                             args: list[str]) -> None:
    """``--paced-by``: a graph 2.5x slower than the LiDAR gets every cloud, the player waiting for its poses, or,
    where it poses nothing, for the ``received`` count of its input on /diagnostics (into a queue of 5, fewer clouds
    not taken than it holds: with the default 1 s of them, 10, it lost 5 of 30); a graph that reports neither gets
    the clouds in real time and loses some (the test can tell)."""
    graph = subprocess.Popen([sys.executable, "-c", SLOW_GRAPH, reports, str(depth), str(period_s)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert graph.stdout.readline().strip() == "ready"
        play = subprocess.run([console_script("lip_bag_play"), str(DEMO_BAG), "--start", "10", "--wait-for-subscribers",
                               "--paced-by", "/slow/pose", *args, "--topics", "/ouster/points"],
                              capture_output=True, text=True, timeout=TIMEOUT_S)
        out, err = graph.communicate(timeout=TIMEOUT_S)  # it ends once it has worked off what it got
    finally:
        if graph.poll() is None:
            graph.kill()
    assert play.returncode == 0 and graph.returncode == 0, (play.stderr, err)
    clouds = sum(1 for _ in read_raw(DEMO_BAG, ["/ouster/points"], bag_span(DEMO_BAG)[0] + 10 * 10**9))
    received = int(out.split("received")[-1]) if "received" in out else 0
    held = float(play.stdout.split("clouds held ")[1].split(" s")[0])
    if reports == "nothing":
        assert received < 0.8 * clouds and held == 0.0, (received, clouds, play.stdout)
    else:
        assert received == clouds and held > 0.0, (received, clouds, play.stdout)


def _wait_until_played(player: subprocess.Popen, messages: int) -> None:
    """Read the player's progress (its stderr, a line a second) until it says it has played ``messages``."""
    deadline = time.monotonic() + TIMEOUT_S
    for line in player.stderr:
        if " messages" in line and int(line.split(" messages")[0].rsplit(" ", 1)[1]) >= messages:
            return
        assert time.monotonic() < deadline, f"the player did not play {messages} messages in {TIMEOUT_S} s"
    raise AssertionError(f"the player ended before it played {messages} messages")


def test_loop_plays_until_interrupted() -> None:
    player = subprocess.Popen([console_script("lip_bag_play"), str(DEMO_BAG), "--loop", "--start", "12",
                               "--topics", "/gt/root_pose"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    per_pass = sum(1 for _ in read_raw(DEMO_BAG, ["/gt/root_pose"], bag_span(DEMO_BAG)[0] + 12 * 10**9))
    _wait_until_played(player, per_pass + 1)  # into the second pass (about 1 s a pass)
    status, out, err = _stop(player, signal.SIGINT)
    assert status == 0, err
    passes = int(out.split(" pass(es)")[0].rsplit("(", 1)[1])
    messages = int(out.split(" messages in ")[0].rsplit(" ", 1)[1])
    assert passes >= 2 and "interrupted" in out, out
    assert (passes - 1) * per_pass <= messages <= passes * per_pass


def test_loop_with_time_going_on_moves_the_stamps_and_the_clock_on(tmp_path: Path) -> None:
    """``--loop --time-goes-on``: pass k is pass 0 stamped k x (window + LOOP_GAP_NS) later, the clock with it;
    nothing else of a message changes."""
    out = tmp_path / "soak"
    recorder = subprocess.Popen([console_script("lip_bag_record"), str(out), "--topics", "/gt/root_pose", "/clock"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    player = subprocess.Popen([console_script("lip_bag_play"), str(DEMO_BAG), "--loop", "--time-goes-on", "--start",
                               "12", "--clock", "--wait-for-subscribers", "--topics", "/gt/root_pose"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    start = bag_span(DEMO_BAG)[0] + 12 * 10**9
    one = [m.msg for m in read_messages(DEMO_BAG, ["/gt/root_pose"]) if m.log_ns >= start]
    _wait_until_played(player, 2 * len(one))  # two passes (about 1 s each)
    time.sleep(0.5)  # their last messages to the recorder
    assert _stop(player, signal.SIGINT)[0] == 0
    assert _stop(recorder, signal.SIGINT)[0] == 0
    window = bag_span(DEMO_BAG)[1] - start + LOOP_GAP_NS
    played = [m.msg for m in read_messages(out, ["/gt/root_pose"])]
    assert len(played) >= 2 * len(one)
    for k, msg in enumerate(played):
        twin = one[k % len(one)]
        assert stamp_to_ns(msg.header.stamp) == stamp_to_ns(twin.header.stamp) + (k // len(one)) * window
        assert msg.pose == twin.pose
    clock = [stamp_to_ns(m.msg.clock) for m in read_messages(out, ["/clock"])]
    assert np.all(np.diff(clock) >= 0) and clock[-1] - clock[0] > window


def test_recorder_stops_after_max_messages(tmp_path: Path) -> None:
    out = tmp_path / "max"
    recorder = subprocess.Popen([console_script("lip_bag_record"), str(out), "--topics", "chatter",
                                 "--max-messages", "25"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rclpy.init()
    node = rclpy.create_node("bag_tools_test_talker")
    try:
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        pub = node.create_publisher(String, "/chatter", qos)
        deadline = time.monotonic() + TIMEOUT_S
        k = 0
        while recorder.poll() is None and time.monotonic() < deadline:
            pub.publish(String(data=f"hello {k}"))
            k += 1
            time.sleep(0.01)
    finally:
        node.destroy_node()
        rclpy.shutdown()
        if recorder.poll() is None:
            recorder.kill()
    assert recorder.wait() == 0, recorder.stderr.read()
    msgs = list(read_messages(out, ["/chatter"]))
    assert len(msgs) == 25 and all(m.msg.data.startswith("hello") for m in msgs)
    info = bag_topics(out)["/chatter"]
    assert info.msgtype == "std_msgs/msg/String" and info.reliability == "reliable"


def test_recorder_says_how_many_messages_it_never_recorded(tmp_path: Path) -> None:
    """A burst of 5000 best-effort messages, faster than the recorder writes them (its queue: RECORD_DEPTH), then
    a few more after a pause: the recorder counts those it never got from the publisher's sequence numbers, so that
    what the bag holds and what it says it missed add up to every message from the first it recorded to the
    last."""
    out = tmp_path / "burst"
    recorder = subprocess.Popen([console_script("lip_bag_record"), str(out), "--topics", "/burst"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rclpy.init()
    node = rclpy.create_node("bag_tools_test_burst")
    burst = 5000
    try:
        pub = node.create_publisher(Int64, "/burst", QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        deadline = time.monotonic() + TIMEOUT_S
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
        for k in range(1, burst + 1):  # the k-th message of this publisher is its sequence number k
            pub.publish(Int64(data=k))
        time.sleep(1.0)
        for k in range(burst + 1, burst + 4):  # the burst's gaps are seen at the next message recorded
            pub.publish(Int64(data=k))
            time.sleep(0.3)
    finally:
        node.destroy_node()
        rclpy.shutdown()
        recorder.send_signal(signal.SIGINT)
    _, err = recorder.communicate(timeout=TIMEOUT_S)
    assert recorder.returncode == 0, err
    values = [m.msg.data for m in read_messages(out, ["/burst"])]
    assert values[-1] > burst and values == sorted(values)
    said = re.search(r"/burst: (\d+) published and never recorded \(\d+ lost in transport, \d+ overwritten in "
                     r"the recorder's queue\)", err)
    assert len(values) + (int(said[1]) if said else 0) == values[-1] - values[0] + 1, err  # here about 5 % recorded


def test_recorder_stops_after_duration_with_a_valid_bag(tmp_path: Path) -> None:
    out = tmp_path / "quiet"
    proc = subprocess.run([console_script("lip_bag_record"), str(out), "--topics", "/nobody/publishes",
                           "--duration", "1"],
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert proc.returncode == 0, proc.stderr
    assert "no publisher of /nobody/publishes" in proc.stderr
    assert bag_topics(out) == {}


@pytest.fixture(scope="module")
def unknown_type_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    store = get_typestore(Stores.ROS2_JAZZY)  # a fresh store, not jazzy_typestore()
    store.register(get_types_from_msg("int32 x", "lip_fake_msgs/msg/Thing"))
    out = tmp_path_factory.mktemp("fake") / "thing"
    with mcap_writer(out) as writer:
        conn = writer.add_connection("/thing", "lip_fake_msgs/msg/Thing", typestore=store)
        writer.write(conn, 1, store.serialize_cdr(store.types["lip_fake_msgs/msg/Thing"](x=1), conn.msgtype))
    return out


BAD_CALLS = {
    "missing bag": (["lip_bag_play", "/no/such/bag"], "no bag at /no/such/bag"),
    "not a bag": (["lip_bag_play", "/"], "not a readable rosbag2 bag"),
    "zero rate": (["lip_bag_play", str(DEMO_BAG), "--rate", "0"], "--rate must be > 0"),
    "unknown topic": (["lip_bag_play", str(DEMO_BAG), "--topics", "/nope"], "/nope not in"),
    "start past end": (["lip_bag_play", str(DEMO_BAG), "--start", "99"], "past the end"),
    "none unreceived": (["lip_bag_play", str(DEMO_BAG), "--paced-by", "/p", "--unreceived", "0"],
                        "--unreceived must be >= 1"),
    "bad number": (["lip_bag_play", str(DEMO_BAG), "--rate", "fast"], "invalid float value"),
    "unknown type": (["lip_bag_play", "UNKNOWN_TYPE_BAG"], "unknown message type lip_fake_msgs/msg/Thing"),
    "no topics": (["lip_bag_record", "/tmp/never"], "the following arguments are required: --topics"),
    "existing out": (["lip_bag_record", str(DEMO_BAG), "--topics", "/a"], "exists"),
    "bad duration": (["lip_bag_record", "/tmp/never", "--topics", "/a", "--duration", "0"], "--duration must be > 0"),
}


@pytest.fixture(scope="module")
def bad_call_results(unknown_type_bag: Path) -> dict[str, subprocess.CompletedProcess]:
    """Every bad call, run concurrently."""
    procs = {name: subprocess.Popen([console_script(argv[0]), *(str(unknown_type_bag) if a == "UNKNOWN_TYPE_BAG" else a
                                                      for a in argv[1:])],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for name, (argv, _) in BAD_CALLS.items()}
    results = {}
    for name, p in procs.items():
        out, err = p.communicate(timeout=TIMEOUT_S)
        results[name] = subprocess.CompletedProcess(p.args, p.returncode, out, err)
    return results


@pytest.mark.parametrize("case", BAD_CALLS)
def test_bad_calls_fail_in_one_line(bad_call_results: dict[str, subprocess.CompletedProcess], case: str) -> None:
    result = bad_call_results[case]
    prog, expected = Path(BAD_CALLS[case][0][0]).name, BAD_CALLS[case][1]
    assert result.returncode == 2, (result.stdout, result.stderr)
    assert result.stderr.count("\n") == 1 and result.stderr.startswith(f"{prog}: error: "), result.stderr
    assert expected in result.stderr
    assert not Path("/tmp/never").exists()


def test_qos_records_map_to_rclpy_and_back() -> None:
    sensor = qos_to_rclpy(SENSOR_QOS)
    assert (sensor.reliability, sensor.history, sensor.depth) == (ReliabilityPolicy.BEST_EFFORT,
                                                                  HistoryPolicy.KEEP_LAST, 5)
    assert qos_to_rclpy(RELIABLE_QOS).reliability == ReliabilityPolicy.RELIABLE
    latched = bag_qos(QosReliability.RELIABLE, 1, QosDurability.TRANSIENT_LOCAL)
    for q in (SENSOR_QOS, RELIABLE_QOS, latched):
        assert qos_to_bag(qos_to_rclpy(q)) == q


def test_common_qos_is_compatible_with_every_offer() -> None:
    sensor, reliable = qos_to_rclpy(SENSOR_QOS), qos_to_rclpy(RELIABLE_QOS)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    assert common_qos([reliable]).reliability == ReliabilityPolicy.RELIABLE
    assert common_qos([reliable, sensor]).reliability == ReliabilityPolicy.BEST_EFFORT
    assert common_qos([latched]).durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert common_qos([latched, reliable]).durability == DurabilityPolicy.VOLATILE
    assert common_qos([sensor, reliable]).depth == 10 and common_qos([sensor], depth=100).depth == 100
    recorded_by_ros2_bag = QoSProfile(history=HistoryPolicy.UNKNOWN, depth=0, reliability=ReliabilityPolicy.RELIABLE)
    assert common_qos([recorded_by_ros2_bag]).depth == 10  # endpoint discovery reports no history
    assert common_qos([]).reliability == ReliabilityPolicy.RELIABLE


def test_record_type_needs_a_jazzy_definition() -> None:
    from lip_ros.tools.bag_record import record_type
    from lip_ros.tools.ros_cli import ToolError

    assert record_type("std_msgs/msg/String", "/a") is String
    assert "lip_fake_msgs/msg/Thing" not in jazzy_typestore().types
    with pytest.raises(ToolError, match="not a ROS 2 Jazzy type"):
        record_type("lip_fake_msgs/msg/Thing", "/a")
