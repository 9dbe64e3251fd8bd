"""lip_bag_play: publish a rosbag2 bag's messages with their recorded timing and QoS (as ``ros2 bag play`` does).

  lip_bag_play BAG [--rate R] [--start S] [--loop [--time-goes-on]] [--clock [HZ]] [--topics T ...]
               [--wait-for-subscribers] [--paced-by POSE_TOPIC [--ahead N] [--unreceived N]]

Messages keep their log-time spacing (divided by ``--rate``) and are published
as the CDR bytes stored in the bag, never deserialised; each topic gets the
reliability, durability and depth its publishers offered when it was recorded.
``--clock`` also publishes ``/clock`` (rosgraph_msgs/Clock, bag time) for nodes
with ``use_sim_time``. ``--loop`` plays the bag again and again, each pass with
the bag's own time (as ``ros2 bag play --loop``: /clock and the stamps go back);
with ``--time-goes-on`` each pass goes on from where the last one ended
instead: /clock and every header stamp move on by the played window's length
plus :data:`LOOP_GAP_NS`, as one long capture would (a soak test).
``--paced-by`` plays no faster than the graph it feeds (a bag processed
offline): each point cloud waits while the graph's latest pose on POSE_TOPIC
(geometry_msgs/PoseStamped) is stamped before the cloud ``--ahead`` clouds
before it, or while the graph's input of the cloud's topic is more than
``--unreceived`` clouds (by default :data:`UNRECEIVED_S` of them) behind what
was sent (by the ``received`` count it reports on /diagnostics, as every
lip_ros node does for its inputs: this paces a graph that poses nothing yet,
calibrating or waiting for a jump; fewer than its input queue holds, more
than the clouds sent between two of its reports);
the timing of everything after the wait moves on by the wait (/clock stands
still meanwhile). A measure that has not moved on for :data:`PACING_STALL_S`
holds nothing (a graph that poses nobody; clouds lost are not waited for
again); with neither it plays at ``--rate``.
Progress on stderr, a summary on stdout.
"""

from __future__ import annotations

import itertools
import sys
import threading
import time
from collections import deque
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from lip_msgs_py import ns_to_sec_nanosec, rclpy_message_class, stamp_to_ns
from lip_msgs_py.cdr import cdr_stamp, with_cdr_stamp
from lip_msgs_py.stamps import NS_PER_S
from lip_ros.bagio import BagError, TopicInfo, bag_span, bag_topics, read_raw
from lip_ros.tools.bag_qos import common_qos, qos_to_rclpy
from lip_ros.tools.ros_cli import ArgumentParser, Progress, ToolError, run_tool, start_ros, stop_on_signals, tool_args

PROG = "lip_bag_play"
CLOCK_TOPIC = "/clock"
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)  # as rclpy's and rclcpp's time sources
DEFAULT_CLOCK_HZ = 40.0  # ros2 bag play --clock's default
DISCOVERY_SETTLE_S = 0.5  # after the subscribers appear, for their side of discovery to finish too
ACK_TIMEOUT = Duration(seconds=2)  # reliable topics: wait this long at the end for the last messages' acks
LINGER_S = 0.5  # best-effort topics: stay this long at the end, as subscribers lose what an exiting writer sent last
LOOP_GAP_NS = 100_000_000  # --time-goes-on: from the end of one pass to the start of the next, in bag time
DEFAULT_AHEAD = 3  # --paced-by: clouds the graph may have unposed (within a LiDAR input queue's depth of 5)
PACING_STALL_S = 2.0  # --paced-by: a measure that has not moved on for this long (wall time) holds nothing
#: --paced-by: the seconds of clouds (at the bag's rate) the graph's input may not have taken yet (HSC4D's cloud
#: queue holds 2 s, its nodes report every 0.5 s under lip_process_bag, 1 s by default; LIP's holds 5 clouds:
#: lip_process_bag gives it --unreceived 4)
UNRECEIVED_S = 1.0
DIAGNOSTICS_TOPIC = "/diagnostics"
PACED_TYPE = "sensor_msgs/msg/PointCloud2"  # the messages --paced-by holds


