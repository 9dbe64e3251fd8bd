"""rosbag2 bags (MCAP or sqlite3) with rosbags and its Jazzy typestore, without ROS: reading, writing, QoS records."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from rosbags.interfaces import Connection, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

__all__ = [
    "BagError",
    "BagMessage",
    "RawMessage",
    "TopicInfo",
    "INFINITE",
    "SENSOR_QOS",
    "RELIABLE_QOS",
    "bag_qos",
    "jazzy_typestore",
    "bag_topics",
    "bag_span",
    "read_messages",
    "read_raw",
    "mcap_writer",
]

INFINITE = QosTime(sec=9223372036, nsec=854775807)  # rmw's infinite duration, as rosbag2 records it


def bag_qos(reliability: QosReliability, depth: int, durability: QosDurability = QosDurability.VOLATILE) -> Qos:
    """A rosbag2 offered-QoS record: keep last ``depth``, automatic liveliness, infinite deadline and lifespan."""
    return Qos(QosHistory.KEEP_LAST, depth, reliability, durability, INFINITE, INFINITE,
               QosLiveliness.AUTOMATIC, INFINITE, False)


SENSOR_QOS = bag_qos(QosReliability.BEST_EFFORT, 5)  # rclpy qos_profile_sensor_data
RELIABLE_QOS = bag_qos(QosReliability.RELIABLE, 10)


class BagError(ValueError):
    """A path that is not a readable rosbag2 bag, or a bag this package cannot use."""


@lru_cache(maxsize=1)
def jazzy_typestore() -> Typestore:
    """The ROS 2 Jazzy message types of rosbags."""
    return get_typestore(Stores.ROS2_JAZZY)


@dataclass(frozen=True)
class BagMessage:
    """One deserialised message and the time the recorder received it."""

    topic: str
    log_ns: int
    msg: Any


@dataclass(frozen=True)
class RawMessage:
    """One message as CDR bytes (with the encapsulation header), its type and the time the recorder received it."""

    topic: str
    log_ns: int
    data: bytes | memoryview  # bytes from read_raw; a view from lip_ros.bagstream.stream_raw (see there)
    msgtype: str


@dataclass(frozen=True)
class TopicInfo:
    """A topic of a bag: type, message count and the QoS its publishers offered when it was recorded."""

    msgtype: str
    count: int
    reliability: str
    offered_qos: tuple[Qos, ...] = ()


@contextmanager
def _open(path: str | Path) -> Iterator[Reader]:
    try:
        reader = Reader(Path(path))
        reader.open()
    except (FileNotFoundError, ReaderError) as exc:
        raise BagError(f"{path}: not a readable rosbag2 bag ({exc})") from None
    try:
        yield reader
    finally:
        reader.close()


def bag_topics(path: str | Path) -> dict[str, TopicInfo]:
    """The topics of a bag; BagError if a topic has messages of several types."""
    with _open(path) as reader:
        out: dict[str, TopicInfo] = {}
        for c in reader.connections:
            prev = out.get(c.topic)
            if prev is not None and prev.msgtype != c.msgtype:
                raise BagError(f"{path}: topic {c.topic} has several types ({prev.msgtype}, {c.msgtype})")
            qos = (*(prev.offered_qos if prev else ()), *c.ext.offered_qos_profiles)
            reliability = qos[0].reliability.name.lower() if qos else "unknown"
            out[c.topic] = TopicInfo(c.msgtype, c.msgcount + (prev.count if prev else 0), reliability, qos)
        return out


def bag_span(path: str | Path) -> tuple[int, int]:
    """Log times (ns) of the first and the last message of a bag."""
    with _open(path) as reader:
        return reader.start_time, reader.start_time + reader.duration


def _connections(reader: Reader, topics: Iterable[str] | None) -> list[Connection]:
    wanted = None if topics is None else set(topics)
    return [c for c in reader.connections if wanted is None or c.topic in wanted]


def read_messages(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Messages of ``topics`` (default: all) in log-time order, deserialised with the Jazzy typestore."""
    store = jazzy_typestore()
    with _open(path) as reader:
        conns = _connections(reader, topics)
        if conns:  # rosbags reads every connection when given none
            for conn, log_ns, raw in reader.messages(connections=conns):
                yield BagMessage(conn.topic, log_ns, store.deserialize_cdr(raw, conn.msgtype))


def read_raw(path: str | Path, topics: Iterable[str] | None = None,
             start_ns: int | None = None) -> Iterator[RawMessage]:
    """Messages of ``topics`` (default: all) logged at or after ``start_ns``, in log-time order, not deserialised."""
    with _open(path) as reader:
        conns = _connections(reader, topics)
        if conns:
            for conn, log_ns, raw in reader.messages(connections=conns, start=start_ns):
                yield RawMessage(conn.topic, log_ns, bytes(raw), conn.msgtype)


def mcap_writer(path: str | Path, zstd: bool = False) -> Writer:
    """A rosbag2 (version 9) MCAP bag writer for the new directory ``path``; ``zstd``: compressed chunks."""
    writer = Writer(Path(path), version=9, storage_plugin=StoragePlugin.MCAP)
    if zstd:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    return writer
