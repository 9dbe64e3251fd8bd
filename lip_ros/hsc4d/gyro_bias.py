"""The pelvis gyro's bias from the times the wearer stands still, ROS-free.

Where a sweep pins no turn (bare ground, an open field), the LiDAR's heading is
held to the pelvis IMU's integrated rate, so the gyro's bias turns the whole
walk (the rig's 0.1 deg/s per axis turned its open field's seed 0 by 1.4 deg in
14 s; with the rig's gyro biases set to zero 0.2 deg, and its error at 28 s
47 -> 38 cm). The LiDAR cannot measure that bias there either: its registration
follows the same integrated rate about the axes the scene leaves free (on the
rig's open field the LiDAR-referenced estimate about the pelvis's vertical axis
read 0.001-0.035 against a true 0.06-0.16 deg/s). Standing still, the rate the
gyro reads is its bias, which is what a zero-velocity detector estimates in
pedestrian navigation: every capture starts with the still A-pose.

:class:`GyroBias` takes the pelvis samples as they arrive and averages the gyro
over every run of samples that read still (the rate under ``max_rate_rad_s``)
for at least ``min_still_s`` once ``trim_s`` is left out at both ends of the
run (the onset of motion reads still for a few samples). A wearer who turns by an angle a
during a run of T seconds moves the estimate by a / T; how far a person holding
an A-pose turns the pelvis is not measured here (the rig's own A-pose is
perfectly still; its ``sway_deg`` variant sways it: 0.3 deg read as 0.042
deg/s of bias, docs/hsc4d/trajectory.md "The pelvis gyro's bias"). The bias's
own drift (the DOT's in-run stability is about 10 deg/h) is too slow to matter
over a capture, so the runs are pooled, each weighted by its span.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from lip_ros.core.clock import stepped_back

__all__ = ["GyroBias", "GyroBiasConfig"]


@dataclass(frozen=True)
class GyroBiasConfig:
    """When the pelvis IMU reads still, and for how long it must, to measure its gyro's bias."""

    max_rate_rad_s: float = 0.03  # 1.7 deg/s: a biased still gyro reads tenths; a walking pelvis tens of deg/s
    min_still_s: float = 1.0  # a still run counts once it is this long (trimmed)
    trim_s: float = 0.25  # left out at both ends of each still run

    def __post_init__(self) -> None:
        if not (self.max_rate_rad_s > 0.0 and self.min_still_s > 0.0
                and self.trim_s >= 0.0):
            raise ValueError(f"invalid {self}")


class GyroBias:
    """The gyro's bias (rad/s, in the sensor's frame) from its still runs; samples in time order."""

    def __init__(self, config: GyroBiasConfig | None = None, max_gap_ns: int = 50_000_000) -> None:
        self.config = config or GyroBiasConfig()
        self.max_gap_ns = int(max_gap_ns)  #: samples further apart than this end a still run (what was between is
        #   not known)
        self._weighted = np.zeros(3)  # the mean gyro of each run that counted times its span (s)
        self._seconds = 0.0  # their spans
        self._last_ns: int | None = None
        self._run_start_ns: int | None = None  # the current still run's first sample
        self._tail: deque[tuple[int, np.ndarray]] = deque()  # its last trim_s, not yet summed
        self._run_sum = np.zeros(3)  # its samples past the trimmed start and before the tail
        self._run_count = 0
        self._run_first_ns = 0  # the first of those
        self._run_last_ns = 0  # and the last

    @property
    def value(self) -> np.ndarray:
        """The bias (3,) rad/s: the mean gyro over the still runs so far (the current one once it is long enough),
        each weighted by its span; zero before any."""
        weighted, seconds = self._weighted, self._seconds
        if self._run_long_enough():
            span = self._run_span_s()
            weighted, seconds = weighted + self._run_sum / self._run_count * span, seconds + span
        return weighted / seconds if seconds > 0.0 else np.zeros(3)

    @property
    def still_s(self) -> float:
        """How much still time (s, trimmed) the estimate averages."""
        return self._seconds + (self._run_span_s() if self._run_long_enough() else 0.0)

    def start_from(self, bias: np.ndarray, still_s: float) -> None:
        """Take ``bias`` (3,) rad/s, measured over ``still_s`` of still runs before (a restarted process's), as if
        those runs had been seen here too (pooled with any seen already)."""
        self._weighted = self._weighted + np.asarray(bias, dtype=np.float64) * float(still_s)
        self._seconds += float(still_s)

    def add(self, stamp_ns: int, gyro: np.ndarray) -> None:
        """One sample's gyro (rad/s); only the rate tells stillness here (the bias needs the pelvis not turning, a
        steady glide does no harm), so no accelerometer scale or local gravity enters. One out of time order is
        left out, one far
        behind the last (a clock step back, :func:`lip_ros.core.clock.stepped_back`) ends the run and starts the
        time line again."""
        if stepped_back(stamp_ns, self._last_ns):
            self._end_run()
            self._last_ns = None
        if self._last_ns is not None and stamp_ns <= self._last_ns:
            return
        c = self.config
        gap = self._last_ns is not None and stamp_ns - self._last_ns > self.max_gap_ns
        self._last_ns = stamp_ns
        still = float(np.linalg.norm(gyro)) < c.max_rate_rad_s
        if gap or not still:
            self._end_run()
        if not still:
            return
        if self._run_start_ns is None:
            self._run_start_ns = stamp_ns
        self._tail.append((stamp_ns, np.asarray(gyro, dtype=np.float64)))
        trim_ns = int(c.trim_s * 1e9)
        while self._tail and stamp_ns - self._tail[0][0] > trim_ns:
            t, w = self._tail.popleft()
            if t - self._run_start_ns >= trim_ns:
                if not self._run_count:
                    self._run_first_ns = t
                self._run_sum += w
                self._run_count += 1
                self._run_last_ns = t

    def _run_span_s(self) -> float:
        return (self._run_last_ns - self._run_first_ns) * 1e-9 if self._run_count else 0.0

    def _run_long_enough(self) -> bool:
        return self._run_span_s() >= self.config.min_still_s

    def _end_run(self) -> None:
        if self._run_long_enough():
            span = self._run_span_s()
            self._weighted = self._weighted + self._run_sum / self._run_count * span
            self._seconds += span
        self._run_start_ns = None
        self._tail.clear()
        self._run_sum = np.zeros(3)
        self._run_count = 0
