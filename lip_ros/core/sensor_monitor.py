"""Per-sensor health bookkeeping: rate, staleness, stamp order and rejected messages (ROS-free).

Every message a node receives is accounted for here: accepted (counted towards
the rate) or rejected with a reason. The node turns :meth:`SensorMonitor.report`
into ``/diagnostics``.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field

from lip_msgs_py.diagnostics import DiagnosticLevel

__all__ = ["SensorReport", "SensorMonitor"]


@dataclass(frozen=True)
class SensorReport:
    """One sensor's state at a point in (receive) time."""

    name: str
    health: DiagnosticLevel
    message: str
    rate_hz: float
    received: int
    accepted: int
    rejected: dict[str, int]  # since start, by reason
    out_of_order: int
    age_s: float | None  # receive time since the last accepted message


@dataclass
class SensorMonitor:
    """Health of one input stream.

    ``expected_rate_hz`` sets the warning threshold (below half of it: WARN);
    ``stale_after_s`` without an accepted message makes the sensor STALE.
    Times are receive times in seconds on any monotonic clock.
    """

    name: str
    expected_rate_hz: float
    stale_after_s: float = 1.0
    window_s: float = 2.0
    _arrivals: deque[float] = field(default_factory=deque, repr=False)
    _rejected: Counter[str] = field(default_factory=Counter, repr=False)
    _recent_rejects: deque[tuple[float, str]] = field(default_factory=deque, repr=False)
    _received: int = 0
    _accepted: int = 0
    _out_of_order: int = 0
    _last_stamp_ns: int | None = None
    _last_arrival: float | None = None

    def accept(self, now_s: float, stamp_ns: int) -> None:
        """Count a valid message with measurement stamp ``stamp_ns`` received at ``now_s``."""
        self._received += 1
        self._accepted += 1
        if self._last_stamp_ns is not None and stamp_ns <= self._last_stamp_ns:
            self._out_of_order += 1
        else:
            self._last_stamp_ns = stamp_ns
        self._arrivals.append(now_s)
        self._last_arrival = now_s
        self._trim(now_s)

    def reject(self, now_s: float, reason: str) -> None:
        """Count a message that could not be used, under a short ``reason``."""
        self._received += 1
        self._rejected[reason] += 1
        self._recent_rejects.append((now_s, reason))
        self._trim(now_s)

    def _trim(self, now_s: float) -> None:
        start = now_s - self.window_s
        while self._arrivals and self._arrivals[0] < start:
            self._arrivals.popleft()
        while self._recent_rejects and self._recent_rejects[0][0] < start:
            self._recent_rejects.popleft()

    def rate_hz(self, now_s: float) -> float:
        """Accepted messages per second over the last ``window_s``."""
        self._trim(now_s)
        return len(self._arrivals) / self.window_s

    def report(self, now_s: float) -> SensorReport:
        """The sensor's health now."""
        rate = self.rate_hz(now_s)
        age = None if self._last_arrival is None else now_s - self._last_arrival
        rejected = dict(self._rejected)
        problems = []
        if rate < 0.5 * self.expected_rate_hz:
            problems.append(f"rate {rate:.1f} Hz, expected {self.expected_rate_hz:.1f} Hz")
        recent = Counter(reason for _, reason in self._recent_rejects)
        if recent:
            problems.append(f"rejected in the last {self.window_s:g} s: "
                            + ", ".join(f"{k} x{v}" for k, v in sorted(recent.items())))
        if age is None or age > self.stale_after_s:
            health = DiagnosticLevel.STALE
            message = "no data" if age is None else f"no valid message for {age:.1f} s"
        elif problems:
            health, message = DiagnosticLevel.WARN, "; ".join(problems)
        else:
            health, message = DiagnosticLevel.OK, f"{rate:.1f} Hz"
        return SensorReport(self.name, health, message, rate, self._received, self._accepted, rejected,
                            self._out_of_order, age)
