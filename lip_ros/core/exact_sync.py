"""Join messages of several streams that carry the same stamp (message_filters' ExactTime policy, ROS-free)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["ExactTimeJoiner", "Incomplete"]


@dataclass(frozen=True)
class Incomplete:
    """A stamp given up on: the streams it had (name -> item)."""

    stamp_ns: int
    items: dict[str, Any]

    def missing(self, names: Sequence[str]) -> list[str]:
        """The streams it lacked."""
        return [n for n in names if n not in self.items]


class ExactTimeJoiner:
    """Items of ``names`` streams in, complete sets (one item per stream at one stamp) out, in stamp order.

    A set completes when its last item arrives; older incomplete stamps are
    then given up (streams deliver in stamp order), as is the oldest one when
    more than ``max_stamps`` are open.
    """

    def __init__(self, names: Sequence[str], max_stamps: int = 50) -> None:
        self.names = tuple(names)
        self.max_stamps = max_stamps
        self._open: dict[int, dict[str, Any]] = {}

    def add(self, name: str, stamp_ns: int, item: Any) -> tuple[list[dict[str, Any]], list[Incomplete]]:
        """One item; the sets completed by it (at most one) and the stamps given up."""
        if name not in self.names:
            raise KeyError(f"unknown stream {name!r}; streams: {', '.join(self.names)}")
        items = self._open.setdefault(stamp_ns, {})
        items[name] = item
        dropped: list[Incomplete] = []
        if len(items) == len(self.names):
            del self._open[stamp_ns]
            for t in sorted(t for t in self._open if t < stamp_ns):
                dropped.append(Incomplete(t, self._open.pop(t)))
            return [items], dropped
        while len(self._open) > self.max_stamps:
            t = min(self._open)
            dropped.append(Incomplete(t, self._open.pop(t)))
        return [], dropped

    @property
    def open_stamps(self) -> int:
        """Stamps waiting for more items."""
        return len(self._open)
