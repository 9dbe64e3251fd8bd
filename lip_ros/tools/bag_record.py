"""lip_bag_record: record topics into a rosbag2 MCAP bag (as ``ros2 bag record -s mcap`` does).

  lip_bag_record OUT --topics T ... [--duration S] [--max-messages N]

Each topic is subscribed as soon as a publisher of it appears, with the type the
graph reports and a QoS compatible with every publisher (best effort if any
publisher is), and recorded as the CDR bytes that arrive, never deserialised.
The bag (version 9, MCAP, ROS 2 Jazzy message definitions, the publishers'
offered QoS per topic) opens in ``ros2 bag``, rosbags and Foxglove. Log times
are the middleware's reception times (system clock), or the node clock's when
``use_sim_time`` is set (``--ros-args -p use_sim_time:=true``). Recording stops on
SIGINT or SIGTERM, after ``--duration`` or ``--max-messages``; the bag is always
closed cleanly. Messages published and never recorded (lost in transport, or
overwritten in the recorder's queue while it wrote) are counted per topic from
the publishers' sequence numbers (``lip_ros.core.delivery``; not before the
first message recorded of a publisher, nor after its last; not where the
middleware does not number them) and said at the end for each topic that has any.
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path
from typing import Any

import rclpy
from rclpy.node import Node
from rclpy.subscription import Subscription
from rosbags.interfaces import Connection
from rosbags.rosbag2 import Writer

from lip_msgs_py import rclpy_message_class
from lip_ros.bagio import jazzy_typestore, mcap_writer
from lip_ros.core.delivery import DeliveryGaps, not_taken_how
from lip_ros.nodes.base import subscribe_counting_losses
from lip_ros.tools.bag_qos import common_qos, qos_to_bag
from lip_ros.tools.ros_cli import ArgumentParser, Progress, ToolError, run_tool, start_ros, stop_on_signals, tool_args

PROG = "lip_bag_record"
RECORD_DEPTH = 100  # subscription queue per topic: room for bursts while a large message is being written
GRAPH_POLL_S = 0.2  # how often the graph is searched for publishers of topics not yet subscribed
RECORDER_QUEUE = "the recorder's queue"  # where a message not recorded may have been overwritten, as said


def record_type(msgtype: str, topic: str) -> type:
    """The rclpy class of a topic's type, which must also be a ROS 2 Jazzy type (for the bag's definitions)."""
    if msgtype not in jazzy_typestore().types:
        raise ToolError(f"unknown message type {msgtype} of {topic}: not a ROS 2 Jazzy type, no definition to record")
    try:
        return rclpy_message_class(msgtype)
    except KeyError:
        raise ToolError(f"unknown message type {msgtype} of {topic}: its Python package is not installed") from None


class BagRecorder:
    """Subscribes ``topics`` on ``node`` as publishers appear and writes what arrives with ``writer``."""

    def __init__(self, node: Node, writer: Writer, topics: list[str], stop: threading.Event,
                 max_messages: int | None = None) -> None:
        self.node, self.writer, self.stop, self.max_messages = node, writer, stop, max_messages
        self.counts: dict[str, int] = {}
        #: per topic subscribed: the messages published and never recorded (times: time.monotonic)
        self.gaps: dict[str, DeliveryGaps] = {}
        self._subscriptions: dict[str, Subscription] = {}  # per topic
        self.pending = list(dict.fromkeys(topics))
        self.messages = 0

    def poll_graph(self) -> None:
        """Subscribe every pending topic that has a publisher now."""
        types = dict(self.node.get_topic_names_and_types())
        for topic in [t for t in self.pending if t in types]:
            if len(types[topic]) != 1:
                raise ToolError(f"{topic} is published with several types: {', '.join(types[topic])}")
            cls = record_type(types[topic][0], topic)
            offers = [info.qos_profile for info in self.node.get_publishers_info_by_topic(topic)]
            if not offers:
                continue  # the publisher left again
            conn = self.writer.add_connection(topic, types[topic][0], typestore=jazzy_typestore(),
                                              offered_qos_profiles=[qos_to_bag(q) for q in offers])
            gaps = self.gaps[topic] = DeliveryGaps()
            qos = common_qos(offers, depth=RECORD_DEPTH)

            def write(data: bytes, info: dict[str, Any], conn: Connection = conn) -> None:
                self._write(conn, data, info)

            self._subscriptions[topic] = subscribe_counting_losses(self.node, cls, topic, write, qos, gaps,
                                                                   time.monotonic, raw=True)
            self.counts[topic] = 0
            self.pending.remove(topic)

    def not_recorded(self) -> list[str]:
        """Per topic with messages published and never recorded: how many and where they went."""
        return [f"{topic}: {gaps.total.not_taken} published and never recorded "
                f"({not_taken_how(gaps.total, gaps.loss_events, RECORDER_QUEUE)})"
                for topic, gaps in self.gaps.items() if gaps.total.not_taken]

    def _log_ns(self, info: dict[str, Any]) -> int:
        """When the middleware received the message (Python's callback may run later); sim time if in use."""
        clock = self.node.get_clock()
        received = info.get("received_timestamp") or 0
        return clock.now().nanoseconds if clock.ros_time_is_active or not received else received

    def _write(self, conn: Connection, data: bytes, info: dict[str, Any]) -> None:
        if self.max_messages is not None and self.messages >= self.max_messages:
            return
        self.writer.write(conn, self._log_ns(info), data)
        self.gaps[conn.topic].taken(time.monotonic(), info.get("publication_sequence_number"),
                                    self._subscriptions[conn.topic].get_publisher_count)
        self.counts[conn.topic] += 1
        self.messages += 1
        if self.max_messages is not None and self.messages >= self.max_messages:
            self.stop.set()

    def run(self, duration_s: float | None = None, progress: Progress | None = None) -> None:
        """Record until ``stop`` is set or ``duration_s`` has passed."""
        end = None if duration_s is None else time.monotonic() + duration_s
        next_poll = 0.0
        while not self.stop.is_set() and (end is None or time.monotonic() < end):
            if self.pending and time.monotonic() >= next_poll:
                self.poll_graph()
                next_poll = time.monotonic() + GRAPH_POLL_S
            rclpy.spin_once(self.node, timeout_sec=0.05)
            if progress:
                progress(f"{self.messages} messages, {len(self.counts)}/{len(self.counts) + len(self.pending)}"
                         " topics subscribed")


def parser() -> ArgumentParser:
    """The command-line interface."""
    p = ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                       epilog="ROS arguments go after --ros-args (e.g. -p use_sim_time:=true).")
    p.add_argument("out", type=Path, help="bag directory to create (must not exist)")
    p.add_argument("--topics", nargs="+", required=True, metavar="TOPIC", help="topics to record")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--max-messages", type=int, metavar="N", help="stop after N messages in all")
    return p


