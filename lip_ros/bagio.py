"""Reading rosbag2 bags (MCAP or sqlite3) with rosbags and its Jazzy typestore, without ROS."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

__all__ = ["BagMessage", "TopicInfo", "jazzy_typestore", "bag_topics", "read_messages"]


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
class TopicInfo:
    """A topic of a bag: type, message count and the QoS it was recorded with."""

    msgtype: str
    count: int
    reliability: str


def bag_topics(path: str | Path) -> dict[str, TopicInfo]:
    """The topics of a bag."""
    with Reader(Path(path)) as reader:
        out = {}
        for c in reader.connections:
            qos = c.ext.offered_qos_profiles
            reliability = qos[0].reliability.name.lower() if qos else "unknown"
            prev = out.get(c.topic)
            out[c.topic] = TopicInfo(c.msgtype, c.msgcount + (prev.count if prev else 0), reliability)
        return out


def read_messages(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Messages of ``topics`` (default: all) in log-time order, deserialised with the Jazzy typestore."""
    store = jazzy_typestore()
    wanted = None if topics is None else set(topics)
    with Reader(Path(path)) as reader:
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        for conn, log_ns, raw in reader.messages(connections=conns):
            yield BagMessage(conn.topic, log_ns, store.deserialize_cdr(raw, conn.msgtype))
