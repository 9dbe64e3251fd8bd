"""How a graph's spinning threads tell a shutdown from a failure (rclpy in this process, no traffic), how a
node takes a fast input's waiting messages itself, polls an input no executor waits on and counts the messages
overwritten in an input's queue (over DDS), and how the nodes of one process hand their messages to each other
directly."""

from __future__ import annotations

import threading
import time

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Int64

from lip_ros.nodes.base import (
    BETWEEN_NODES,
    DIRECT_INPUTS_PARAM,
    NOT_TAKEN_VALUE,
    RELIABLE,
    GraphNode,
    LocalTopics,
    _spin_each,
    suit_input,
)
from lip_ros.nodes.lip import LIP_PARAMS_FILE

pytestmark = pytest.mark.ros


def _spin_one_callback(callback, stop: threading.Event | None = None) -> list[BaseException]:
    rclpy.init()
    node = rclpy.create_node("lip_ros_test_spin")
    node.create_timer(0.01, callback)
    try:
        return _spin_each([node], stop or threading.Event())
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def test_a_shutdown_during_the_wait_set_is_a_clean_shutdown() -> None:
    """A shutdown of the context while spin_once builds its wait set raises RCLError inside rclpy (seen in CI as a
    traceback at the end of a run): the same as a shutdown, nothing to report."""
    def signal_then_wait_set() -> None:
        rclpy.try_shutdown()  # a shutdown from elsewhere (e.g. the HSC4D graph's child ended)
        raise RCLError("failed to initialize wait set: the given context is not valid")

    assert _spin_one_callback(signal_then_wait_set) == []


def test_a_stop_signal_ends_every_spin_cleanly() -> None:
    """SIGINT or SIGTERM set the stop event (``stop_on_signals``): the main thread shuts the context down, every
    node's spin ends, nothing is reported."""
    stop, calls = threading.Event(), []

    def count_then_stop() -> None:
        calls.append(1)
        if len(calls) == 3:
            stop.set()

    assert _spin_one_callback(count_then_stop, stop) == []
    assert len(calls) >= 3 and not rclpy.ok()


def test_a_failing_callback_is_reported_and_stops_the_graph() -> None:
    def fail() -> None:
        raise RuntimeError("a bug")

    errors = _spin_one_callback(fail)
    assert [str(e) for e in errors] == ["a bug"]
    assert not rclpy.ok()


class _Probe(GraphNode):
    """A graph node with one fast input, its messages kept in order."""

    NAME = "lip_ros_test_take_waiting"
    PARAMS_FILE = LIP_PARAMS_FILE

    def __init__(self) -> None:
        super().__init__(self.NAME)
        self.handled: list[int] = []
        self.add_input("probe", "/lip_ros_test/take_waiting", Int64, 100.0, self._on_probe, suit_input(100.0))

    def _on_probe(self, msg: Int64) -> int:
        self.handled.append(msg.data)
        return msg.data


def test_take_waiting_handles_every_message_already_received() -> None:
    """A long callback takes the rest of a fast input in one go (the executor would give it one message per wait):
    every message received so far, in order, through the input's own handler; then nothing."""
    rclpy.init()
    probe = _Probe()
    driver = rclpy.create_node("lip_ros_test_take_waiting_driver")
    publisher = driver.create_publisher(Int64, "/lip_ros_test/take_waiting", suit_input(100.0))
    try:
        deadline = time.monotonic() + 10.0
        while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        for k in range(1, 51):
            publisher.publish(Int64(data=k))
        taken = 0
        while taken < 50 and time.monotonic() < deadline:  # no executor spins: only take_waiting takes
            time.sleep(0.05)
            taken += probe.take_waiting("probe")
        assert probe.handled == list(range(1, 51)) and taken == 50
        assert probe.take_waiting("probe") == 0
    finally:
        driver.destroy_node()
        probe.destroy_node()
        rclpy.try_shutdown()


class _PolledProbe(GraphNode):
    """A graph node with one input the executor waits on and one it polls (``topics``: their topics, by "spun" and
    "polled"; ``qos``: default the suit's)."""

    NAME = "lip_ros_test_polled"
    PARAMS_FILE = LIP_PARAMS_FILE

    def __init__(self, topics: str = "/lip_ros_test/{}", qos: QoSProfile | None = None) -> None:
        super().__init__(self.NAME)
        self.handled: dict[str, list[int]] = {"spun": [], "polled": []}
        for name in self.handled:
            self.add_input(name, topics.format(name), Int64, 100.0,
                           lambda msg, name=name: self.handled[name].append(msg.data) or msg.data,
                           qos or suit_input(100.0), polled=name == "polled")