@dataclass(frozen=True)
class PlayPlan:
    """What to play: the bag, its selected topics with their message classes, the bag-time window and the options."""

    bag: Path
    topics: dict[str, TopicInfo]
    classes: dict[str, type]
    first_ns: int  # the bag's first message's log time (its topics' rates are over first_ns..end_ns)
    start_ns: int
    end_ns: int
    rate: float = 1.0
    loop: bool = False
    clock_hz: float | None = None
    wait_for_subscribers: bool = False
    time_goes_on: bool = False  # with loop: each pass's time follows the last one's (header stamps and /clock)
    paced_by: str | None = None  # the graph's PoseStamped topic that paces the clouds (--paced-by)
    ahead: int = DEFAULT_AHEAD  # clouds the graph may have unposed with paced_by
    unreceived: int | None = None  # clouds of a topic its input may not have taken with paced_by (None: UNRECEIVED_S)


@dataclass
class PlayStats:
    """What was played."""

    messages: int = 0
    passes: int = 0
    max_lag_ms: float = 0.0  # largest delay of a publication behind its scheduled time
    held_s: float = 0.0  # wall time the clouds waited for the graph (paced_by)
    per_topic: dict[str, int] = field(default_factory=dict)


def plan_playback(bag: Path, rate: float = 1.0, start_s: float = 0.0, topics: list[str] | None = None,
                  loop: bool = False, clock_hz: float | None = None, wait_for_subscribers: bool = False,
                  time_goes_on: bool = False, paced_by: str | None = None, ahead: int = DEFAULT_AHEAD,
                  unreceived: int | None = None) -> PlayPlan:
    """Check the bag and options and resolve each topic's rclpy message class; ToolError on a problem."""
    if not rate > 0:
        raise ToolError(f"--rate must be > 0, got {rate}")
    if not start_s >= 0:
        raise ToolError(f"--start must be >= 0, got {start_s}")
    if clock_hz is not None and not clock_hz > 0:
        raise ToolError(f"--clock rate must be > 0 Hz, got {clock_hz}")
    if not Path(bag).exists():
        raise ToolError(f"no bag at {bag}")
    try:
        available = bag_topics(bag)
        first_ns, last_ns = bag_span(bag)
    except BagError as exc:
        raise ToolError(str(exc)) from None
    unknown = sorted(set(topics or ()) - available.keys())
    if unknown:
        raise ToolError(f"topic(s) {', '.join(unknown)} not in {bag} (it has {', '.join(sorted(available))})")
    selected = {t: i for t, i in available.items() if topics is None or t in topics}
    classes = {}
    for topic, info in selected.items():
        try:
            classes[topic] = rclpy_message_class(info.msgtype)
        except KeyError:
            raise ToolError(f"unknown message type {info.msgtype} of {topic}: its Python package is not installed "
                            f"(leave the topic out with --topics)") from None
    start_ns = first_ns + round(start_s * NS_PER_S)
    if start_ns > last_ns:
        raise ToolError(f"--start {start_s} s is past the end of the bag ({(last_ns - first_ns) / NS_PER_S:.1f} s)")
    if time_goes_on and not loop:
        raise ToolError("--time-goes-on is for --loop")
    if paced_by is not None and not any(selected[t].msgtype == PACED_TYPE for t in selected):
        raise ToolError(f"--paced-by holds point clouds, and none of the played topics is a {PACED_TYPE}")
    if not ahead >= 1:
        raise ToolError(f"--ahead must be >= 1, got {ahead}")
    if unreceived is not None and not unreceived >= 1:
        raise ToolError(f"--unreceived must be >= 1, got {unreceived}")
    return PlayPlan(Path(bag), selected, classes, first_ns, start_ns, last_ns, rate, loop, clock_hz,
                    wait_for_subscribers, time_goes_on, paced_by, ahead, unreceived)


