"""What every node of lip_ros shares: validated parameters, monitored inputs, frame accounting, diagnostics,
``main``.

Parameters: each node lists its parameters (:class:`Param`: description and
check); their defaults come from its branch's shipped parameter file
(``PARAMS_FILE``, e.g. ``params/lip.yaml``: ``ros__parameters`` of the node's
section and of ``/**``), the single source of defaults. ``--ros-args --params-file FILE`` and
``-p name:=value`` override them; every value is checked at start-up, and a bad or unknown one stops the
executable with one clear line and exit status 2.

Diagnostics (``/diagnostics``, every ``diagnostics_period_s`` of steady time):
one status per monitored input (rate, age, rejections) and one
``<node>: frames`` status. Its values named ``frames <what>`` count LiDAR
frames that ended in this node (skipped with the reason, calibrating, pose),
so that summed over the graph's nodes every input frame is counted exactly
once; other values (pending, latency) are named otherwise. The log says when a
sensor input falls silent (no valid message for ``stale_after_s``: WARN) and
when it comes back (INFO, with how long it was silent), and once for each that
has received nothing :data:`NO_MESSAGE_LOG_S` after the node started (WARN).
"""

from __future__ import annotations

import contextlib
import functools
import gc
import math
import re
import sys
import threading
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.callback_groups import CallbackGroup, MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import QoSMessageLostInfo, SubscriptionEventCallbacks, UnsupportedEventTypeError
from rclpy.exceptions import InvalidHandle, InvalidParameterTypeException, ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from rclpy.subscription import Subscription
from sensor_msgs.msg import Imu

from lip_msgs_py import (
    DiagnosticLevel,
    ImuSample,
    MalformedMessageError,
    RclpyBackend,
    diagnostic_array_to_msg,
    diagnostic_status_to_msg,
    msg_to_imu,
    rclpy_message_class,
)
from lip_msgs_py.cdr import imu_samples
from lip_ros.core.clock import SteppingClock
from lip_ros.core.delivery import DeliveryGaps, not_taken_how
from lip_ros.core.sensor_monitor import SensorMonitor
from lip_ros.middleware import keep_message_buffers, use_lip_dds_profile
from lip_ros.resources import params_path
from lip_ros.signals import stop_on_signals

__all__ = ["ParameterError", "TopicTypeError", "Param", "positive", "non_negative", "numbers", "GraphNode",
           "LatencyWindow", "RELIABLE", "BETWEEN_NODES", "IMU_INPUT", "SUIT_QUEUE_S", "suit_input",
           "LATCHED", "POLL_PERIOD_S", "node_defaults", "check_params_files", "run_nodes", "FrameArrivals",
           "LocalTopics", "BetweenNodesPublisher", "DIRECT_INPUTS_PARAM", "tf_publisher", "rejection_reason",
           "read_imu", "SKIPPED", "subscribe_counting_losses", "NOT_TAKEN_VALUE", "LOST_IN_TRANSPORT_VALUE", "UNKNOWN"]

#: How ``GraphNode.count_frame`` names a frame that ended without a pose.
SKIPPED = "skipped"
#: QoS of the graph's outputs.
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
#: Reliable and transient local: a late subscriber gets the last message (a state, not a stream).
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: QoS of the topics between the graph's nodes: reliable, and deep enough that a busy node loses nothing.
BETWEEN_NODES = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
#: SensorDataQoS (best effort) for the 60 Hz IMUs, with room for the samples that arrive while a frame is processed.
IMU_INPUT = QoSProfile(depth=50, reliability=qos_profile_sensor_data.reliability,
                       durability=qos_profile_sensor_data.durability, history=qos_profile_sensor_data.history)
#: An input's /diagnostics values: its messages published and never taken since start, and of them those DDS said
#: were lost in transport (:class:`lip_ros.core.delivery.DeliveryGaps`; the rest were overwritten in its queue);
#: UNKNOWN until a numbered message was taken (none yet; a middleware that does not number them).
NOT_TAKEN_VALUE = "not_taken"
LOST_IN_TRANSPORT_VALUE = "not_taken_lost_in_transport"
UNKNOWN = "unknown"
#: seconds (steady time) after a node's start at which each input that has received nothing yet is logged, once
NO_MESSAGE_LOG_S = 10.0
#: how often a node takes the messages of its polled inputs (:meth:`GraphNode.add_input`, ``polled``) and looks at
#: what waits on them, seconds (steady time)
POLL_PERIOD_S = 0.02
#: seconds of the HSC4D suit's topics a subscription holds, for a node's longest callback (the trajectory node
#: registering sweeps while the rest of its process wants the interpreter; the body node optimising a window:
#: about a second measured for the first, more under load)
SUIT_QUEUE_S = 5.0