def _record(argv: list[str]) -> int:
    args = parser().parse_args(tool_args(argv))
    if args.out.exists():
        raise ToolError(f"{args.out} exists; choose a new directory")
    if args.duration is not None and not args.duration > 0:
        raise ToolError(f"--duration must be > 0, got {args.duration}")
    if args.max_messages is not None and args.max_messages < 1:
        raise ToolError(f"--max-messages must be >= 1, got {args.max_messages}")
    topics = [t if t.startswith("/") else "/" + t for t in args.topics]
    stop = stop_on_signals()
    start_ros(argv)
    node = rclpy.create_node("lip_bag_record")
    writer = mcap_writer(args.out)
    writer.open()
    recorder = BagRecorder(node, writer, topics, stop, args.max_messages)
    progress = Progress(PROG)
    try:
        recorder.run(args.duration, progress)
    finally:  # an error too ends with a complete bag of what was recorded
        progress.done()
        writer.close()
        node.destroy_node()
    for topic in recorder.pending:
        print(f"{PROG}: warning: no publisher of {topic} appeared", file=sys.stderr)
    for line in recorder.not_recorded():
        print(f"{PROG}: warning: {line}", file=sys.stderr)
    counts = ", ".join(f"{t} {n}" for t, n in recorder.counts.items())
    print(f"{PROG}: wrote {args.out}: {recorder.messages} messages ({counts})")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``lip_bag_record`` (``argv`` with the program name, as ``sys.argv``)."""
    return run_tool(PROG, _record, sys.argv if argv is None else argv)


if __name__ == "__main__":
    raise SystemExit(main())
