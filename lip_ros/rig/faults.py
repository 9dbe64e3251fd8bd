"""Faulty captures: a bag rewritten with sensor faults in given windows, deterministically (ROS-free).

What a real rig does to a graph: sensors that go silent, drop frames or send
garbage, clocks that step, messages that arrive late or out of order. Each
:class:`FaultSpec` names one fault kind (:data:`FAULT_KINDS`) and its window
on the bag's receive (log) time, from the first message. The sensors are found
by type, so LIP and HSC4D bags are treated alike: every ``sensor_msgs/Imu``
topic outside ``/gt/`` is an IMU (sorted by name; a fault of one IMU hits the
first of them unless it names another), every ``sensor_msgs/PointCloud2``
outside ``/gt/`` a LiDAR.

:func:`write_faulty_bag` writes the new bag, copies the rig's truth sidecars
and writes ``faults.yaml`` beside them: each fault's window on the sensors'
own clock (header stamps, as the graph's outputs and diagnostics are stamped),
so that a test or a user can tell the outputs inside a fault from those after
it.
"""

from __future__ import annotations

import heapq
import shutil
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from lip_msgs_py import RosbagsBackend
from lip_ros.bagio import RawMessage, bag_span, bag_topics, mcap_writer, read_raw

__all__ = ["FAULT_KINDS", "ONE_IMU_FAULTS", "FaultSpec", "FaultWindow", "FAULTS_FILE", "write_faulty_bag",
           "read_fault_windows"]

#: The sidecar that says where the faults are.
FAULTS_FILE = "faults.yaml"

#: Fault kinds and what each does inside its window.
FAULT_KINDS = {
    "imu_silent": "one IMU (the first, or the one named) sends nothing",
    "imus_silent": "no IMU sends anything",
    "all_silent": "no sensor sends anything (from the start: a capture without its calibration poses)",
    "lidar_gap": "no LiDAR frame arrives",
    "lidar_drops": "one LiDAR frame in ten is lost (seeded)",
    "bad_imu_samples": "one IMU sample in three is bad, in turn: NaN orientation, Inf acceleration, zero "
                       "quaternion, NaN rate",
    "imu_reordered": "each IMU's messages arrive swapped in pairs, and one in five twice",
    "imu_ahead": "one IMU (the first, or the one named) stamps its samples 40 ms ahead of the others",
    "imu_late": "every IMU sample arrives 300 ms late",
    "malformed_clouds": "LiDAR frames malformed, in turn: point_step shorter than the fields, data truncated, no "
                        "x field, row_step not matching the data, a field of an unknown datatype",
    "blinded_clouds": "LiDAR frames with every pixel a no-return (all zero)",
    "empty_clouds": "LiDAR frames of 0 x 0 points",
    "clock_back": "from the window's start every sensor's stamps jump 5 s back (a PTP step; receive times go on)",
    "clock_forward": "from the window's start every sensor's stamps jump 5 s forward",
    "played_again": "at the window's start the capture starts again from its beginning, with its own stamps and "
                    "the truth's (a bag played in a loop, a replay restarted), and plays for the window's length; "
                    "the bag ends with it",
}

#: The kinds that hit one IMU (``FaultSpec.imu``).
ONE_IMU_FAULTS = ("imu_silent", "imu_ahead")

_IMU = "sensor_msgs/msg/Imu"
_CLOUD = "sensor_msgs/msg/PointCloud2"
_CLOCK_STEP_NS = 5_000_000_000
_AHEAD_NS = 40_000_000
_LATE_NS = 300_000_000
_REORDER_NS = 1_000  # a message held back arrives this much after the one that followed it
_MAX_DELAY_NS = _LATE_NS + 1_000_000_000  # no message is logged later than this after its place in the input


@dataclass(frozen=True)
class FaultSpec:
    """A fault ``kind`` (:data:`FAULT_KINDS`) from ``start_s`` for ``duration_s`` of the bag's receive time; ``imu``:
    the IMU topic a fault of one IMU (:data:`ONE_IMU_FAULTS`) hits (None: the first by name)."""

    kind: str
    start_s: float
    duration_s: float
    imu: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault {self.kind!r}; known: {', '.join(FAULT_KINDS)}")
        if self.start_s < 0 or self.duration_s <= 0:
            raise ValueError(f"fault {self.kind}: start must be >= 0 s and duration > 0 s")
        if self.imu is not None and self.kind not in ONE_IMU_FAULTS:
            raise ValueError(f"fault {self.kind}: only {' and '.join(ONE_IMU_FAULTS)} hit one IMU")


@dataclass(frozen=True)
class FaultWindow:
    """Where a fault is, on the sensors' clock (header stamps, ns): from ``start_ns`` to ``end_ns``."""

    kind: str
    start_ns: int
    end_ns: int
    description: str


def _stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _set_stamp(msg: Any, stamp_ns: int) -> None:
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)


