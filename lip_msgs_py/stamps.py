"""builtin_interfaces Time / Duration <-> integer nanoseconds, and headers."""

from __future__ import annotations

from typing import Any

from lip_msgs_py.errors import MalformedMessageError

__all__ = ["NS_PER_S", "stamp_to_ns", "ns_to_sec_nanosec", "read_header"]

NS_PER_S = 1_000_000_000
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


def stamp_to_ns(stamp: Any) -> int:
    """Integer nanoseconds of a ``builtin_interfaces`` Time or Duration (any backend)."""
    sec, nanosec = int(stamp.sec), int(stamp.nanosec)
    if not 0 <= nanosec < NS_PER_S:
        raise MalformedMessageError(f"stamp nanosec {nanosec} outside [0, 1e9)")
    return sec * NS_PER_S + nanosec


def ns_to_sec_nanosec(ns: int) -> tuple[int, int]:
    """Split nanoseconds into ``(sec, nanosec)`` as ROS does (nanosec always in [0, 1e9))."""
    sec, nanosec = divmod(int(ns), NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise MalformedMessageError(f"time {ns} ns does not fit builtin_interfaces (int32 seconds)")
    return sec, nanosec


def read_header(msg: Any) -> tuple[int, str]:
    """``(stamp_ns, frame_id)`` of a message with a ``std_msgs/Header``."""
    return stamp_to_ns(msg.header.stamp), str(msg.header.frame_id)
