"""The suit's clock against the LiDAR's, from one vertical jump seen by both (HSC4D's time sync), ROS-free.

Every HSC4D capture starts with the A-pose, then a jump in place. The suit
sees the jump as free fall: the pelvis IMU's specific force drops to nearly
zero between take-off and landing (:func:`suit_apex`); the middle of that
flight is the apex, stamped on the suit's clock. The LiDAR odometry sees the
jump as a parabola of the sensor's height, which is rigid to the pelvis
(:func:`lidar_apex`): the frames of each rise above the standing height, near
its highest, are fitted with the parabola of free fall (the curvature is
gravity's, so two frames fix it), whose vertex is the apex on the LiDAR's
clock, between frames; a rise that does not fall freely (the arms swung
before take-off) is not the jump. The offset is
suit apex minus LiDAR apex (:class:`JumpSync` collects both streams online,
bounded, and says what it waits for).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from lip_ros.core.frames import GRAVITY

__all__ = ["JumpSyncConfig", "suit_apex", "lidar_apex", "JumpSync"]


@dataclass(frozen=True)
class JumpSyncConfig:
    """What a jump looks like to each sensor."""

    free_fall: float = 0.6  # specific force (averaged over smooth_s) below this fraction of gravity: in the air
    smooth_s: float = 0.05
    min_flight_s: float = 0.15  # shorter dips of the specific force are not a jump
    max_flight_s: float = 1.0  # longer ones are not a jump in place (a fall, a sensor fault)
    min_rise_m: float = 0.05  # the LiDAR's height rises this much above its median in a jump
    flight_margin_s: float = 0.02  # LiDAR frames this close to take-off or landing are not fitted
    # a rise whose frames fit the free-fall parabola this much worse (RMS) than the best-fitting rise's is not the
    # jump (at 20 Hz the arms' swing before take-off lifts the hip 5-15 cm for five sweeps: a rise of its own)
    fit_tolerance_m: float = 0.03
    max_offset_s: float = 2.0  # the clocks are at most this far apart
    buffer_s: float = 30.0  # data kept while waiting for the jump

    def __post_init__(self) -> None:
        if not (0.0 < self.free_fall < 1.0 and self.smooth_s >= 0.0 and 0.0 < self.min_flight_s < self.max_flight_s
                and self.min_rise_m > 0.0 and self.flight_margin_s >= 0.0 and self.fit_tolerance_m > 0.0
                and self.max_offset_s > 0.0
                and self.buffer_s > self.max_flight_s):
            raise ValueError(f"invalid {self}")


def _crossing(t: np.ndarray, value: np.ndarray, k: int, level: float) -> float:
    """The time between samples k and k + 1 where ``value`` crosses ``level`` (linear)."""
    a, b = value[k], value[k + 1]
    w = 0.0 if a == b else (level - a) / (b - a)
    return float(t[k] + np.clip(w, 0.0, 1.0) * (t[k + 1] - t[k]))


def suit_apex(stamp_ns: np.ndarray, specific_force: np.ndarray, config: JumpSyncConfig | None = None
              ) -> tuple[float, float] | None:
    """The first jump in the pelvis IMU's specific force (N, 3) or its norm (N,), at ``stamp_ns`` (N,) sorted:
    (apex time ns, flight s), None if there is none."""
    c = config or JumpSyncConfig()
    t = np.asarray(stamp_ns, dtype=np.float64)
    force = np.asarray(specific_force, dtype=np.float64)
    norm = np.linalg.norm(force, axis=-1) if force.ndim == 2 else force
    if t.size < 2:
        return None
    width = max(1, int(round(c.smooth_s * 1e9 / max(float(np.median(np.diff(t))), 1.0))))
    norm = np.convolve(np.pad(norm, (width // 2, width - 1 - width // 2), mode="edge"), np.ones(width) / width,
                       mode="valid")
    level = c.free_fall * GRAVITY
    air = norm < level
    edges = np.flatnonzero(np.diff(air.astype(np.int8)))  # k: air changes between k and k + 1
    starts = edges[~air[edges]]  # on the ground at k, in the air at k + 1
    for k in starts:
        ends = edges[(edges > k) & air[edges]]
        if not ends.size:
            return None  # still in the air at the end of the data
        take_off = _crossing(t, norm, k, level)
        landing = _crossing(t, norm, int(ends[0]), level)
        flight = (landing - take_off) * 1e-9
        if c.min_flight_s <= flight <= c.max_flight_s:
            return 0.5 * (take_off + landing), flight
    return None


def _free_fall_fit(t: np.ndarray, z: np.ndarray, top: int, reach_s: float) -> tuple[float, float] | None:
    """The free-fall parabola through the frames in the air round frame ``top``, those within ``reach_s`` of its
    apex (found from the top frame on): (apex time ns, RMS residual m; 0 with two frames), None with fewer."""
    s = (t - t[top]) * 1e-9  # seconds from the top frame
    apex, residual = 0.0, np.zeros(0)
    for _ in range(3):  # the frames in the air depend on the apex
        air = np.flatnonzero(np.abs(s - apex) <= reach_s)
        if air.size < 2:
            return None
        # z = z_a - g/2 (s - s_a)^2  <=>  z + g/2 s^2 = (z_a - g/2 s_a^2) + g s_a s: a line in s
        y = z[air] + 0.5 * GRAVITY * s[air] ** 2
        slope, intercept = np.polyfit(s[air], y, 1)
        apex, residual = slope / GRAVITY, y - (intercept + slope * s[air])
    return float(t[top] + apex * 1e9), float(np.sqrt(np.mean(residual**2)))


def lidar_apex(stamp_ns: np.ndarray, height_m: np.ndarray, flight_s: float, config: JumpSyncConfig | None = None,
               near_ns: float | None = None) -> float | None:
    """The apex time (ns) of a jump in the sensor's height trajectory (N,) at ``stamp_ns`` (N,) sorted, a jump
    whose flight lasts ``flight_s`` (the suit's): each run of frames ``min_rise_m`` above the median height is
    fitted with the free-fall parabola through its frames in the air (those within half the flight, less
    ``flight_margin_s``, of the apex, found from its highest frame on); of the runs that fall freely (an RMS
    residual within ``fit_tolerance_m`` of the best fit's), the first, or the one whose apex is nearest
    ``near_ns`` (None: no jump, or fewer than two frames in the air)."""
    c = config or JumpSyncConfig()
    t = np.asarray(stamp_ns, dtype=np.int64)
    z = np.asarray(height_m, dtype=np.float64)
    up = z > np.median(z) + c.min_rise_m if z.size else np.zeros(0, dtype=bool)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], up.astype(np.int8), [0]])))
    reach = max(0.5 * flight_s - c.flight_margin_s, 0.0)
    fits = [f for a, b in edges.reshape(-1, 2)  # [first, end) of each run above
            if (f := _free_fall_fit(t, z, a + int(np.argmax(z[a:b])), reach)) is not None]
    if not fits:
        return None
    best = min(rms for _, rms in fits)
    apexes = np.array([apex for apex, rms in fits if rms <= best + c.fit_tolerance_m])
    return float(apexes[0] if near_ns is None else apexes[np.argmin(np.abs(apexes - near_ns))])


class JumpSync:
    """Online: the suit's pelvis specific force and the LiDAR's height come in; once the jump is in both, the
    offset of the suit's clock (ns; suit stamp = LiDAR stamp + offset) is :attr:`offset_ns`."""

    def __init__(self, config: JumpSyncConfig | None = None) -> None:
        self.config = config or JumpSyncConfig()
        self._suit: deque[tuple[int, float]] = deque()
        self._lidar: deque[tuple[int, float]] = deque()
        self.suit_apex_ns: float | None = None
        self._landed_ns: int | None = None  # the suit's force last came back above free fall here
        self.flight_s = 0.0  # of the jump the suit saw
        self.offset_ns: int | None = None
        #: the flights (s) of the jumps the suit saw but the LiDAR could not fit (too short for its frame rate)
        self.missed: deque[float] = deque(maxlen=10)

    @property
    def status(self) -> str:
        """What the sync waits for, or the offset found."""
        if self.offset_ns is not None:
            return f"synced: the suit's clock is {self.offset_ns * 1e-6:+.1f} ms from the LiDAR's"
        if self.suit_apex_ns is None:
            if self.missed:
                return (f"waiting for a jump: the LiDAR could not follow the last one (flight {self.missed[-1]:.2f} s"
                        "; it needs two frames in the air): jump higher")
            return "waiting for the jump (in the suit's data)"
        return "jump seen by the suit, waiting for the LiDAR to see it"

    def set_offset(self, offset_ns: int) -> None:
        """Take the suit's clock offset as known without a jump (a resumed trajectory)."""
        self.offset_ns = int(offset_ns)

    def add_suit(self, stamp_ns: int, specific_force: np.ndarray) -> None:
        """One pelvis IMU sample (specific force (3,) in any frame)."""
        if self.offset_ns is not None:
            return
        norm = float(np.linalg.norm(specific_force))
        if self._suit and self._suit[-1][1] < self.config.free_fall * GRAVITY <= norm:
            self._landed_ns = stamp_ns  # a flight may have ended: look once the smoothing has passed it
        _append(self._suit, stamp_ns, norm, self.config.buffer_s)
        if (self.suit_apex_ns is None and self._landed_ns is not None
                and stamp_ns - self._landed_ns >= self.config.smooth_s * 1e9):
            self._landed_ns = None
            t, force = np.array([s[0] for s in self._suit]), np.array([s[1] for s in self._suit])
            found = suit_apex(t, force, self.config)
            if found is not None:
                self.suit_apex_ns, self.flight_s = found
        self._try()

    def add_lidar(self, stamp_ns: int, height_m: float) -> None:
        """One LiDAR pose's height (z of the sensor in a gravity-aligned map)."""
        if self.offset_ns is not None:
            return
        _append(self._lidar, stamp_ns, float(height_m), self.config.buffer_s)
        self._try()

    def _try(self) -> None:
        """Once the LiDAR data covers the window where the jump can be on its clock, find its apex there."""
        if self.suit_apex_ns is None or not self._lidar:
            return
        reach = (self.config.max_offset_s + self.config.max_flight_s) * 1e9
        if self._lidar[-1][0] < self.suit_apex_ns + reach:
            return
        t = np.array([s[0] for s in self._lidar])
        window = np.abs(t - self.suit_apex_ns) <= reach
        apex = lidar_apex(t[window], np.array([s[1] for s in self._lidar])[window], self.flight_s, self.config,
                          near_ns=self.suit_apex_ns)
        if apex is not None:
            self.offset_ns = int(round(self.suit_apex_ns - apex))
        else:  # look for the next jump, after this one's landing
            self.missed.append(self.flight_s)
            landed = self.suit_apex_ns + 0.5 * self.flight_s * 1e9
            while self._suit and self._suit[0][0] <= landed:
                self._suit.popleft()
            self.suit_apex_ns = None


def _append(buffer: deque[tuple[int, float]], stamp_ns: int, value: float, keep_s: float) -> None:
    """Add a sample; drop those older than ``keep_s`` before it."""
    buffer.append((int(stamp_ns), value))
    while buffer[0][0] < stamp_ns - keep_s * 1e9:
        buffer.popleft()