def suit_input(rate_hz: float) -> QoSProfile:
    """SensorDataQoS for a suit topic of ``rate_hz``, :data:`SUIT_QUEUE_S` deep."""
    return QoSProfile(depth=int(np.ceil(SUIT_QUEUE_S * rate_hz)), reliability=IMU_INPUT.reliability,
                      durability=IMU_INPUT.durability, history=IMU_INPUT.history)


class _NotWaitedOn(CallbackGroup):
    """The group of the polled inputs: an executor leaves its entities out of its wait set (their node takes
    their messages itself). Their QoS event handlers go with them: a polled input is best effort, which matches
    any publisher's reliability."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        pass


_NOT_WAITED_ON = _NotWaitedOn()


class ParameterError(ValueError):
    """A parameter value (or parameter file) a node cannot run with."""


class TopicTypeError(RuntimeError):
    """An input topic is published with another message type than the node reads."""


@dataclass(frozen=True)
class Param:
    """A node parameter: what it means and, optionally, what makes a value wrong (a message, or None if fine)."""

    description: str
    check: Callable[[Any], str | None] | None = None
    any_type: bool = False  # e.g. a list whose default is empty ([] = none) and that a list of numbers overrides


def positive(value: Any) -> str | None:
    """Check: a number > 0."""
    return None if value > 0 else f"must be > 0, got {value}"


def non_negative(value: Any) -> str | None:
    """Check: a number >= 0."""
    return None if value >= 0 else f"must be >= 0, got {value}"


def numbers(*lengths: int) -> Callable[[Any], str | None]:
    """Check: a list of finite numbers of one of these lengths."""

    def check(value: Any) -> str | None:
        ok = (isinstance(value, (list, tuple)) and len(value) in lengths
              and all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in value))
        return None if ok else f"must be a list of {' or '.join(map(str, lengths))} finite numbers, got {value!r}"

    return check


def node_defaults(params_file: str, node_name: str) -> dict[str, Any]:
    """The shipped defaults of a node: ``/**`` then the node's own section of ``params/<params_file>``."""
    doc = yaml.safe_load(params_path(params_file).read_text(encoding="utf-8")) or {}
    out: dict[str, Any] = {}
    for section in ("/**", node_name):
        out.update((doc.get(section) or {}).get("ros__parameters") or {})
    return out


def _params_files(argv: Sequence[str]) -> list[Path]:
    files, ros = [], False
    for i, arg in enumerate(argv):
        if arg == "--ros-args":
            ros = True
        elif arg == "--" and ros:
            ros = False
        elif ros and arg == "--params-file" and i + 1 < len(argv):
            files.append(Path(argv[i + 1]))
    return files


def check_params_files(argv: Sequence[str], known: dict[str, set[str]]) -> None:
    """Raise :class:`ParameterError` if a ``--params-file`` of ``argv`` is unreadable or sets a parameter that
    no node of this process has (``known``: node name -> parameter names); other nodes' sections are left alone."""
    every = set().union(*known.values()) | {"use_sim_time"}
    for path in _params_files(argv):
        try:
            doc = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        except (OSError, yaml.YAMLError) as exc:
            raise ParameterError(f"cannot read parameter file {path}: {exc}") from exc
        for section, body in doc.items():
            names = every if section in ("/**", "**") else known.get(str(section).lstrip("/"))
            if names is None:
                continue
            unknown = set((body or {}).get("ros__parameters") or {}) - names - {"use_sim_time"}
            if unknown:
                raise ParameterError(f"{path}: unknown parameter(s) {', '.join(sorted(unknown))} for {section} "
                                     f"(known: {', '.join(sorted(names))})")


class LatencyWindow:
    """Latencies (ms): percentiles over every one added (a histogram of bins 0.5 % wide, so bounded over any run)
    and over the most recent ``size``."""

    #: bin edges of the whole run's histogram (ms): 0.01 ms to 1000 s, each 0.5 % wider than the last
    _EDGES = np.geomspace(1e-2, 1e6, int(np.ceil(np.log(1e8) / np.log(1.005))) + 1)

    def __init__(self, size: int = 1000) -> None:
        self._ms: deque[float] = deque(maxlen=size)
        self._counts = np.zeros(self._EDGES.size + 1, dtype=np.int64)  # [0]: below the first edge; [-1]: above
        self._max = 0.0
        self.count = 0  # latencies added in all

    def add(self, seconds: float) -> None:
        """One latency, in seconds."""
        ms = 1e3 * seconds
        self._ms.append(ms)
        self._counts[np.searchsorted(self._EDGES, ms, side="right")] += 1
        self._max = max(self._max, ms)
        self.count += 1

    def percentiles(self, q: Sequence[float]) -> list[float]:
        """The whole run's percentiles ``q`` (0-100), ms, each to 0.5 % (the geometric middle of its bin)."""
        cumulative = np.cumsum(self._counts)
        out = []
        for p in q:
            k = int(np.searchsorted(cumulative, max(p / 100.0 * self.count, 1.0)))
            if k >= self._EDGES.size:  # beyond the last edge
                out.append(self._max)
            else:
                out.append(min(float(np.sqrt(self._EDGES[max(k - 1, 0)] * self._EDGES[k])), self._max))
        return out

    def values(self, prefix: str) -> dict[str, str]:
        """Diagnostic values (ms): ``<prefix>_p50/_p90/_p99/_max`` over the whole run, ``<prefix>_recent_p50/_p99``
        over the most recent; empty without data."""
        if not self._ms:
            return {}
        p50, p90, p99 = self.percentiles([50, 90, 99])
        recent = np.percentile(np.array(self._ms), [50, 99])
        return {f"{prefix}_p50": f"{p50:.1f}", f"{prefix}_p90": f"{p90:.1f}", f"{prefix}_p99": f"{p99:.1f}",
                f"{prefix}_max": f"{self._max:.1f}", f"{prefix}_recent_p50": f"{recent[0]:.1f}",
                f"{prefix}_recent_p99": f"{recent[1]:.1f}"}


class FrameArrivals:
    """When each LiDAR frame arrived (steady seconds, by pose stamp), shared by the nodes of one process so that
    the last one can measure the graph's latency from cloud receipt to pose publication."""

    def __init__(self, size: int = 200) -> None:
        self._t: dict[int, float] = {}
        self._size = size
        self._lock = threading.Lock()

    def mark(self, pose_stamp_ns: int, seconds: float) -> None:
        """Frame ``pose_stamp_ns`` arrived at ``seconds``."""
        with self._lock:
            self._t[pose_stamp_ns] = seconds
            while len(self._t) > self._size:
                del self._t[next(iter(self._t))]

    def pop(self, pose_stamp_ns: int) -> float | None:
        """When that frame arrived (None if unknown, e.g. segmented in another process)."""
        with self._lock:
            return self._t.pop(pose_stamp_ns, None)


class LocalTopics:
    """The topics between the nodes of one process (a composed graph): a message published on one is handed to the
    process's own subscribers of it by a direct call, on the publishing thread, instead of through DDS and the
    subscriber's executor (whose wake-up cost 2-3 ms a hop in the LIP graph: docs/reliability.md "Latency against
    the transport floor"). Subscribers register while the nodes are made; the receiving node's callbacks are
    serialised by its own lock (:class:`GraphNode`)."""

    def __init__(self) -> None:
        self._receivers: dict[str, list[Callable[[Any], None]]] = {}

    def subscribe(self, topic: str, callback: Callable[[Any], None]) -> None:
        """Call ``callback`` with every message published on ``topic`` (a resolved name) in this process."""
        self._receivers.setdefault(topic, []).append(callback)

    def deliver(self, topic: str, msg: Any) -> None:
        """Hand ``msg`` to this process's subscribers of ``topic``, the last to subscribe first. A graph's nodes are
        made in the data's order, so a node that also waits for what an earlier one makes of the message (pose_node
        for the bones calibration_node makes of the performer's points) holds it when that comes: the frame
        completes within the earlier node's publication, before the rest of that node's work (the DOT latency's
        scoring)."""
        for callback in reversed(self._receivers.get(topic, ())):
            callback(msg)


class BetweenNodesPublisher:
    """A publisher of a topic between the graph's nodes (:data:`BETWEEN_NODES`): to the nodes of the same process
    directly (:class:`LocalTopics`), first, then over DDS for nodes of other processes, recorders and tools."""

    def __init__(self, node: Node, msg_type: type, topic: str, local: LocalTopics | None) -> None:
        self._publisher = node.create_publisher(msg_type, topic, BETWEEN_NODES)
        self._topic = self._publisher.topic_name
        self._local = local

    def publish(self, msg: Any) -> None:
        """Publish ``msg``."""
        if self._local is not None:
            self._local.deliver(self._topic, msg)
        self._publisher.publish(msg)


#: The parameter of a node whose inputs come from the graph's other nodes (``add_input(from_graph=True)``).
DIRECT_INPUTS_PARAM = Param("in fusion_node, take the other nodes' outputs by direct calls: a frame runs through the "
                            "stages on one thread, the lowest latency (false: through DDS, each stage on its own "
                            "thread, overlapping consecutive frames: more throughput for a bag played faster than "
                            "real time)")


class GraphNode(Node):
    """A node of a capture graph: subclasses set ``NAME``, ``PARAMS_FILE`` (their branch's file in ``params/``)
    and ``PARAMS``, and override :meth:`frame_status`."""

    NAME = ""
    PARAMS_FILE = ""

    #: Parameters every node has.
    COMMON_PARAMS = {
        "diagnostics_period_s": Param("period of /diagnostics (steady time)", positive),
        "stale_after_s": Param("an input with no message for this long is reported stale", positive),
        "lidar_rate_hz": Param("expected LiDAR frame rate", positive),
        "max_input_delay_s": Param("a sensor input whose messages arrive this much later than their stamps (a "
                                   "LiDAR: beyond its sweep time) is reported late", positive),
    }
    PARAMS: dict[str, Param] = {}

    def __init__(self, name: str, local_topics: LocalTopics | None = None, **kwargs: Any) -> None:
        #: Every callback of the node runs holding this (its stage objects are not thread-safe): its own
        #: executor's, and those other nodes of the process call directly (``local_topics``).
        self.serial = threading.RLock()
        super().__init__(name, **kwargs)
        self.local_topics = local_topics
        self.params = self._declare_parameters()
        self.backend = RclpyBackend()
        #: All of this node's callbacks in one group, so that no executor waits on :attr:`serial` with a thread.
        self.group = MutuallyExclusiveCallbackGroup()
        self.frames: Counter[str] = Counter()  # "frames <what>" of the diagnostics, without the prefix
        self._reported: Counter[str] = Counter()  # self.frames at the last report
        self._last_skip = ""  # why the latest skipped frame was skipped, in detail
        self._inputs: dict[str, tuple[str, type, SensorMonitor]] = {}
        self._takers: dict[str, tuple[Subscription, Callable[[Any, dict[str, Any] | None], None]]] = {}  # by input
        self._polled: list[str] = []  # the inputs no executor waits on (:meth:`take_polled`)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", RELIABLE)
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)  # also ticks while a bag's /clock is paused or over
        self._started_ns = self.steady.now().nanoseconds
        self._watched: list[str] = []  # the inputs whose silences are logged (add_input's ``watched``)
        self._waiting: set[str] = set()  # watched inputs logged as having received nothing since start
        self._not_taken_logged: dict[str, int] = {}  # by input: its messages not taken, as last logged
        self.create_timer(self.params["diagnostics_period_s"], self._on_diagnostics_timer, self.group,
                          clock=self.steady)

    def _serialised(self, callback: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(callback)  # its signature: rclpy hands a subscription's message info to a two-argument one
        def call(*args: Any) -> Any:
            with self.serial:
                return callback(*args)
        return call

    def create_subscription(self, msg_type: Any, topic: str, callback: Callable[..., Any], *args: Any,
                            **kwargs: Any) -> Subscription:
        """rclpy's, with the callback holding :attr:`serial`."""
        return super().create_subscription(msg_type, topic, self._serialised(callback), *args, **kwargs)

    def create_timer(self, timer_period_sec: float, callback: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """rclpy's, with the callback holding :attr:`serial`."""
        return super().create_timer(timer_period_sec, self._serialised(callback), *args, **kwargs)

    def create_service(self, srv_type: Any, srv_name: str, callback: Callable[..., Any], *args: Any,
                       **kwargs: Any) -> Any:
        """rclpy's, with the callback holding :attr:`serial`."""
        return super().create_service(srv_type, srv_name, self._serialised(callback), *args, **kwargs)

    def create_between_publisher(self, msg_type: type, topic: str) -> BetweenNodesPublisher:
        """A publisher to the graph's other nodes: directly to those of this process, over DDS to the others."""
        return BetweenNodesPublisher(self, msg_type, topic, self.local_topics)

    @classmethod
    def parameter_names(cls) -> set[str]:
        """Names of every parameter of this node."""
        return set(cls.COMMON_PARAMS) | set(cls.PARAMS)

    def _declare_parameters(self) -> dict[str, Any]:
        defaults = node_defaults(self.PARAMS_FILE, self.NAME)
        specs = {**self.COMMON_PARAMS, **self.PARAMS}
        missing = set(specs) - set(defaults)
        if missing:
            raise ParameterError(f"{params_path(self.PARAMS_FILE)} has no default for {', '.join(sorted(missing))}")
        values, problems = {}, []
        for name, spec in specs.items():
            try:
                value = self.declare_parameter(name, defaults[name], ParameterDescriptor(
                    description=spec.description, dynamic_typing=spec.any_type)).value
            except (InvalidParameterTypeException, ParameterException) as exc:
                problems.append(f"{name}: {exc}")
                continue
            problem = spec.check(value) if spec.check else None
            if problem:
                problems.append(f"{name} {problem}")
            values[name] = value
        if problems:
            raise ParameterError("; ".join(problems))
        return values

    def now_ns(self) -> int:
        """The node's clock (ROS time, or /clock with use_sim_time)."""
        return self.get_clock().now().nanoseconds

    def add_input(self, name: str, topic: str, msg_type: type, rate_hz: float, handle: Callable[[Any], int],
                  qos: QoSProfile = qos_profile_sensor_data, raw: bool = False, polled: bool = False,
                  stamped_at: float | None = None, count_missing: bool = False, from_graph: bool = False,
                  watched: bool | None = None) -> None:
        """Subscribe ``handle`` (returns the message stamp, raises MalformedMessageError to reject) with a
        monitor of the input's rate, age and rejections on /diagnostics; with ``raw`` it gets the message's CDR
        bytes (a fast input decoded later, in batches). A ``polled`` input is not waited on by the executor: the
        node takes its messages itself with :meth:`take_polled` (from a timer, or when it needs them), so that
        a fast input of small messages costs no executor wake-up each (the HSC4D body node's 17 suit IMUs at
        100 Hz: half its CPU went to rclpy rebuilding its wait set); its queue must hold what comes between two
        takes. ``stamped_at``: how long (s) a sensor's message normally takes from its stamp to its
        publication (0 for an IMU, a LiDAR's sweep time); with it, messages arriving ``max_input_delay_s`` later
        than that are reported late (None: not checked, e.g. an input from another node). ``count_missing``: the
        sensor stamps each message one period after the last (a LiDAR), so gaps in the stamps are lost messages.
        ``from_graph``: the input is another node's output (:meth:`create_between_publisher`, QoS
        :data:`BETWEEN_NODES`); in a composed graph (``local_topics``) of a node whose ``direct_inputs``
        (:data:`DIRECT_INPUTS_PARAM`) is true it is handed over by a direct call. ``watched``: the log says
        when the input falls silent and comes back (:meth:`_log_silences`; default: unless ``from_graph``, whose
        silence follows that of the other node's inputs, or that node's own choice not to publish). An input over
        DDS counts the messages published and never taken from the publisher's sequence numbers, and those DDS
        says were lost in transport (not for a ``polled`` input, whose QoS events no executor handles):
        :class:`lip_ros.core.delivery.DeliveryGaps`, on /diagnostics and in the log (:meth:`_log_not_taken`)."""
        max_delay = None if stamped_at is None else stamped_at + self.params["max_input_delay_s"]
        monitor = SensorMonitor(name, expected_rate_hz=rate_hz, stale_after_s=self.params["stale_after_s"],
                                max_delay_s=max_delay, count_missing=count_missing)
        self._inputs[name] = (topic, msg_type, monitor)
        if (not from_graph) if watched is None else watched:
            self._watched.append(name)

        def callback(msg: Any, info: dict[str, Any] | None) -> None:
            now = self.now_ns() * 1e-9
            if info is not None:  # over DDS: the publishers matched, asked only at a gap
                monitor.delivery.taken(now, info.get("publication_sequence_number"),
                                       self._takers[name][0].get_publisher_count)
            try:
                monitor.accept(now, handle(msg))
            except MalformedMessageError as exc:
                monitor.reject(now, rejection_reason(exc))
                self.get_logger().warning(f"{name} ({topic}): message skipped: {exc}", throttle_duration_sec=5.0)

        qos = BETWEEN_NODES if from_graph else qos
        if polled and qos.reliability != ReliabilityPolicy.BEST_EFFORT:
            raise ValueError(f"polled input {name} must be best effort (no QoS event of it is handled)")
        if from_graph and self.local_topics is not None and self.params.get("direct_inputs", False):
            self.local_topics.subscribe(self.resolve_topic_name(topic),
                                        self._serialised(lambda msg: callback(msg, None)))
            return
        if polled:  # in a group no executor waits on: no QoS event of it would be handled
            monitor.delivery.loss_events = False
            subscription = self.create_subscription(msg_type, topic, callback, qos, callback_group=_NOT_WAITED_ON,
                                                    raw=raw)
        else:
            subscription = subscribe_counting_losses(self, msg_type, topic, callback, qos, monitor.delivery,
                                                     lambda: self.now_ns() * 1e-9, self.serial,
                                                     callback_group=self.group, raw=raw)
        self._takers[name] = (subscription, callback)
        if polled:
            self._polled.append(name)

    def on_time_line(self, clock: SteppingClock, stream: str, stamp_ns: int, confirm: bool = True) -> int:
        """``stream``'s stamp on ``clock``'s time line across its steps back (:meth:`SteppingClock.internal`); a
        step is logged; MalformedMessageError for a stamp the clock refuses (far behind and not confirmed as a step
        yet; of the capture before a new one began)."""
        steps = len(clock.steps_ns)
        line_ns = clock.internal(stream, stamp_ns, confirm)
        if line_ns is None:
            raise MalformedMessageError(clock.refused)
        if len(clock.steps_ns) > steps:
            self.get_logger().warning(f"{stream}: its clock stepped back {clock.steps_ns[-1] * 1e-9:.3f} s: going "
                                      "on, its stamps moved on by the step")
        return line_ns

    def input_rate_hz(self, name: str) -> float:
        """Input ``name``'s rate as its stamps show it (:attr:`SensorMonitor.measured_rate_hz`): a sensor stamping each
        period; its expected rate until known."""
        return self._inputs[name][2].measured_rate_hz

    def input_delay_s(self, name: str) -> float | None:
        """Input ``name``'s recent median of receive time less stamp (:meth:`SensorMonitor.delay_s`)."""
        return self._inputs[name][2].delay_s()

    def take_polled(self) -> int:
        """Handle every message received on the polled inputs (:meth:`add_input`); how many."""
        return sum(self.take_waiting(name) for name in self._polled)

    def take_waiting(self, name: str) -> int:
        """Handle every message of input ``name`` received and not yet taken; how many. rclpy's executor takes
        one message per subscription per wait, so while a long callback (a sweep's registration) comes round on
        every wait a fast input falls behind it until its queue overflows; the long callback calls this first."""
        subscription, callback = self._takers[name]
        taken = 0
        while True:
            try:
                with subscription.handle:
                    message = subscription.handle.take_message(subscription.msg_type, subscription.raw)
            except InvalidHandle:  # destroyed at shutdown
                return taken
            if message is None:
                return taken
            callback(*message)
            taken += 1

    def count_frame(self, what: str, detail: str = "") -> None:
        """Account for a LiDAR frame that ends here (``frames <what>`` on /diagnostics; ``what`` starts with
        :data:`SKIPPED` for a frame without a pose: the status is a WARN in the report after); log why."""
        self.frames[what] += 1
        if what.startswith(SKIPPED) and detail:
            self._last_skip = detail
        if detail:
            self.get_logger().info(f"frame {what}: {detail}", throttle_duration_sec=2.0)

    def frame_status(self) -> tuple[DiagnosticLevel, str, dict[str, Any]]:
        """Level, message and extra values of the ``<node>: frames`` status."""
        return DiagnosticLevel.OK, "", {}

    def _check_topic_types(self) -> None:
        """Raise :class:`TopicTypeError` if an input topic has a publisher of another type than ours."""
        for name, (topic, msg_type, _) in self._inputs.items():
            want = f"{msg_type.__module__.split('.')[0]}/msg/{msg_type.__name__}"
            other = {i.topic_type for i in self.get_publishers_info_by_topic(self.resolve_topic_name(topic))} - {want}
            if other:
                raise TopicTypeError(f"{name} input {self.resolve_topic_name(topic)} is published as "
                                     f"{', '.join(sorted(other))}; this node reads {want} (remap the input to the "
                                     f"right topic)")

    def _on_diagnostics_timer(self) -> None:
        self._check_topic_types()
        now = self.now_ns()
        statuses = []
        self.take_polled()  # what waits in the polled inputs' queues is not a silence
        self._log_silences(now * 1e-9)
        self._log_not_taken()
        for name, (topic, _, monitor) in self._inputs.items():
            r = monitor.report(now * 1e-9)
            values = {"rate_hz": f"{r.rate_hz:.2f}", "received": r.received, "accepted": r.accepted,
                      "out_of_order": r.out_of_order, "clock_steps": r.clock_steps, "missing": r.missing,
                      "age_s": "none" if r.age_s is None else f"{r.age_s:.3f}",
                      "delay_ms": "none" if r.delay_s is None else f"{1e3 * r.delay_s:.1f}"}
            if name in self._takers:  # over DDS (not handed over by a direct call)
                values |= {NOT_TAKEN_VALUE: UNKNOWN if r.not_taken is None else r.not_taken,
                           LOST_IN_TRANSPORT_VALUE: UNKNOWN if r.lost_in_transport is None else r.lost_in_transport}
            values.update({f"rejected: {k}": v for k, v in r.rejected.items()})
            statuses.append(diagnostic_status_to_msg(self.backend, int(r.health), f"{self.get_name()}: {r.name}",
                                                     r.message, hardware_id=topic, values=values))
        level, message, extra = self.frame_status()
        skipped = {k: v - self._reported[k] for k, v in self.frames.items()
                   if k.startswith(SKIPPED) and v > self._reported[k]}
        self._reported = Counter(self.frames)
        if skipped:  # a fault shorter than the report period is still seen on /diagnostics
            level = max(level, DiagnosticLevel.WARN)
            last = f" (the last: {self._last_skip[:160]})" if self._last_skip else ""
            message = "; ".join(filter(None, [message, "since the last report " + ", ".join(
                f"{k} x{v}" for k, v in sorted(skipped.items())) + last]))
        values = {**{f"frames {k}": v for k, v in sorted(self.frames.items())}, **extra}
        statuses.append(diagnostic_status_to_msg(self.backend, int(level), f"{self.get_name()}: frames", message,
                                                 values=values))
        self._diag_pub.publish(diagnostic_array_to_msg(self.backend, now, statuses))

    def _log_silences(self, now_s: float) -> None:
        """Log the watched inputs (:meth:`add_input`) that fell silent (WARN), were silent between two reports
        (WARN) or came back (INFO) since the last report; once each that has received nothing
        :data:`NO_MESSAGE_LOG_S` after the node started (WARN), and its first message after that (INFO)."""
        said: dict[str, list[str]] = {"silent": [], "was_silent": [], "back": [], "waiting": [], "first": []}
        waited_s = (self.steady.now().nanoseconds - self._started_ns) * 1e-9
        for name in self._watched:
            topic, _, monitor = self._inputs[name]
            change = monitor.silence_change(now_s)
            if change is not None:
                seconds = "(across a reset of the clock)" if math.isnan(change.seconds) else f"{change.seconds:.1f} s"
                said[change.kind].append(f"{name} ({topic}) {seconds}")
            if monitor.received == 0 and waited_s > NO_MESSAGE_LOG_S and name not in self._waiting:
                self._waiting.add(name)
                said["waiting"].append(f"{name} ({topic})")
            elif monitor.received and name in self._waiting:
                self._waiting.discard(name)
                said["first"].append(f"{name} ({topic})")
        log = self.get_logger()
        if said["silent"]:
            log.warning("no valid message for: " + ", ".join(said["silent"]))
        if said["was_silent"]:
            log.warning("silent since the last report for: " + ", ".join(said["was_silent"]))
        if said["back"]:
            log.info("receiving again after a silence of: " + ", ".join(said["back"]))
        if said["waiting"]:
            log.warning(f"no message in the {waited_s:.0f} s since start on: {', '.join(said['waiting'])} (its "
                        "publisher not running, or not reachable over DDS)")
        if said["first"]:
            log.info(f"first message, {waited_s:.0f} s after start, on: " + ", ".join(said["first"]))

    def _log_not_taken(self) -> None:
        """Log (WARN) the inputs with messages published and never taken since the last report (:meth:`add_input`):
        how many, and since start how many, of them how many DDS said were lost in transport and how many were
        overwritten in the input's queue (since start: a loss DDS reports after its gap was seen moves one from
        the second to the first)."""
        said = []
        for name in self._takers:
            topic, _, monitor = self._inputs[name]
            total = monitor.delivery.total
            new = total.not_taken - self._not_taken_logged.get(name, 0)
            if not new:
                continue
            self._not_taken_logged[name] = total.not_taken
            how = not_taken_how(total, monitor.delivery.loss_events)
            said.append(f"{name} ({topic}) {new} (since start {total.not_taken}: {how})")
        if said:
            self.get_logger().warning("published and never taken since the last report: " + ", ".join(said))


def subscribe_counting_losses(node: Node, msg_type: Any, topic: str, callback: Callable[..., Any], qos: QoSProfile,
                              gaps: DeliveryGaps, now_s: Callable[[], float],
                              lock: contextlib.AbstractContextManager[Any] | None = None,
                              **kwargs: Any) -> Subscription:
    """``node.create_subscription`` whose DDS loss events (rclpy's ``message_lost``) go to ``gaps`` at ``now_s()``,
    holding ``lock`` (a graph node's :attr:`GraphNode.serial`); with an rmw that has no such event, without it
    (``gaps.loss_events`` false: what is not taken is not told apart)."""
    lock = lock or contextlib.nullcontext()

    def lost(status: QoSMessageLostInfo) -> None:
        with lock:
            gaps.lost_in_transport(now_s(), status.total_count_change)

    gaps.loss_events = True
    try:
        return node.create_subscription(msg_type, topic, callback, qos,
                                        event_callbacks=SubscriptionEventCallbacks(message_lost=lost), **kwargs)
    except UnsupportedEventTypeError:
        gaps.loss_events = False
        return node.create_subscription(msg_type, topic, callback, qos, **kwargs)


def read_imu(data: bytes) -> ImuSample:
    """The sample of a sensor_msgs/Imu's CDR bytes: read in place (:func:`lip_msgs_py.cdr.imu_samples`), or where
    that leaves it (not plain little-endian CDR, a value it would refuse) deserialised and read in full;
    MalformedMessageError if it cannot be read."""
    sample = imu_samples([data])[0]
    if sample is not None:
        return sample
    try:
        return msg_to_imu(deserialize_message(data, Imu))
    except RuntimeError as exc:
        raise MalformedMessageError(f"Imu CDR: {exc}") from exc


def rejection_reason(exc: Exception) -> str:
    """A message's rejection as a short reason to count it under: its error with numbers (and lists of them) as N
    (so that one kind of fault is one reason, however its values vary)."""
    numbers = re.sub(r"(?<![\w.])-?\d+(\.\d+)?(e-?\d+)?", "N", str(exc))
    return re.sub(r"\[[\[\]N, ]*\]", "[N]", numbers)[:80]


def tf_publisher(node: Node) -> Any:
    """A /tf publisher of ``node``, or None (said once in its log) where tf2_msgs is not installed (no wheel)."""
    try:
        tf_type = rclpy_message_class("tf2_msgs/msg/TFMessage")
    except KeyError:
        node.get_logger().info("tf2_msgs is not installed: nothing is broadcast on /tf")
        return None
    return node.create_publisher(tf_type, "/tf", RELIABLE)


def _spin_each(nodes: Sequence[Node], stop: threading.Event) -> list[BaseException]:
    """Spin every node on its own single-threaded executor in its own thread until ``stop`` is set (a signal) or
    one of them ends (a node failed, or the context was shut down); then shut the context down, which ends every
    spin, and wait for the threads. The exceptions the nodes raised."""
    errors: list[BaseException] = []

    def spin(node: Node) -> None:
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            executor.spin()
        except ExternalShutdownException:
            pass
        except RuntimeError as exc:
            # a shutdown while spin_once builds its wait set makes rclpy raise RCLError ("the given context is not
            # valid") rather than ExternalShutdownException: a shutdown
            if executor.context.ok():
                errors.append(exc)
        except BaseException as exc:  # noqa: BLE001  (reported by the main thread)
            errors.append(exc)
        finally:
            executor.shutdown()

    threads = [threading.Thread(target=spin, args=(n,), name=n.get_name(), daemon=True) for n in nodes]
    for t in threads:
        t.start()
    while not stop.wait(0.1) and all(t.is_alive() for t in threads):
        pass
    rclpy.try_shutdown()  # from this thread, not from a signal handler's: rclpy's own aborted the process at exit
    for t in threads:
        t.join()
    return errors


def run_nodes(prog: str, description: str, factories: Sequence[Callable[[], GraphNode]],
              classes: Sequence[type[GraphNode]], argv: list[str] | None = None) -> int:
    """``main`` of an executable: parse, check parameter files, create the nodes and spin them, each on its own
    thread; parameter and topic type errors end it with one line on stderr and exit status 2.

    One single-threaded executor per node (its callbacks one at a time, the
    nodes in parallel) rather than rclpy's ``MultiThreadedExecutor``, which
    measured here spent 12.9 ms of CPU per IMU message against 0.8 ms and
    so lost most IMU samples at 4 x 60 Hz (docs/lip/graph.md). SIGINT and
    SIGTERM set an event that the main thread waits on; it then shuts the
    context down and joins the threads before the nodes are destroyed: with
    rclpy's own signal handlers a node spinning in a thread made the process
    abort at exit (``terminate called without an active exception``) in most
    stops while another process was subscribed to it.
    """
    import argparse

    argv = sys.argv if argv is None else argv
    parser = argparse.ArgumentParser(prog=prog, description=description,
                                     epilog="ROS arguments go after --ros-args (remapping, -p name:=value, "
                                            "--params-file FILE, -p use_sim_time:=true).")
    parser.parse_args(rclpy.utilities.remove_ros_args(argv)[1:])
    keep_message_buffers()
    stop = stop_on_signals()
    use_lip_dds_profile()
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    nodes: list[GraphNode] = []
    try:
        check_params_files(argv, {c.NAME: c.parameter_names() for c in classes})
        for make in factories:
            nodes.append(make())
    except ParameterError as exc:
        print(f"{prog}: parameter error: {exc}", file=sys.stderr)
        _shutdown(nodes)
        return 2
    gc.freeze()  # the models and messages types loaded so far are never garbage: keep the collector off them
    sys.setswitchinterval(0.001)  # the threads of a graph take turns on the GIL within a millisecond, not five
    try:
        errors = _spin_each(nodes, stop)
    finally:
        _shutdown(nodes)
    for exc in errors:
        if isinstance(exc, TopicTypeError):
            print(f"{prog}: {exc}", file=sys.stderr)
            return 2
        raise exc
    return 0


def _shutdown(nodes: Sequence[Node]) -> None:
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown()