def test_a_polled_input_is_taken_only_when_the_node_polls_it() -> None:
    """An executor spinning the node handles the other input's messages but never the polled one's (it is not in
    its wait set); take_polled then handles every one received, in order, through the input's handler."""
    rclpy.init()
    probe = _PolledProbe()
    driver = rclpy.create_node("lip_ros_test_polled_driver")
    publishers = {name: driver.create_publisher(Int64, f"/lip_ros_test/{name}", suit_input(100.0))
                  for name in probe.handled}
    executor = SingleThreadedExecutor()
    executor.add_node(probe)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        deadline = time.monotonic() + 10.0
        while (min(p.get_subscription_count() for p in publishers.values()) == 0
               and time.monotonic() < deadline):
            time.sleep(0.05)
        for k in range(1, 21):
            for publisher in publishers.values():
                publisher.publish(Int64(data=k))
        while len(probe.handled["spun"]) < 20 and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.2)  # the executor had every chance to take the polled ones too
        assert probe.handled == {"spun": list(range(1, 21)), "polled": []}
        assert probe.take_polled() == 20 and probe.handled["polled"] == list(range(1, 21))
        assert probe.take_polled() == 0
        with pytest.raises(ValueError, match="best effort"):
            probe.add_input("reliable", "/lip_ros_test/reliable", Int64, 10.0, lambda msg: msg.data, RELIABLE,
                            polled=True)
    finally:
        executor.shutdown()
        driver.destroy_node()
        probe.destroy_node()
        rclpy.try_shutdown()


_SHALLOW = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)  # a queue of five messages


def test_messages_overwritten_in_an_input_queue_are_counted_on_diagnostics_and_logged(capfd) -> None:
    """One message taken on each input, then 30 published while the node takes none: it takes the last 5 (its
    queue), so the 25 before were published and never taken, overwritten in the queue (they all arrived: DDS lost
    none; the node is not spun here, so no loss event of DDS is handled either). Each input's /diagnostics status
    counts them (values and message: the polled one cannot tell a loss in transport from an overwrite, its QoS
    events unhandled) and a WARN says so. A publisher started again numbers its messages from 1 again: not a
    gap."""
    rclpy.init()
    probe = _PolledProbe("/lip_ros_test/not_taken_{}", _SHALLOW)
    driver = rclpy.create_node("lip_ros_test_not_taken_driver")
    publishers = {name: driver.create_publisher(Int64, f"/lip_ros_test/not_taken_{name}", _SHALLOW)
                  for name in probe.handled}
    reports: list[DiagnosticArray] = []
    driver.create_subscription(DiagnosticArray, "/diagnostics", reports.append, RELIABLE)

    def statuses(deadline: float) -> dict[str, object]:
        reports.clear()
        probe._on_diagnostics_timer()  # a report now (the timer's call)
        while time.monotonic() < deadline:
            rclpy.spin_once(driver, timeout_sec=0.05)
            mine = [s for r in reports for s in r.status if s.name.startswith(probe.NAME + ": ")]
            if mine:
                return {s.name.split(": ")[1]: s for s in mine}
        raise AssertionError("no report of the probe on /diagnostics")

    try:
        deadline = time.monotonic() + 20.0
        while (min(p.get_subscription_count() for p in publishers.values()) == 0
               or driver.count_publishers("/diagnostics") == 0) and time.monotonic() < deadline:
            time.sleep(0.05)
        for k in range(31):  # the first taken alone: the count starts from it
            for publisher in publishers.values():
                publisher.publish(Int64(data=k))
            while k == 0 and not (probe.handled["spun"] and probe.handled["polled"]) and time.monotonic() < deadline:
                time.sleep(0.02)
                probe.take_waiting("spun")
                probe.take_polled()
        time.sleep(0.3)
        assert probe.take_waiting("spun") == 5 and probe.take_polled() == 5
        assert probe.handled == {"spun": [0, *range(26, 31)], "polled": [0, *range(26, 31)]}
        capfd.readouterr()
        status = statuses(deadline)
        values = {name: {v.key: v.value for v in s.values} for name, s in status.items()}
        assert values["spun"][NOT_TAKEN_VALUE] == values["polled"][NOT_TAKEN_VALUE] == "25"
        assert ("25 published and not taken (0 lost in transport, 25 overwritten in the input's queue)"
                in status["spun"].message)
        assert ("25 published and not taken (lost in transport or overwritten in the input's queue)"
                in status["polled"].message)
        log = capfd.readouterr().err
        assert ("published and never taken since the last report: spun (/lip_ros_test/not_taken_spun) 25 (since "
                "start 25: 0 lost in transport, 25 overwritten in the input's queue), polled "
                "(/lip_ros_test/not_taken_polled) 25 (since start 25: lost in transport or overwritten in the input's "
                "queue)") in log
        driver.destroy_publisher(publishers["spun"])  # started again: its numbers from 1
        again = driver.create_publisher(Int64, "/lip_ros_test/not_taken_spun", _SHALLOW)
        while again.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        for k in range(1, 4):
            again.publish(Int64(data=k))
        time.sleep(0.3)
        assert probe.take_waiting("spun") == 3 and probe.handled["spun"][-3:] == [1, 2, 3]
        status = statuses(deadline)
        assert {v.key: v.value for v in status["spun"].values}[NOT_TAKEN_VALUE] == "25"
        assert "published and never taken" not in capfd.readouterr().err
    finally:
        driver.destroy_node()
        probe.destroy_node()
        rclpy.try_shutdown()


