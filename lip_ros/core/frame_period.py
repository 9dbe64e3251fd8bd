"""A periodic sensor's frame period, measured from its stamps (ROS-free).

A spinning LiDAR runs at the rate it was configured for (an Ouster at 10 or
20 Hz, its ``lidar_mode``), which a node's parameter may not match. The
period is the median of the latest intervals between consecutive stamps: a
frame dropped now and then (an interval of two periods) or a clock step (an
interval out of all proportion, or negative) does not move it.
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["FramePeriod"]


class FramePeriod:
    """The median interval of the latest ``window`` between consecutive, increasing stamps; known after
    ``min_intervals``."""

    def __init__(self, window: int = 9, min_intervals: int = 5) -> None:
        if not 1 <= min_intervals <= window:
            raise ValueError(f"need 1 <= min_intervals <= window, got {min_intervals}, {window}")
        self.min_intervals = min_intervals
        self._intervals: deque[int] = deque(maxlen=window)
        self._last_ns: int | None = None

    def add(self, stamp_ns: int) -> None:
        """The stamp (ns) of the next frame; one before the last starts the intervals again (a clock step), the
        same stamp again is no interval."""
        if self._last_ns is not None and stamp_ns == self._last_ns:
            return
        if self._last_ns is not None and stamp_ns > self._last_ns:
            self._intervals.append(stamp_ns - self._last_ns)
        elif self._last_ns is not None:
            self._intervals.clear()
        self._last_ns = stamp_ns

    @property
    def period_s(self) -> float | None:
        """The frame period (s), None until ``min_intervals`` intervals are known."""
        if len(self._intervals) < self.min_intervals:
            return None
        return float(np.median(self._intervals)) * 1e-9

    @property
    def rate_hz(self) -> float | None:
        """1 / :attr:`period_s`, None until known."""
        period = self.period_s
        return None if period is None else 1.0 / period
