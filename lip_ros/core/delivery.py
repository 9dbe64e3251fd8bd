"""Messages published to an input and never taken by it, from the publisher's sequence numbers (ROS-free).

DDS numbers each writer's samples 1, 2, 3, ... and rmw hands the number to
the subscriber with each message it takes (rclpy's message info,
``publication_sequence_number``). A gap in those numbers between two messages
taken is messages published and never taken: lost in transport (a best-effort
sample that never arrived, which DDS reports too: rclpy's ``message_lost``
event, :meth:`DeliveryGaps.lost_in_transport`) or overwritten in the
subscription's queue (a KEEP_LAST queue full while the node did not take from
it: nothing else reports that).

The numbers are per publisher and the message info does not say which one sent
a message, so gaps are not counted while the topic has more than one publisher
(:meth:`DeliveryGaps.publishers`). A number not above the last one starts again
from it (a publisher restarted, or another one replaced it), and so does a
publisher's first message: what it published before this subscriber was matched
is nobody's loss.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import NamedTuple

__all__ = ["Delivery", "DeliveryGaps", "SEQUENCE_UNSUPPORTED", "not_taken_how"]

#: rmw's RMW_MESSAGE_INFO_SEQUENCE_NUMBER_UNSUPPORTED: a middleware that does not number its messages (and any
#: number from this one up) counts nothing
SEQUENCE_UNSUPPORTED = 2**64 - 1


class Delivery(NamedTuple):
    """Messages not taken, since start or in a recent window."""

    not_taken: int  # published and never taken (lost in transport or overwritten in the queue)
    lost_in_transport: int  # of which DDS said they never arrived (only where its loss events are handled)

    @property
    def overwritten(self) -> int:
        """Those not taken that arrived and were overwritten in the queue."""
        return self.not_taken - self.lost_in_transport


@dataclass
class DeliveryGaps:
    """One input's messages published and never taken (module docstring); receive times in seconds on any
    monotonic clock, ``window_s`` the span of :meth:`recent`."""

    window_s: float = 2.0
    loss_events: bool = True  #: whether DDS's loss events come to :meth:`lost_in_transport` (not for a polled input)
    _last: int | None = None  # the sequence number of the last message taken
    _several: bool = False  # the topic has more than one publisher: gaps are not counted
    _not_taken: int = 0
    _lost: int = 0
    _recent: deque[tuple[float, int, int]] = field(default_factory=deque, repr=False)  # (time, not taken, lost)

    def taken(self, now_s: float, sequence: int | None) -> None:
        """A message with the publisher's ``sequence`` number (None: not given) taken at ``now_s``."""
        if sequence is None or sequence >= SEQUENCE_UNSUPPORTED or self._several:
            return
        if self._last is not None and sequence > self._last + 1:
            self._add(now_s, sequence - self._last - 1, 0)
        self._last = sequence

    def lost_in_transport(self, now_s: float, count: int) -> None:
        """DDS says ``count`` more messages never arrived (they are gaps in the numbers taken as well)."""
        if count > 0:
            self._add(now_s, 0, count)

    def publishers(self, count: int) -> None:
        """The topic has ``count`` publishers now: gaps are counted while it has at most one."""
        self._several = count > 1
        if self._several:
            self._last = None

    @property
    def counting(self) -> bool:
        """Whether gaps are counted now (not while the topic has several publishers)."""
        return not self._several

    @property
    def total(self) -> Delivery:
        """Since start; DDS's losses counted once their gap was seen in the messages taken (the next message after
        them taken), so never more than the gaps."""
        return Delivery(self._not_taken, min(self._lost, self._not_taken))

    def recent(self, now_s: float) -> Delivery:
        """In the last ``window_s`` (all since a reset of the receive clock), the losses as in :attr:`total`."""
        if self._recent and now_s < self._recent[-1][0]:  # the receive clock went back
            self._recent.clear()
        while self._recent and self._recent[0][0] < now_s - self.window_s:
            self._recent.popleft()
        not_taken = sum(n for _, n, _ in self._recent)
        return Delivery(not_taken, min(sum(n for _, _, n in self._recent), not_taken))

    def _add(self, now_s: float, not_taken: int, lost: int) -> None:
        self._not_taken += not_taken
        self._lost += lost
        self.recent(now_s)  # the window trimmed: bounded whether or not anyone reads it
        self._recent.append((now_s, not_taken, lost))


def not_taken_how(delivery: Delivery, loss_events: bool, queue: str = "the input's queue") -> str:
    """Where the messages of ``delivery`` not taken went, as a log line says it (``loss_events``: whether DDS's
    losses were counted; ``queue``: the subscription's queue, as the line names it)."""
    if not loss_events:
        return f"lost in transport or overwritten in {queue}"
    return f"{delivery.lost_in_transport} lost in transport, {delivery.overwritten} overwritten in {queue}"
