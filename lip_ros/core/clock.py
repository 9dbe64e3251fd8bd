"""Sensor clocks that step back: a bag played in a loop, a PTP or NTP step, a driver restarted (ROS-free).

A stream's stamps only ever grow, but for messages a transport delivers out of
order (a few ms). A stamp more than :data:`CLOCK_STEP_NS` behind the newest one
of its stream is taken as the clock having stepped back. The LIP branch lets go
of what was buffered on the old time line (keeping what does not depend on
time, such as a calibration) and starts the stream again from that stamp. The
HSC4D branch, whose state is built along time (a trajectory, a pose graph, the
suit's buffers), keeps one time line instead: :class:`SteppingClock` moves the
stamps after a step on by its size, so that the time line goes on where it
was, and takes times on it back to the clock's reading for the outputs. When
the data show that a new capture began instead (a bag played again:
:mod:`lip_ros.hsc4d.suit_restart`), :meth:`SteppingClock.begin_again` starts a
new time line and refuses what the last capture still sends, or
:meth:`SteppingClock.realign` puts the new capture's stream where another
clock's time line has it.
"""

from __future__ import annotations

from bisect import bisect_right

__all__ = ["CLOCK_STEP_NS", "stepped_back", "SteppingClock"]

#: a stamp this far behind its stream's newest is a clock that stepped back, not a message out of order
CLOCK_STEP_NS = 500_000_000
_FAR_BEHIND = "far behind the last message (a clock step if the next one is too)"
_LAST_CAPTURE = "of the capture before a new one began"


def stepped_back(stamp_ns: int, newest_ns: int | None, tolerance_ns: int = CLOCK_STEP_NS) -> int:
    """How far (ns, > 0) the clock stepped back if ``stamp_ns`` is more than ``tolerance_ns`` behind ``newest_ns``;
    0 otherwise (or without a newest stamp)."""
    if newest_ns is None or newest_ns - stamp_ns <= tolerance_ns:
        return 0
    return int(newest_ns - stamp_ns)


class SteppingClock:
    """One clock's streams (the suit's IMUs and odometry; a LiDAR) on a time line that goes on across the clock's
    steps back.

    A stream whose stamp falls more than :data:`CLOCK_STEP_NS` behind its own newest has met a step, once the next
    one does too (a single stale message is only refused): from then on its stamps are moved on by the step's size
    (its newest stamp less the first stamp after the step, plus the stream's spacing), so that :meth:`internal`
    goes on one spacing after where it was. The other streams of the clock cross the same step, of the same size,
    when their stamps fall back too. Steps ahead are not undone: they look like a gap, which they also are for the
    data.
    """

    def __init__(self) -> None:
        self.steps_ns: list[int] = []  #: the steps back seen (their sizes, ns), oldest first
        self.refused = ""  #: why :meth:`internal` last refused a stamp
        self._starts: list[int] = []  # the internal time each step took effect at
        self._shifts: list[int] = [0]  # what the stamps are moved on by after 0, 1, ... steps
        # stream -> newest stamp, spacing, steps crossed, the stamp far behind it not confirmed yet (or None)
        self._streams: dict[str, tuple[int, int, int, int | None]] = {}
        self._last_capture: dict[str, int] = {}  # stream -> its newest stamp of the capture before (begin_again)
        self._ahead_ns: int | None = None  # ... and how far after it a stamp is the new capture's

    def begin_again(self, ahead_ns: int | None = None, crossed_within_ns: int | None = None) -> None:
        """A new capture on this clock: a new time line, from each stream's next stamp. A stream that crossed the
        clock's latest step back (the new capture's; within ``crossed_within_ns`` of its time line, if the step
        may be an older one) is in the new capture already; what the others send is the last capture's, refused
        by :meth:`internal`, until a stamp falls far behind their newest (their clock stepped back with the new
        capture), or (with ``ahead_ns``) comes more than ``ahead_ns`` after it (what the last capture may still
        send comes sooner: a clock that did not step, a stream silent across the step)."""
        latest = self._starts[-1] if self._starts else None
        self._ahead_ns = ahead_ns
        self._last_capture = {
            stream: newest for stream, (newest, _, crossed, _) in self._streams.items()
            if latest is None or crossed < len(self.steps_ns)
            or (crossed_within_ns is not None and newest + self._shifts[crossed] - latest > crossed_within_ns)}
        self.steps_ns, self._starts, self._shifts, self._streams = [], [], [0], {}

    @property
    def shift_ns(self) -> int:
        """What the stamps of the streams past the clock's latest step are moved on by."""
        return self._shifts[-1]

    def realign(self, stream: str, stamp_ns: int, shift_ns: int) -> int:
        """Move ``stream``'s stamps from ``stamp_ns`` on by ``shift_ns``, taken as a step (a new capture whose
        stamps must keep their relation to another clock's on that clock's time line: its :attr:`shift_ns`);
        the time of ``stamp_ns`` there (:meth:`external` takes times back right if that is after where the last
        step started the time line)."""
        self.steps_ns.append(shift_ns - self._shifts[-1])
        self._shifts.append(shift_ns)
        self._starts.append(stamp_ns + shift_ns)
        self._streams[stream] = (stamp_ns, self._streams.get(stream, (0, 0))[1], len(self.steps_ns), None)
        return stamp_ns + shift_ns

    def internal(self, stream: str, stamp_ns: int, confirm: bool = True) -> int | None:
        """The time of ``stream``'s stamp on the time line; None for a stamp far behind the stream's newest that
        the stream has not confirmed as a step yet (refuse that message). Without ``confirm`` the first stamp far
        behind is the step (a stream that never sends a stale message: a LiDAR's sweeps, another node's output);
        no message is refused then, which keeps the spacing of what the stream sends after the step right for
        those downstream that measure the step again. After :meth:`begin_again`, also None for what the stream
        still sends of the last capture. :attr:`refused` says why."""
        last = self._last_capture.get(stream)
        if last is not None:
            if not stepped_back(stamp_ns, last) and (self._ahead_ns is None or stamp_ns - last <= self._ahead_ns):
                self.refused = _LAST_CAPTURE
                return None
            del self._last_capture[stream]
        newest, spacing, crossed, stale = self._streams.get(stream, (None, 0, 0, None))
        if newest is None:
            self._streams[stream] = (stamp_ns, 0, 0, None)
            return stamp_ns + self._shifts[0]
        if not stepped_back(stamp_ns, newest):
            if stamp_ns > newest:
                spacing, newest = stamp_ns - newest, stamp_ns
            self._streams[stream] = (newest, spacing, crossed, None)
            return stamp_ns + self._shifts[crossed]
        if stale is None and confirm:  # the first stamp that far back: a stale message, or a step the next one confirms
            self._streams[stream] = (newest, spacing, crossed, stamp_ns)
            self.refused = _FAR_BEHIND
            return None
        if crossed == len(self.steps_ns):  # the first of the clock's streams past this step
            first = stamp_ns if stale is None else min(stale, stamp_ns)  # the first stamp after the step
            size = newest + spacing - first
            self.steps_ns.append(size)
            self._shifts.append(self._shifts[-1] + size)
            self._starts.append(first + self._shifts[-1])
        crossed += 1
        self._streams[stream] = (stamp_ns, spacing, crossed, None)
        return stamp_ns + self._shifts[crossed]

    def external(self, internal_ns: int) -> int:
        """A time of the time line as the clock read it then (the stamp its sensor gave that moment)."""
        return internal_ns - self._shifts[bisect_right(self._starts, internal_ns)]
