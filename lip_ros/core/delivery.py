"""Messages published to an input and never taken by it, from the publishers' sequence numbers (ROS-free).

DDS numbers each writer's samples 1, 2, 3, ... and rmw hands the number to
the subscriber with each message it takes (rclpy's message info,
``publication_sequence_number``). A gap in those numbers between two messages
taken is messages published and never taken: lost in transport (a best-effort
sample that never arrived, or one a reliable writer gave up on, which DDS
reports as lost: rclpy's ``message_lost`` event,
:meth:`DeliveryGaps.lost_in_transport`) or, where DDS reported no loss,
overwritten in the subscription's queue (a KEEP_LAST queue full while the node
did not take from it: nothing else reports that).

The numbers are per publisher, and the message info does not say which one sent
a message: each number continues the *stream* whose last number is the closest
below it; one below every stream's starts a stream of its own (a second
publisher, or one started again), and so does one that would leave a gap while
the subscription has more publishers matched than streams followed (a publisher
matched late, its numbers ahead of the others'). A stream's first message starts
its count: what a publisher published before this subscriber was matched is
nobody's loss, and so is what went missing before the first message taken and
after the last. Streams are kept, however long idle (a gap across an outage is
counted), up to :data:`MAX_STREAMS`; a publisher gone leaves its stream behind,
so one matched after it with numbers ahead of that stream's has its first
message taken for a gap in it. Two publishers' streams could swap messages where
one's numbers pass the other's; the count stays the number of messages skipped.
A loss DDS reports is matched to a gap seen within ``window_s`` before or after
it (the event and the message after the loss are taken in either order).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

__all__ = ["Delivery", "DeliveryGaps", "SEQUENCE_UNSUPPORTED", "not_taken_how"]

#: rmw's RMW_MESSAGE_INFO_SEQUENCE_NUMBER_UNSUPPORTED: a middleware that does not number its messages (and any
#: number from this one up) counts nothing
SEQUENCE_UNSUPPORTED = 2**64 - 1
#: streams (publishers) followed at once; the one that continued longest ago goes first
MAX_STREAMS = 8


class Delivery(NamedTuple):
    """Messages not taken, since start or in a recent window."""

    not_taken: int  # published and never taken (lost in transport or overwritten in the queue)
    lost_in_transport: int  # of which DDS said they were lost (only where its loss events are handled)

    @property
    def overwritten(self) -> int:
        """Those not taken that DDS did not report lost: overwritten in the queue."""
        return self.not_taken - self.lost_in_transport


@dataclass
class DeliveryGaps:
    """One input's messages published and never taken (module docstring); receive times in seconds on any
    monotonic clock, ``window_s`` the span of :meth:`recent` and how long a loss DDS reported waits for its gap."""

    window_s: float = 2.0
    loss_events: bool = True  #: whether DDS's loss events come to :meth:`lost_in_transport` (not for a polled input)
    _streams: dict[int, float] = field(default_factory=dict)  # last number -> when it was taken
    _not_taken: int = 0
    _lost: int = 0
    _pending: deque[tuple[float, int]] = field(default_factory=deque, repr=False)  # DDS's losses, gap not seen yet
    _open: deque[list[float | int]] = field(default_factory=deque, repr=False)  # [time, skipped no loss matched yet]
    _recent: deque[tuple[float, int, int]] = field(default_factory=deque, repr=False)  # (time, not taken, lost)

    @property
    def counting(self) -> bool:
        """Whether a numbered message was taken (a middleware that numbers them; not by a direct call)."""
        return bool(self._streams)

    def taken(self, now_s: float, sequence: int | None, publishers: Callable[[], int] | None = None) -> None:
        """A message with the publisher's ``sequence`` number (None: not given) taken at ``now_s``;
        ``publishers()``: how many publishers the subscription has matched now (asked only where the message would
        leave a gap; None: as many as streams followed)."""
        if sequence is None or sequence >= SEQUENCE_UNSUPPORTED:
            return
        if sequence in self._streams:  # the number a stream is at (a repeat, or two publishers' numbers met)
            self._streams[sequence] = now_s
            return
        last = max((n for n in self._streams if n < sequence), default=None)
        if (last is not None and sequence > last + 1 and publishers is not None
                and publishers() > len(self._streams)):
            last = None  # a publisher not followed yet: its first message, not a gap in another's numbers
        if last is None:  # a new publisher, or one started again
            if len(self._streams) >= MAX_STREAMS:
                del self._streams[min(self._streams, key=self._streams.__getitem__)]
        else:
            del self._streams[last]
            if sequence > last + 1:
                self._gap(now_s, sequence - last - 1)
        self._streams[sequence] = now_s

    def lost_in_transport(self, now_s: float, count: int) -> None:
        """DDS says ``count`` more messages were lost: matched to the gaps seen in the messages taken within
        ``window_s`` before (oldest first) or, the rest, after."""
        if count <= 0:
            return
        self._expire(now_s)
        matched = 0
        while self._open and matched < count:
            gap = self._open[0]
            use = min(int(gap[1]), count - matched)
            matched += use
            gap[1] -= use
            if not gap[1]:
                self._open.popleft()
        if matched:
            self._lost += matched
            self._recent.append((now_s, 0, matched))
        if count > matched:
            self._pending.append((now_s, count - matched))

    @property
    def total(self) -> Delivery:
        """Since start."""
        return Delivery(self._not_taken, self._lost)

    def recent(self, now_s: float) -> Delivery:
        """In the last ``window_s`` (all since a reset of the receive clock)."""
        if self._recent and now_s < self._recent[-1][0]:  # the receive clock went back
            self._recent.clear()
        while self._recent and self._recent[0][0] < now_s - self.window_s:
            self._recent.popleft()
        not_taken = sum(n for _, n, _ in self._recent)  # a late loss's gap may have left the window before it
        return Delivery(not_taken, min(sum(n for _, _, n in self._recent), not_taken))

    def _gap(self, now_s: float, missed: int) -> None:
        """``missed`` messages skipped: as many of them lost as DDS reported and no gap took yet."""
        self._expire(now_s)
        lost = 0
        while self._pending and lost < missed:
            at, count = self._pending.popleft()
            used = min(count, missed - lost)
            lost += used
            if used < count:
                self._pending.appendleft((at, count - used))
        self._not_taken += missed
        self._lost += lost
        if missed > lost:  # a loss DDS reports late may still be this gap's
            self._open.append([now_s, missed - lost])
        self.recent(now_s)  # the window trimmed: bounded whether or not anyone reads it
        self._recent.append((now_s, missed, lost))

    def _expire(self, now_s: float) -> None:
        """Forget the losses DDS reported whose gap did not come within ``window_s`` (lost after the last message
        taken), and the gaps no loss came for within it; all of them across a reset of the receive clock."""
        for waiting in (self._pending, self._open):
            while waiting and not now_s - self.window_s <= waiting[0][0] <= now_s:
                waiting.popleft()


def not_taken_how(delivery: Delivery, loss_events: bool, queue: str = "the input's queue") -> str:
    """Where the messages of ``delivery`` not taken went, as a log line says it (``loss_events``: whether DDS's
    losses were counted; ``queue``: the subscription's queue, as the line names it)."""
    if not loss_events:
        return f"lost in transport or overwritten in {queue}"
    return f"{delivery.lost_in_transport} lost in transport, {delivery.overwritten} overwritten in {queue}"