class BagPlayer:
    """Publishes a planned playback on ``node`` until done or until ``stop`` is set."""

    def __init__(self, node: Node, plan: PlayPlan, stop: threading.Event, progress: Progress | None = None) -> None:
        self.plan, self.stop, self.progress = plan, stop, progress
        self.publishers: dict[str, Publisher] = {
            topic: node.create_publisher(plan.classes[topic], topic,
                                         common_qos([qos_to_rclpy(q) for q in info.offered_qos]))
            for topic, info in plan.topics.items()
        }
        self.clock_pub = node.create_publisher(Clock, CLOCK_TOPIC, CLOCK_QOS) if plan.clock_hz else None
        #: the topics whose messages start with a std_msgs/Header (their stamps move on with --time-goes-on)
        self.stamped = {t for t, c in plan.classes.items()
                        if next(iter(c.get_fields_and_field_types().items()), None) == ("header", "std_msgs/Header")}
        self.stats = PlayStats(per_topic=dict.fromkeys(plan.topics, 0))
        self.paced = {t for t, i in plan.topics.items() if i.msgtype == PACED_TYPE} if plan.paced_by else set()
        span_s = max(plan.end_ns - plan.first_ns, 1) / NS_PER_S
        unreceived = {t: plan.unreceived or max(1, round(UNRECEIVED_S * plan.topics[t].count / span_s))
                      for t in self.paced}
        self.pacer = None if plan.paced_by is None else Pacer(node, plan.paced_by, plan.ahead, unreceived, stop)

    def run(self) -> PlayStats:
        """Wait for subscribers if asked, play (looping if asked), let reliable topics deliver; the stats."""
        try:
            if self.plan.wait_for_subscribers and not self._wait_for_subscribers():
                return self.stats
            while not self.stop.is_set():
                offset = self.stats.passes * (self.plan.end_ns - self.plan.start_ns + LOOP_GAP_NS)
                self._play_pass(offset if self.plan.time_goes_on else 0)
                self.stats.passes += 1
                if not self.plan.loop:
                    break
        finally:
            if self.pacer is not None:
                self.pacer.close()
        for pub in self.publishers.values():
            if pub.qos_profile.reliability == ReliabilityPolicy.RELIABLE:
                pub.wait_for_all_acked(ACK_TIMEOUT)
        self.stop.wait(LINGER_S)
        return self.stats

    def _wait_for_subscribers(self) -> bool:
        while not self.stop.is_set():
            missing = [t for t, p in self.publishers.items() if p.get_subscription_count() == 0]
            if not missing:
                return not self.stop.wait(DISCOVERY_SETTLE_S)
            if self.progress:
                self.progress(f"waiting for subscribers on {', '.join(missing)}")
            self.stop.wait(0.05)
        return False

    def _play_pass(self, offset_ns: int = 0) -> None:
        """Publish the window once; message k at wall0 + (log_k - start) / rate; ``offset_ns`` later in time (the
        header stamps and /clock)."""
        plan = self.plan
        with closing(read_raw(plan.bag, plan.topics, plan.start_ns)) as messages:
            first = next(messages, None)  # the bag is open and its first chunk read before the clock starts
            wall0 = time.monotonic_ns()
            next_clock = wall0
            for m in itertools.chain([first] if first else [], messages):
                due = wall0 + round((m.log_ns - plan.start_ns) / plan.rate)
                while (now := time.monotonic_ns()) < due:
                    if self.stop.is_set():
                        return
                    bag_ns = plan.start_ns + round((now - wall0) * plan.rate)
                    if self.clock_pub is not None and now >= next_clock:
                        self._publish_clock(bag_ns + offset_ns)
                        next_clock += round(NS_PER_S / plan.clock_hz)
                    if self.progress:
                        self.progress(self._status(bag_ns))
                    wake = min(due, next_clock) if self.clock_pub is not None else due
                    self.stop.wait((wake - now) / NS_PER_S)
                if self.stop.is_set():
                    return
                if m.topic in self.paced:
                    held = self.pacer.hold(m.topic, cdr_stamp(m.data) + offset_ns)
                    wall0, next_clock, due = wall0 + held, next_clock + held, due + held
                    self.stats.held_s += held / NS_PER_S
                stamped = offset_ns and m.topic in self.stamped
                self.publishers[m.topic].publish(with_cdr_stamp(m.data, cdr_stamp(m.data) + offset_ns) if stamped
                                                 else m.data)
                self.stats.messages += 1
                self.stats.per_topic[m.topic] += 1
                self.stats.max_lag_ms = max(self.stats.max_lag_ms, (time.monotonic_ns() - due) / 1e6)

    def _publish_clock(self, bag_ns: int) -> None:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = ns_to_sec_nanosec(bag_ns)
        self.clock_pub.publish(msg)

    def _status(self, bag_ns: int) -> str:
        total = (self.plan.end_ns - self.plan.start_ns) / NS_PER_S
        return f"{(bag_ns - self.plan.start_ns) / NS_PER_S:6.1f} / {total:.1f} s, {self.stats.messages} messages"


