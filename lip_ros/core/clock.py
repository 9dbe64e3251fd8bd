"""Sensor clocks that step back: a bag played in a loop, a PTP or NTP step, a driver restarted (ROS-free).

A stream's stamps only ever grow, but for messages a transport delivers out of
order (a few ms). A stamp more than :data:`CLOCK_STEP_NS` behind the newest one
of its stream is taken as the clock having stepped back: what was buffered on
the old time line is let go (keeping what does not depend on time, such as a
calibration) and the stream starts again from that stamp.
"""

from __future__ import annotations

__all__ = ["CLOCK_STEP_NS", "stepped_back"]

#: a stamp this far behind its stream's newest is a clock that stepped back, not a message out of order
CLOCK_STEP_NS = 500_000_000


def stepped_back(stamp_ns: int, newest_ns: int | None, tolerance_ns: int = CLOCK_STEP_NS) -> int:
    """How far (ns, > 0) the clock stepped back if ``stamp_ns`` is more than ``tolerance_ns`` behind ``newest_ns``;
    0 otherwise (or without a newest stamp)."""
    if newest_ns is None or newest_ns - stamp_ns <= tolerance_ns:
        return 0
    return int(newest_ns - stamp_ns)