_BETWEEN = "/lip_ros_test/between"


class _Sender(GraphNode):
    """A graph node with one output to the graph's other nodes."""

    NAME = "lip_ros_test_sender"
    PARAMS_FILE = LIP_PARAMS_FILE

    def __init__(self, **kwargs) -> None:
        super().__init__(self.NAME, **kwargs)
        self.out = self.create_between_publisher(Int64, _BETWEEN)


class _Receiver(GraphNode):
    """A graph node with that output as its input; it records, per message, the thread it ran on and whether its
    lock was held (another thread could not take it)."""

    NAME = "pose_node"  # its section of the parameter file has the default of direct_inputs
    PARAMS_FILE = LIP_PARAMS_FILE
    PARAMS = {"direct_inputs": DIRECT_INPUTS_PARAM}

    def __init__(self, name: str, **kwargs) -> None:
        super().__init__(name, **kwargs)
        self.handled: list[tuple[int, int, bool]] = []
        self.add_input("between", _BETWEEN, Int64, 10.0, self._on_message, from_graph=True)

    def _on_message(self, msg: Int64) -> int:
        free: list[bool] = []
        probe = threading.Thread(target=lambda: free.append(self.serial.acquire(blocking=False)))
        probe.start()
        probe.join()
        if free[0]:
            self.serial.release()
        self.handled.append((msg.data, threading.get_ident(), not free[0]))
        return msg.data


def test_nodes_of_one_process_hand_their_messages_over_directly() -> None:
    """With ``local_topics`` (a composed graph) a message published to the graph's other nodes reaches those of the
    process that take their inputs directly within ``publish``, on the publishing thread, holding the receiver's
    lock, counted by its input's monitor, with no executor spinning; it still goes over DDS, to a node of the
    process with ``direct_inputs`` false, to one that was not composed (no ``local_topics``) and to any other
    subscriber, each on its executor's thread."""
    rclpy.init()
    topics = LocalTopics()
    sender = _Sender(local_topics=topics)
    direct = _Receiver("lip_ros_test_receiver_direct", local_topics=topics)
    through_dds = _Receiver("lip_ros_test_receiver_dds", local_topics=topics,
                            parameter_overrides=[Parameter("direct_inputs", value=False)])
    alone = _Receiver("lip_ros_test_receiver_alone")
    outside = rclpy.create_node("lip_ros_test_between_outside")
    seen: list[int] = []
    outside.create_subscription(Int64, _BETWEEN, lambda msg: seen.append(msg.data), BETWEEN_NODES)
    executor = SingleThreadedExecutor()
    for node in (through_dds, alone, outside):
        executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        deadline = time.monotonic() + 10.0
        while sender.count_subscribers(_BETWEEN) < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
        for k in (1, 2):
            sender.out.publish(Int64(data=k))
            assert direct.handled[-1] == (k, threading.get_ident(), True)
        while (len(seen) < 2 or len(alone.handled) < 2 or len(through_dds.handled) < 2) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert seen == [1, 2]
        for receiver in (through_dds, alone):
            assert [m for m, _, _ in receiver.handled] == [1, 2]
            assert all(t == spinner.ident and held for _, t, held in receiver.handled)
        assert len(direct.handled) == 2  # not again through DDS
        assert direct._inputs["between"][2].report(direct.now_ns() * 1e-9).accepted == 2
    finally:
        executor.shutdown()
        for node in (outside, alone, through_dds, direct, sender):
            node.destroy_node()
        rclpy.try_shutdown()


def test_a_frame_completes_within_the_publication_of_its_last_part() -> None:
    """A node made later (downstream) that joins a message with what an earlier node makes of it gets the message
    first: when the earlier node publishes its part, the frame completes there, before that node's further work
    (calibration_node scores the DOT latency after publishing the bones; before, pose_node waited for it)."""
    topics, events = LocalTopics(), []
    joined: dict[str, int] = {}

    def calibration(points: int) -> None:  # subscribed first: the graph's nodes are made in the data's order
        topics.deliver("/bones", points)
        events.append("calibration: after-work")

    def pose(part: str, value: int) -> None:
        joined[part] = value
        if len(joined) == 2:
            events.append("pose: published")

    topics.subscribe("/points", calibration)
    topics.subscribe("/points", lambda m: pose("points", m))
    topics.subscribe("/bones", lambda m: pose("bones", m))
    topics.deliver("/points", 7)
    assert events == ["pose: published", "calibration: after-work"]