class Pacer:
    """``--paced-by``: holds each cloud while the graph lags, by its latest pose on ``pose_topic`` (older than the
    cloud ``ahead`` before) or by its input of the cloud's topic (more than ``unreceived[topic]`` of the clouds sent
    not taken, by the ``received`` counts on /diagnostics); both taken on a thread of its own."""

    def __init__(self, node: Node, pose_topic: str, ahead: int, unreceived: dict[str, int],
                 stop: threading.Event) -> None:
        self.ahead, self.unreceived, self.stop = ahead, dict(unreceived), stop
        self._sent: deque[int] = deque(maxlen=ahead)  # header stamps (ns) of the last clouds published
        self._pose: tuple[int, int] | None = None  # (stamp, monotonic ns of its arrival) of the latest pose
        self._count = dict.fromkeys(unreceived, 0)  # topic -> clouds published
        self._reports: dict[str, tuple[int, int]] = {}  # status name -> (its "received", its node's counts before)
        self._taken: dict[str, tuple[int, int]] = {}  # topic -> (clouds the graph took, monotonic ns that grew)
        self._lost = dict.fromkeys(unreceived, 0)  # topic -> clouds sent that it never took (not waited for again)
        self._posed = threading.Condition()
        node.create_subscription(PoseStamped, pose_topic, self._on_pose,
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics,
                                 QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(node)
        self._thread = threading.Thread(target=self._executor.spin, name="pacer", daemon=True)
        self._thread.start()

    def _on_pose(self, msg: PoseStamped) -> None:
        with self._posed:
            self._pose = stamp_to_ns(msg.header.stamp), time.monotonic_ns()
            self._posed.notify_all()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        """The ``received`` counts of the inputs of the paced topics (``hardware_id``); a count that went down is a
        node started again, its counts before added on."""
        with self._posed:
            for status in msg.status:
                received = next((v.value for v in status.values if v.key == "received"), None)
                if status.hardware_id not in self._count or received is None or not received.isdigit():
                    continue
                last, before = self._reports.get(status.name, (0, 0))
                self._reports[status.name] = int(received), before + (last if int(received) < last else 0)
                taken = int(received) + self._reports[status.name][1]
                if status.hardware_id not in self._taken:  # the graph took clouds before this player: not ours
                    self._lost[status.hardware_id] = min(0, self._count[status.hardware_id] - taken)
                if taken > self._taken.get(status.hardware_id, (-1, 0))[0]:
                    self._taken[status.hardware_id] = taken, time.monotonic_ns()
            self._posed.notify_all()

    def _lagging(self, topic: str) -> bool:
        """Whether the graph is behind: its latest pose older than the cloud ``ahead`` before, and recent; or more
        than ``unreceived`` of ``topic``'s clouds sent not taken, its count grown recently (clouds that were not
        taken for that long are lost: not waited for again)."""
        now = time.monotonic_ns()
        if self._pose is not None and len(self._sent) == self.ahead:
            stamp, arrived = self._pose
            if stamp < self._sent[0] and now - arrived < PACING_STALL_S * NS_PER_S:
                return True
        if topic not in self._taken:
            return False
        taken, grew = self._taken[topic]
        if self._count[topic] - self._lost[topic] - taken <= self.unreceived[topic]:
            return False
        if now - grew < PACING_STALL_S * NS_PER_S:
            return True
        self._lost[topic] = self._count[topic] - taken
        return False

    def hold(self, topic: str, stamp_ns: int) -> int:
        """Wait while the graph lags (or until stopped), then count the cloud of ``topic`` stamped ``stamp_ns`` as
        sent; the wall time waited (ns)."""
        start = time.monotonic_ns()
        with self._posed:
            while self._lagging(topic) and not self.stop.is_set():
                self._posed.wait(0.05)
            self._sent.append(stamp_ns)
            self._count[topic] += 1
        return time.monotonic_ns() - start

    def close(self) -> None:
        """Stop taking poses and reports."""
        self._executor.shutdown(timeout_sec=1.0)
        self._thread.join(timeout=2.0)


def parser() -> ArgumentParser:
    """The command-line interface."""
    p = ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                       epilog="ROS arguments go after --ros-args (e.g. remapping: --ros-args -r /a:=/b).")
    p.add_argument("bag", type=Path, help="rosbag2 bag directory (MCAP or sqlite3)")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1)")
    p.add_argument("--start", type=float, default=0.0, metavar="S", help="skip the first S seconds of the bag")
    p.add_argument("--loop", action="store_true", help="play again and again until interrupted")
    p.add_argument("--time-goes-on", action="store_true",
                   help="with --loop: each pass's /clock and header stamps go on from the last pass's end (one long "
                        "capture) instead of going back to the bag's start")
    p.add_argument("--clock", type=float, nargs="?", const=DEFAULT_CLOCK_HZ, metavar="HZ",
                   help=f"publish {CLOCK_TOPIC} (bag time) at HZ (default {DEFAULT_CLOCK_HZ:g}) for use_sim_time")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="play only these topics")
    p.add_argument("--wait-for-subscribers", action="store_true",
                   help="start only when every played topic has a subscriber")
    p.add_argument("--paced-by", metavar="POSE_TOPIC",
                   help="hold each point cloud while the graph's latest pose on this geometry_msgs/PoseStamped topic "
                        "is stamped before the cloud --ahead clouds before it, or while the graph's input of the "
                        f"cloud's topic is more than {UNRECEIVED_S:g} s of clouds behind what was sent (by its "
                        f"received count on {DIAGNOSTICS_TOPIC}): no faster than the graph")
    p.add_argument("--ahead", type=int, default=DEFAULT_AHEAD, metavar="N",
                   help=f"with --paced-by: clouds the graph may have unposed (default {DEFAULT_AHEAD})")
    p.add_argument("--unreceived", type=int, metavar="N",
                   help=f"with --paced-by: clouds of a topic the graph's input may not have taken yet (default "
                        f"{UNRECEIVED_S:g} s of them at the bag's rate; fewer than the input's queue holds)")
    return p


def _play(argv: list[str]) -> int:
    args = parser().parse_args(tool_args(argv))
    plan = plan_playback(args.bag, args.rate, args.start, args.topics, args.loop, args.clock,
                         args.wait_for_subscribers, args.time_goes_on, args.paced_by, args.ahead, args.unreceived)
    stop = stop_on_signals()
    start_ros(argv)
    node = rclpy.create_node("lip_bag_play")
    progress = Progress(PROG)
    t0 = time.monotonic()
    try:
        stats = BagPlayer(node, plan, stop, progress).run()
    finally:
        progress.done()
        node.destroy_node()
    topics = ", ".join(f"{t} {n}" for t, n in stats.per_topic.items())
    held = f", clouds held {stats.held_s:.1f} s for the graph" if plan.paced_by else ""
    print(f"{PROG}: {stats.messages} messages in {time.monotonic() - t0:.1f} s ({stats.passes} pass(es), "
          f"max lag {stats.max_lag_ms:.1f} ms{held}{', interrupted' if stop.is_set() else ''}): {topics}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``lip_bag_play`` (``argv`` with the program name, as ``sys.argv``)."""
    return run_tool(PROG, _play, sys.argv if argv is None else argv)


if __name__ == "__main__":
    raise SystemExit(main())
