"""diagnostic_msgs DiagnosticStatus / DiagnosticArray builders and reader."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from lip_msgs_py.backend import Backend
from lip_msgs_py.errors import MalformedMessageError
from lip_msgs_py.stamps import read_header

__all__ = [
    "DiagnosticLevel",
    "Diagnostic",
    "StampedDiagnostics",
    "diagnostic_status_to_msg",
    "diagnostic_array_to_msg",
    "msg_to_diagnostics",
]


class DiagnosticLevel(IntEnum):
    """DiagnosticStatus.level values."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(frozen=True)
class Diagnostic:
    """One DiagnosticStatus as read back."""

    level: DiagnosticLevel
    name: str
    message: str
    hardware_id: str = ""
    values: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class StampedDiagnostics:
    """The statuses of a DiagnosticArray."""

    stamp_ns: int
    frame_id: str
    statuses: tuple[Diagnostic, ...]


def _level(level: Any) -> DiagnosticLevel:
    """A level from an int (rosbags 'byte') or a 1-byte bytes (rclpy 'byte')."""
    value = level[0] if isinstance(level, (bytes, bytearray)) and len(level) == 1 else level
    try:
        return DiagnosticLevel(value)
    except ValueError:
        raise MalformedMessageError(f"DiagnosticStatus level {level!r} is not OK/WARN/ERROR/STALE (0..3)") from None


def diagnostic_status_to_msg(
    backend: Backend,
    level: int,
    name: str,
    message: str,
    hardware_id: str = "",
    values: Mapping[str, Any] | None = None,
) -> Any:
    """``diagnostic_msgs/msg/DiagnosticStatus``; ``values`` become KeyValue pairs via ``str()``."""
    return backend.msg(
        "diagnostic_msgs/msg/DiagnosticStatus",
        level=int(_level(level)),
        name=str(name),
        message=str(message),
        hardware_id=str(hardware_id),
        values=[
            backend.msg("diagnostic_msgs/msg/KeyValue", key=str(key), value=str(value))
            for key, value in (values or {}).items()
        ],
    )


def diagnostic_array_to_msg(backend: Backend, stamp_ns: int, statuses: Sequence[Any], frame_id: str = "") -> Any:
    """``diagnostic_msgs/msg/DiagnosticArray`` of DiagnosticStatus messages."""
    return backend.msg(
        "diagnostic_msgs/msg/DiagnosticArray", header=backend.header(stamp_ns, frame_id), status=list(statuses)
    )


def msg_to_diagnostics(msg: Any) -> StampedDiagnostics:
    """The statuses of a DiagnosticArray (KeyValue pairs as a dict; a repeated key keeps its last value)."""
    stamp_ns, frame_id = read_header(msg)
    return StampedDiagnostics(
        stamp_ns,
        frame_id,
        tuple(
            Diagnostic(
                level=_level(s.level),
                name=str(s.name),
                message=str(s.message),
                hardware_id=str(s.hardware_id),
                values={str(kv.key): str(kv.value) for kv in s.values},
            )
            for s in msg.status
        ),
    )