def _malform(msg: Any, which: int) -> None:
    """Make a PointCloud2 unreadable in one of five ways."""
    if which == 0:
        msg.point_step = max(f.offset for f in msg.fields)  # the last field sticks out of a point
    elif which == 1:
        msg.data = msg.data[: msg.data.size // 2]
    elif which == 2:
        msg.fields = [f for f in msg.fields if f.name != "x"]
    elif which == 3:
        msg.row_step += 8
    else:
        msg.fields[0].datatype = 42  # no such PointField datatype


class _Rewriter:
    """The faults applied to one message at a time, with the state they need (counters, a seeded generator)."""

    def __init__(self, src: Path, faults: Sequence[FaultSpec], seed: int) -> None:
        topics = bag_topics(src)
        self.imus = sorted(t for t, i in topics.items() if i.msgtype == _IMU and not t.startswith("/gt/"))
        self.clouds = {t for t, i in topics.items() if i.msgtype == _CLOUD and not t.startswith("/gt/")}
        self.t0 = bag_span(src)[0]
        self.faults = faults
        for f in faults:
            if f.imu is not None and f.imu not in self.imus:
                raise ValueError(f"fault {f.kind}: {f.imu} is not an IMU topic of {src} ({', '.join(self.imus)})")
        self.backend = RosbagsBackend()
        self.rng = np.random.default_rng(seed)
        self.count: dict[tuple[str, str], int] = {}  # (fault kind, topic) -> messages of it seen in the window
        self.held: dict[str, RawMessage] = {}  # topic -> a message held back to arrive after the next one
        self.first_stamp: dict[int, int] = {}  # fault index -> earliest header stamp of a message inside it
        self.last_stamp: dict[int, int] = {}  # ... latest

    def _active(self, log_ns: int) -> list[tuple[int, str]]:
        s = (log_ns - self.t0) * 1e-9
        return [(k, f.kind) for k, f in enumerate(self.faults) if f.start_s <= s < f.start_s + f.duration_s]

    def _hits(self, k: int, topic: str) -> bool:
        """Whether fault ``k``, a fault of one IMU, hits ``topic``."""
        return bool(self.imus) and topic == (self.faults[k].imu or self.imus[0])

    def _clock_step(self, log_ns: int) -> int:
        """The stamp shift of the clock faults begun by ``log_ns`` (they last to their window's end)."""
        s = (log_ns - self.t0) * 1e-9
        step = 0
        for f in self.faults:
            if f.kind in ("clock_back", "clock_forward") and f.start_s <= s < f.start_s + f.duration_s:
                step += _CLOCK_STEP_NS if f.kind == "clock_forward" else -_CLOCK_STEP_NS
        return step

    def apply(self, m: RawMessage) -> list[RawMessage]:
        """The messages that arrive instead of ``m`` (none, itself, changed, later, twice), and a message held
        back to arrive after it (:data:`FAULT_KINDS` ``imu_reordered``)."""
        out, hold = self._apply(m)
        held = self.held.pop(m.topic, None)
        if held is not None:  # after the message that followed it in the input
            out.append(RawMessage(held.topic, max([held.log_ns, *(o.log_ns for o in out)]) + _REORDER_NS, held.data,
                                  held.msgtype))
        if hold:  # arrives after the next message of its topic
            self.held[m.topic] = out.pop(0)
        return out

    def _apply(self, m: RawMessage) -> tuple[list[RawMessage], bool]:
        """The messages that arrive instead of ``m``, and whether the first is to be held back."""
        active = self._active(m.log_ns)
        step = self._clock_step(m.log_ns)
        sensor = m.topic in self.clouds or m.topic in self.imus
        if not step and not (active and sensor):
            return [m], False
        msg = self.backend.typestore.deserialize_cdr(m.data, m.msgtype)
        log_ns, copies, hold = m.log_ns, 1, False
        for k, kind in active if sensor else ():
            stamp = _stamp_ns(msg) + step
            self.first_stamp[k] = min(self.first_stamp.get(k, stamp), stamp)
            self.last_stamp[k] = max(self.last_stamp.get(k, stamp), stamp)
            n = self.count[(kind, m.topic)] = self.count.get((kind, m.topic), 0) + 1
            imu, cloud = m.topic in self.imus, m.topic in self.clouds
            one_imu = self._hits(k, m.topic)
            dropped = cloud and (kind == "lidar_gap" or (kind == "lidar_drops" and self.rng.random() < 0.1))
            if (kind == "all_silent" or (kind == "imus_silent" and imu) or (kind == "imu_silent" and one_imu)
                    or dropped):
                return [], False
            if kind == "bad_imu_samples" and imu and n % 3 == 0:
                bad = (n // 3) % 4
                if bad == 0:
                    msg.orientation.x = float("nan")
                elif bad == 1:
                    msg.linear_acceleration.z = float("inf")
                elif bad == 2:
                    msg.orientation.x = msg.orientation.y = msg.orientation.z = msg.orientation.w = 0.0
                else:
                    msg.angular_velocity.y = float("nan")
            elif kind == "imu_reordered" and imu:
                hold = n % 2 == 1
                copies = 2 if n % 5 == 0 else 1
            elif kind == "imu_ahead" and one_imu:
                _set_stamp(msg, _stamp_ns(msg) + _AHEAD_NS)
            elif kind == "imu_late" and imu:
                log_ns += _LATE_NS
            elif kind == "malformed_clouds" and cloud:
                _malform(msg, (n - 1) % 5)
            elif kind == "blinded_clouds" and cloud:
                msg.data = np.zeros_like(msg.data)
            elif kind == "empty_clouds" and cloud:
                msg.height = msg.width = msg.row_step = 0
                msg.data = np.zeros(0, dtype=np.uint8)
        if step and hasattr(msg, "header"):
            _set_stamp(msg, _stamp_ns(msg) + step)
        data = self.backend.serialize(msg, m.msgtype)
        return [RawMessage(m.topic, log_ns + k * _REORDER_NS, data, m.msgtype) for k in range(copies)], hold

    def leftover(self) -> list[RawMessage]:
        """The messages still held back at the end of the input."""
        out, self.held = list(self.held.values()), {}
        return out

    def windows(self) -> list[FaultWindow]:
        """Each fault's window on the sensors' clock (a fault that met no message: its receive-time window)."""
        out = []
        for k, f in enumerate(self.faults):
            start = self.t0 + round(f.start_s * 1e9)
            first = self.first_stamp.get(k, start)
            last = self.last_stamp.get(k, start + round(f.duration_s * 1e9))
            hit = f" ({f.imu or self.imus[0]})" if f.kind in ONE_IMU_FAULTS and self.imus else ""
            out.append(FaultWindow(f.kind, first, last, FAULT_KINDS[f.kind] + hit))
        return out


def _played(src: Path, faults: Sequence[FaultSpec], t0: int) -> Iterator[RawMessage]:
    """The input's messages in log order, with the capture started again at a ``played_again`` fault's start (its
    receive times go on from there; the earliest such fault; the input as it is without one)."""
    again = min((f for f in faults if f.kind == "played_again"), key=lambda f: f.start_s, default=None)
    if again is None:
        yield from read_raw(src)
        return
    start_ns, length_ns = round(again.start_s * 1e9), round(again.duration_s * 1e9)
    for m in read_raw(src):
        if m.log_ns - t0 >= start_ns:
            break
        yield m
    for m in read_raw(src):
        if m.log_ns - t0 >= length_ns:
            break
        yield RawMessage(m.topic, m.log_ns + start_ns, m.data, m.msgtype)


def _in_log_order(messages: Iterator[RawMessage], rewriter: _Rewriter) -> Iterator[RawMessage]:
    """The rewritten messages sorted by their (possibly delayed) receive time."""
    heap: list[tuple[int, int, RawMessage]] = []
    seq = 0
    for m in messages:
        for out in rewriter.apply(m):
            heapq.heappush(heap, (out.log_ns, seq, out))
            seq += 1
        while heap and heap[0][0] < m.log_ns - _MAX_DELAY_NS:
            yield heapq.heappop(heap)[2]
    for out in rewriter.leftover():
        heapq.heappush(heap, (out.log_ns, seq, out))
        seq += 1
    while heap:
        yield heapq.heappop(heap)[2]


def write_faulty_bag(src: str | Path, dst: str | Path, faults: Sequence[FaultSpec], seed: int = 0
                     ) -> list[FaultWindow]:
    """Rewrite the bag ``src`` into the new directory ``dst`` with ``faults``; copy the rig's sidecars; write
    ``faults.yaml``; the faults' windows on the sensors' clock."""
    src, dst = Path(src), Path(dst)
    if dst.exists():
        raise FileExistsError(f"{dst} exists")
    topics = bag_topics(src)
    rewriter = _Rewriter(src, faults, seed)
    conns: dict[str, Any] = {}
    with mcap_writer(dst, zstd=True) as writer:
        for m in _in_log_order(_played(src, faults, rewriter.t0), rewriter):
            if m.topic not in conns:
                info = topics[m.topic]
                conns[m.topic] = writer.add_connection(m.topic, info.msgtype, typestore=rewriter.backend.typestore,
                                                       offered_qos_profiles=list(info.offered_qos))
            writer.write(conns[m.topic], m.log_ns, m.data)
    for sidecar in src.iterdir():
        if sidecar.suffix in (".yaml", ".npz") and sidecar.name != "metadata.yaml":
            shutil.copy2(sidecar, dst / sidecar.name)
    windows = rewriter.windows()
    (dst / FAULTS_FILE).write_text(yaml.safe_dump({"faults": [
        {"kind": w.kind, "start_ns": w.start_ns, "end_ns": w.end_ns, "what": w.description} for w in windows]},
        sort_keys=False), encoding="utf-8")
    return windows


def read_fault_windows(bag: str | Path) -> list[FaultWindow]:
    """The fault windows of a bag written by :func:`write_faulty_bag` (none for another bag)."""
    path = Path(bag) / FAULTS_FILE
    if not path.is_file():
        return []
    doc = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    return [FaultWindow(f["kind"], int(f["start_ns"]), int(f["end_ns"]), f["what"]) for f in doc.get("faults", [])]
