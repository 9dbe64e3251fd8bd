"""Per-sensor health bookkeeping: rate, staleness, stamp order, clock steps and rejected messages (ROS-free).

Every message a node receives is accounted for here: accepted (counted towards
the rate) or rejected with a reason. The node turns :meth:`SensorMonitor.report`
into ``/diagnostics``. A clock step of the sensor is a stamp more than
:data:`lip_ros.core.clock.CLOCK_STEP_NS` behind the newest, or that ran that
much further than the receive clock since the last message; it is reported
(WARN) for ``window_s`` after. A sensor stamping each period
(``count_missing``) has its period measured from the stamps
(:class:`lip_ros.core.frame_period.FramePeriod`): the missing messages are
counted in it, and one far from the expected rate is reported (WARN: a LiDAR
at 20 Hz where 10 was configured). Messages published and never taken (lost in
transport or overwritten in the input's queue) are counted from the publisher's
sequence numbers (:attr:`SensorMonitor.delivery`,
:class:`lip_ros.core.delivery.DeliveryGaps`) and reported (WARN) for ``window_s``.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

import numpy as np

from lip_msgs_py.diagnostics import DiagnosticLevel
from lip_ros.core.clock import CLOCK_STEP_NS, stepped_back
from lip_ros.core.delivery import DeliveryGaps, not_taken_how
from lip_ros.core.frame_period import FramePeriod

__all__ = ["SensorReport", "SilenceChange", "SensorMonitor", "odd_delays"]

#: how many of the latest messages the delay is the median of (a tenth of a second of 60 Hz IMU data, a second of
#: 10 Hz LiDAR frames)
_DELAY_MESSAGES = 9
#: a period measured from the stamps is reported when its rate is farther than this factor from the expected one
_RATE_FACTOR = 1.25


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
    clock_steps: int = 0  # how often the stamps stepped back or ran ahead of the receive clock, since start
    delay_s: float | None = None  # median receive time less stamp of the latest messages (SensorMonitor.delay_s)
    missing: int = 0  # messages missing from gaps in the stamps, since start (with count_missing)
    not_taken: int | None = None  # messages published and never taken, since start (None: not counted; delivery)
    lost_in_transport: int | None = None  # of which DDS said they were lost


class SilenceChange(NamedTuple):
    """A sensor falling silent or sending again (:meth:`SensorMonitor.silence_change`)."""

    kind: Literal["silent", "back", "was_silent"]
    seconds: float  # silent: since its last message; back, was_silent: how long the silence lasted (NaN: unknown)


@dataclass
class SensorMonitor:
    """Health of one input stream.

    ``expected_rate_hz`` sets the warning threshold (below half of it: WARN);
    ``stale_after_s`` without an accepted message makes the sensor STALE.
    Times are receive times in seconds on any monotonic clock; 0 is taken for no
    time in the silences (:meth:`silence_change`): a node on ``/clock`` before its
    first tick.
    """

    name: str
    expected_rate_hz: float
    stale_after_s: float = 1.0
    window_s: float = 2.0
    max_delay_s: float | None = None  # messages arriving later than this after their stamps (median): WARN
    count_missing: bool = False  # count messages missing from gaps in the stamps (a sensor stamping each period)
    #: messages published and never taken, from the publisher's sequence numbers, over ``window_s`` as the rest
    delivery: DeliveryGaps = field(init=False, repr=False)
    _arrivals: deque[float] = field(default_factory=deque, repr=False)
    # receive time - stamp (s) of the latest messages
    _delays: deque[float] = field(default_factory=lambda: deque(maxlen=_DELAY_MESSAGES), repr=False)
    _rejected: Counter[str] = field(default_factory=Counter, repr=False)
    _recent_rejects: deque[tuple[float, str]] = field(default_factory=deque, repr=False)
    _recent_steps: deque[tuple[float, int]] = field(default_factory=deque, repr=False)  # (receive time, signed step)
    _recent_missing: deque[tuple[float, int]] = field(default_factory=deque, repr=False)  # (receive time, missing)
    _period: FramePeriod = field(default_factory=FramePeriod, repr=False)  # of the accepted stamps (count_missing)
    _missing: int = 0
    _received: int = 0
    _accepted: int = 0
    _out_of_order: int = 0
    _last_stamp_ns: int | None = None
    _last_arrival: float | None = None
    _clock_steps: int = 0
    _silent: bool = False  # said silent by silence_change, and not said back since
    _silence_lasted_s: float | None = None  # receive time from the last message before a silence to the first after
    _unseen_silence_s: float | None = None  # a silence that began and ended between two looks, how long

    def __post_init__(self) -> None:
        self.delivery = DeliveryGaps(self.window_s)

    def accept(self, now_s: float, stamp_ns: int) -> None:
        """Count a valid message with measurement stamp ``stamp_ns`` received at ``now_s``."""
        self._received += 1
        self._accepted += 1
        # receive time 0 is no time: a node on /clock before its first message
        gap = now_s - self._last_arrival if self._last_arrival else None
        if self._silent:
            if self._silence_lasted_s is None:
                self._silence_lasted_s = gap if gap is not None and gap >= 0.0 else math.nan  # the clock went back
        elif gap is not None and gap > self.stale_after_s:
            self._unseen_silence_s = gap
        step = -stepped_back(stamp_ns, self._last_stamp_ns)
        if not step and self._last_stamp_ns is not None and self._last_arrival is not None:
            ahead = (stamp_ns - self._last_stamp_ns) - round((now_s - self._last_arrival) * 1e9)
            step = ahead if ahead > CLOCK_STEP_NS else 0  # the stamps ran ahead of the receive clock
        if step:  # the sensor's clock stepped: its stamps go on from here
            self._clock_steps += 1
            self._recent_steps.append((now_s, step))
        elif self.count_missing and self._last_stamp_ns is not None and stamp_ns > self._last_stamp_ns:
            missing = round((stamp_ns - self._last_stamp_ns) * 1e-9 * self.measured_rate_hz) - 1
            if missing > 0:
                self._missing += missing
                self._recent_missing.append((now_s, missing))
        if self._last_stamp_ns is not None and stamp_ns <= self._last_stamp_ns and not step:
            self._out_of_order += 1
        else:
            self._last_stamp_ns = stamp_ns
            if self.count_missing:
                self._period.add(stamp_ns)
        self._trim(now_s)
        self._arrivals.append(now_s)
        self._delays.append(now_s - stamp_ns * 1e-9)
        self._last_arrival = now_s

    def reject(self, now_s: float, reason: str) -> None:
        """Count a message that could not be used, under a short ``reason``."""
        self._received += 1
        self._rejected[reason] += 1
        self._trim(now_s)
        self._recent_rejects.append((now_s, reason))

    def _trim(self, now_s: float) -> None:
        if self._last_arrival is not None and now_s < self._last_arrival - self.window_s:
            # the receive clock went back (a bag played again with its /clock): the windows start again
            self._arrivals.clear()
            self._delays.clear()
            self._recent_rejects = deque(e for e in self._recent_rejects if e[0] <= now_s)
            self._recent_steps = deque(e for e in self._recent_steps if e[0] <= now_s)
            self._recent_missing = deque(e for e in self._recent_missing if e[0] <= now_s)
            self._last_arrival = None
        start = now_s - self.window_s
        while self._arrivals and self._arrivals[0] < start:
            self._arrivals.popleft()
        while self._recent_rejects and self._recent_rejects[0][0] < start:
            self._recent_rejects.popleft()
        while self._recent_steps and self._recent_steps[0][0] < start:
            self._recent_steps.popleft()
        while self._recent_missing and self._recent_missing[0][0] < start:
            self._recent_missing.popleft()

    def rate_hz(self, now_s: float) -> float:
        """Accepted messages per second over the last ``window_s``."""
        self._trim(now_s)
        return len(self._arrivals) / self.window_s

    @property
    def received(self) -> int:
        """Messages received since start, valid or not."""
        return self._received

    @property
    def measured_rate_hz(self) -> float:
        """The rate of the stamps (a sensor stamping each period, ``count_missing``), the expected rate until it
        is known or without ``count_missing``."""
        return self._period.rate_hz or self.expected_rate_hz

    def delay_s(self) -> float | None:
        """Median of receive time less stamp over the latest messages (None without any): transport and driver
        delay, plus any offset between the sensor's clock and the receive clock."""
        return float(np.median(self._delays)) if self._delays else None

    def silence_change(self, now_s: float) -> SilenceChange | None:
        """A change in the sensor's silence since the last call, each said once (:class:`SilenceChange`): a sensor
        that sent valid messages has sent none for more than ``stale_after_s`` (``silent``, seconds since its last
        message), sends again after such a silence (``back``, how long it lasted: from its last message before to
        its first after; NaN across a reset of the receive clock), or did both since the last call (``was_silent``,
        how long); None otherwise."""
        self._trim(now_s)
        if self._unseen_silence_s is not None:
            lasted, self._unseen_silence_s = self._unseen_silence_s, None
            return SilenceChange("was_silent", lasted)
        if not self._last_arrival:  # none yet, the receive clock went back, or receive time 0 (no time)
            return None
        age = now_s - self._last_arrival
        if not self._silent and age > self.stale_after_s:
            self._silent, self._silence_lasted_s = True, None
            return SilenceChange("silent", age)
        if self._silent and self._silence_lasted_s is not None:
            self._silent, lasted, self._silence_lasted_s = False, self._silence_lasted_s, None
            return SilenceChange("back", lasted)
        return None

    def report(self, now_s: float) -> SensorReport:
        """The sensor's health now."""
        rate = self.rate_hz(now_s)
        delay = self.delay_s()
        age = None if self._last_arrival is None else now_s - self._last_arrival
        rejected = dict(self._rejected)
        problems = []
        if rate < 0.5 * self.expected_rate_hz:
            problems.append(f"rate {rate:.1f} Hz, expected {self.expected_rate_hz:.1f} Hz")
        stamped = self.measured_rate_hz
        if not 1.0 / _RATE_FACTOR <= stamped / self.expected_rate_hz <= _RATE_FACTOR:
            problems.append(f"stamped {1e3 / stamped:.0f} ms apart ({stamped:.1f} Hz), expected "
                            f"{self.expected_rate_hz:.1f} Hz")
        recent = Counter(reason for _, reason in self._recent_rejects)
        if recent:
            problems.append(f"rejected in the last {self.window_s:g} s: "
                            + ", ".join(f"{k} x{v}" for k, v in sorted(recent.items())))
        if self._recent_missing:
            problems.append(f"{sum(n for _, n in self._recent_missing)} missing (gaps in the accepted stamps) in "
                            f"the last {self.window_s:g} s")
        gaps = self.delivery.recent(now_s)
        if gaps.not_taken:
            how = not_taken_how(gaps, self.delivery.loss_events)
            problems.append(f"{gaps.not_taken} published and not taken ({how}) in the last {self.window_s:g} s")
        if delay is not None and self.max_delay_s is not None and delay > self.max_delay_s:
            problems.append(f"arriving {1e3 * delay:.0f} ms after their stamps (more than "
                            f"{1e3 * self.max_delay_s:.0f} ms)")
        if self._recent_steps:
            step = self._recent_steps[-1][1] * 1e-9
            problems.append(f"stamps stepped {'back' if step < 0 else 'ahead'} {abs(step):.1f} s (a clock step) in "
                            f"the last {self.window_s:g} s")
        if age is None or age > self.stale_after_s:
            health = DiagnosticLevel.STALE
            message = "no data" if age is None else f"no valid message for {age:.1f} s"
        elif problems:
            health, message = DiagnosticLevel.WARN, "; ".join(problems)
        else:
            health, message = DiagnosticLevel.OK, f"{rate:.1f} Hz"
        total = self.delivery.total
        counted = self.delivery.counting
        return SensorReport(self.name, health, message, rate, self._received, self._accepted, rejected,
                            self._out_of_order, age, self._clock_steps, delay, self._missing,
                            total.not_taken if counted else None, total.lost_in_transport if counted else None)


def odd_delays(delays: Mapping[str, float | None], tolerance_s: float) -> dict[str, float]:
    """Of sensors that should be stamped alike (e.g. on arrival at one host), those whose delay
    (:meth:`SensorMonitor.delay_s`) differs from the median of all by more than ``tolerance_s``: name -> how much
    (s; negative: stamped ahead of the others). Needs three sensors with a delay."""
    known = {n: d for n, d in delays.items() if d is not None}
    if len(known) < 3:
        return {}
    middle = float(np.median(list(known.values())))
    return {n: d - middle for n, d in known.items() if abs(d - middle) > tolerance_s}
