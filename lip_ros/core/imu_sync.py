"""IMU samples at a LiDAR frame's time: per-sensor buffers and interpolation (ROS-free).

A LiDAR frame's pose holds at its *effective* time, ``header.stamp`` plus the
mean ``t`` of the performer's points (docs/conventions.md, "Time"). Each IMU
is interpolated to that time ``t``: orientation ``R_I_S`` by slerp (shortest
arc, so q and -q are one rotation), angular velocity and specific force (both
in the sensor frame S) linearly.

Per sensor and query the outcome is

* ``OK``: samples on both sides of ``t`` at most ``max_gap_ns`` apart, interpolated
  (or a sample exactly at ``t``);
* ``HELD``: no such pair, but the last sample before ``t`` is at most
  ``max_hold_ns`` old; its values are held and ``age_ns = t - its stamp`` says
  how old they are;
* ``MISSING``: no sample before ``t``, or the last one is too old; the values are NaN.

A frame is ``OK`` when every sensor is, ``DEGRADED`` when some are only held,
``SKIP`` when any is missing; ``reason`` says which and why.

Online, :class:`ImuSynchronizer` keeps a bounded, sorted buffer per sensor
(out-of-order samples are inserted in place; a repeated stamp keeps the first
sample; invalid samples are rejected with a reason; a sensor whose stamps step
back, :mod:`lip_ros.core.clock`, starts its buffer again from the first sample
of the new time line, once the second confirms the step). A node asks for ``t`` once
:meth:`ImuSynchronizer.ready` says so: every sensor has a sample at or after
``t + settle_ns``, or ``wait_ns`` passed since ``t``. The latency this implies
is one IMU period (about 17 ms at 60 Hz) plus ``settle_ns`` plus the transport
delay of the IMU messages, beyond the LiDAR frame's own.

Offline, :func:`sync_batch` does the same over whole recordings, with
bit-for-bit the same results as feeding the samples to an
:class:`ImuSynchronizer` in the given (arrival) order and querying each time
once it is ready, provided that no query was forced by ``wait_ns`` while a
sample it needed was still on its way, that ``settle_ns`` covers the largest
reordering in transport plus one sample period, that the buffers did not
overflow and that no sensor's clock stepped back.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Protocol

import numpy as np

from lip_ros.core.clock import CLOCK_STEP_NS, stepped_back
from lip_ros.core.rotations import axis_angle_to_matrix

__all__ = [
    "SensorStatus",
    "FrameStatus",
    "SyncConfig",
    "ImuArrays",
    "ImuSampleLike",
    "ImuSeries",
    "SyncResult",
    "ImuSynchronizer",
    "sync_batch",
]

_QUAT, _GYRO, _ACCEL = slice(0, 4), slice(4, 7), slice(7, 10)
_WIDTH = 10  # quat (4), gyro (3), accel (3) per sample
_SLERP_LINEAR = 1e-6  # below this sin(angle) slerp falls back to a linear blend


class SensorStatus(str, Enum):
    """How a sensor's values at the query time were obtained."""

    OK = "ok"
    HELD = "held"
    MISSING = "missing"


class FrameStatus(str, Enum):
    """Whether a frame can be processed: all sensors OK, some HELD (degraded), or some MISSING (skip)."""

    OK = "ok"
    DEGRADED = "degraded"
    SKIP = "skip"


@dataclass(frozen=True)
class SyncConfig:
    """Buffer size, gap and hold bounds and readiness rules (integer nanoseconds)."""

    capacity: int = 1024  # samples kept per sensor (about 17 s at 60 Hz)
    max_gap_ns: int = 60_000_000  # widest stamp gap interpolated across (two lost samples at 60 Hz)
    max_hold_ns: int = 100_000_000  # oldest a held sample may be
    settle_ns: int = 0  # ready() wants data this far past t (reordering in transport + a period)
    wait_ns: int = 200_000_000  # ready() stops waiting this long after t
    quat_norm_tolerance: float = 1e-3  # quaternions farther from unit norm are rejected
    max_clock_gap_ns: int = 10_000_000_000  # a time this far outside the buffered samples is on another clock
    #: per sensor, in the synchroniser's order: how much later than its measurement a sample is stamped (a driver
    #: that stamps on arrival); subtracted from every stamp on the way in. () = none
    latency_ns: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if self.capacity < 2 or min(self.max_gap_ns, self.max_hold_ns, self.settle_ns, self.wait_ns,
                                    self.max_clock_gap_ns, *self.latency_ns) < 0:
            raise ValueError(f"invalid {self}")


class ImuArrays(Protocol):
    """Anything with a sensor's samples as arrays (e.g. :class:`ImuSeries`, ``lip_ros.rig.imu.ImuStream``)."""

    stamp_ns: np.ndarray  # (N,) int64
    quat: np.ndarray  # (N, 4) R_I_S, (x, y, z, w)
    gyro: np.ndarray  # (N, 3) rad/s in S
    accel: np.ndarray  # (N, 3) specific force, m/s^2 in S


_REJECTS = (
    "orientation not finite",
    "angular velocity not finite",
    "acceleration not finite",
    "quaternion not unit",
    "stamp not positive",
)


def _validate(
    stamp_ns: np.ndarray, quat: np.ndarray, gyro: np.ndarray, accel: np.ndarray, tolerance: float
) -> tuple[np.ndarray, np.ndarray]:
    """Samples as (N, 10) rows [unit quat, gyro, accel] and each one's rejection code (-1: valid, else _REJECTS)."""
    rows = np.concatenate(
        [np.asarray(quat, np.float64), np.asarray(gyro, np.float64), np.asarray(accel, np.float64)], axis=1
    )
    finite = np.isfinite(rows)
    norm = np.sqrt(np.sum(np.where(finite[:, _QUAT], rows[:, _QUAT], 0.0) ** 2, axis=1))
    bad = np.stack([
        ~finite[:, _QUAT].all(axis=1),
        ~finite[:, _GYRO].all(axis=1),
        ~finite[:, _ACCEL].all(axis=1),
        np.abs(norm - 1.0) > tolerance,
        np.asarray(stamp_ns) <= 0,
    ])
    code = np.where(bad.any(axis=0), np.argmax(bad, axis=0), -1)  # the first failing check
    good = code < 0
    rows[good, _QUAT] /= norm[good, None]
    return rows, code


@dataclass(frozen=True, eq=False)
class ImuSeries:
    """One sensor's valid samples, sorted by stamp, stamps unique (the arrays of :class:`ImuArrays`)."""

    stamp_ns: np.ndarray
    quat: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray

    @classmethod
    def clean(cls, samples: ImuArrays, quat_norm_tolerance: float = 1e-3) -> tuple[ImuSeries, Counter[str]]:
        """Samples in arrival order -> valid ones sorted (a repeated stamp keeps the first), and rejects by reason."""
        stamp_ns = np.asarray(samples.stamp_ns, dtype=np.int64)
        rows, code = _validate(stamp_ns, samples.quat, samples.gyro, samples.accel, quat_norm_tolerance)
        rejected = Counter(_REJECTS[c] for c in code[code >= 0])
        good = np.flatnonzero(code < 0)
        _, first = np.unique(stamp_ns[good], return_index=True)  # sorted, first occurrence of each stamp
        if good.size > first.size:
            rejected["duplicate stamp"] += good.size - first.size
        keep = good[first]
        rows = rows[keep]
        return cls(stamp_ns[keep], rows[:, _QUAT], rows[:, _GYRO], rows[:, _ACCEL]), rejected

    def _rows(self) -> np.ndarray:
        return np.concatenate([self.quat, self.gyro, self.accel], axis=1)


@dataclass(frozen=True, eq=False)
class SyncResult:
    """All sensors at one time ``t_ns``; arrays in ``names`` order, NaN where MISSING."""

    t_ns: int
    names: tuple[str, ...]
    quat: np.ndarray  # (S, 4) R_I_S at t, (x, y, z, w), w >= 0
    gyro: np.ndarray  # (S, 3) rad/s in S
    accel: np.ndarray  # (S, 3) specific force in S, m/s^2
    status: tuple[SensorStatus, ...]
    age_ns: np.ndarray  # (S,) int64: t minus the held sample's stamp (HELD), else 0
    reasons: tuple[str, ...]  # per sensor, "" when OK

    @property
    def frame_status(self) -> FrameStatus:
        """SKIP if a sensor is missing, DEGRADED if one is held, else OK."""
        if SensorStatus.MISSING in self.status:
            return FrameStatus.SKIP
        return FrameStatus.DEGRADED if SensorStatus.HELD in self.status else FrameStatus.OK

    @property
    def reason(self) -> str:
        """Why the frame is not OK ("" if it is)."""
        return "; ".join(f"{n}: {r}" for n, r in zip(self.names, self.reasons) if r)

    def same_as(self, other: SyncResult) -> bool:
        """Bit-for-bit equality (NaN equal to NaN)."""
        return (
            self.t_ns == other.t_ns
            and self.names == other.names
            and self.status == other.status
            and self.reasons == other.reasons
            and all(
                np.array_equal(a, b, equal_nan=True)
                for a, b in zip((self.quat, self.gyro, self.accel, self.age_ns),
                                (other.quat, other.gyro, other.accel, other.age_ns))
            )
        )


def _linear(columns: slice) -> Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    """A blend for :meth:`ImuSynchronizer._bracketed`: the rows' ``columns`` interpolated linearly."""
    return lambda a, b, w: (1.0 - w)[:, None] * a[:, columns] + w[:, None] * b[:, columns]


def _slerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Shortest-arc slerp of unit quaternions (T, 4) at weights (T,), normalised, w >= 0."""
    dot = np.sum(q0 * q1, axis=1)
    q1 = np.where(dot[:, None] < 0.0, -q1, q1)
    theta = np.arccos(np.minimum(np.abs(dot), 1.0))
    sin = np.sin(theta)
    linear = sin < _SLERP_LINEAR
    safe = np.where(linear, 1.0, sin)
    w0 = np.where(linear, 1.0 - w, np.sin((1.0 - w) * theta) / safe)
    w1 = np.where(linear, w, np.sin(w * theta) / safe)
    q = w0[:, None] * q0 + w1[:, None] * q1
    q /= np.sqrt(np.sum(q * q, axis=1))[:, None]
    return np.where(q[:, 3:4] < 0.0, -q, q)


def _ms(ns: int) -> str:
    return f"{ns * 1e-6:.0f} ms"


_PerSensor = tuple[np.ndarray, list[SensorStatus], np.ndarray, list[str]]  # values, status, age_ns, reasons


def _bracket(stamps: np.ndarray, t: np.ndarray, config: SyncConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For times ``t`` in sorted unique ``stamps`` (not empty): the last sample at or before each (-1: none), the
    first after it, and whether it can be interpolated (an exact sample, or a pair at most ``max_gap_ns`` apart)."""
    after = np.searchsorted(stamps, t, side="right")
    before = after - 1
    lo, hi = np.maximum(before, 0), np.minimum(after, stamps.size - 1)
    exact = (before >= 0) & (stamps[lo] == t)
    pair = (before >= 0) & (after < stamps.size) & (stamps[hi] - stamps[lo] <= config.max_gap_ns)
    return before, after, exact | pair


def _weights(stamps: np.ndarray, t: np.ndarray, lo: np.ndarray, hi: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Interpolation weights of the samples ``hi`` at the times ``t[ok]`` (0 on an exact sample)."""
    s0, s1 = stamps[lo[ok]], stamps[hi[ok]]
    return np.where(s1 == s0, 0.0, (t[ok] - s0).astype(np.float64) / np.maximum(s1 - s0, 1).astype(np.float64))


def _interpolate(
    stamps: np.ndarray, rows: np.ndarray, t: np.ndarray, config: SyncConfig, evicted: bool = False
) -> _PerSensor:
    """One sensor's sorted unique samples at times ``t`` (T,): values (T, 10), status, age_ns, reasons."""
    n, count = t.size, stamps.size
    out = np.full((n, _WIDTH), np.nan)
    status = [SensorStatus.MISSING] * n
    age = np.zeros(n, dtype=np.int64)
    reasons = ["no data"] * n
    if count == 0:
        return out, status, age, reasons
    before, after, ok = _bracket(stamps, t, config)
    lo, hi = np.maximum(before, 0), np.minimum(after, count - 1)
    if ok.any():
        w = _weights(stamps, t, lo, hi, ok)
        r0, r1 = rows[lo[ok]], rows[hi[ok]]
        out[ok, _QUAT] = _slerp(r0[:, _QUAT], r1[:, _QUAT], w)
        out[ok, 4:] = (1.0 - w)[:, None] * r0[:, 4:] + w[:, None] * r1[:, 4:]
    # no bracketing pair: hold the last sample before t
    held_age = t - stamps[lo]
    held = ~ok & (before >= 0) & (held_age <= config.max_hold_ns)
    out[held] = rows[lo[held]]
    age[held] = held_age[held]
    for i in range(n):
        if ok[i]:
            status[i], reasons[i] = SensorStatus.OK, ""
        elif before[i] < 0:
            reasons[i] = "older than the buffered data" if evicted else "no sample before t"
        elif held[i]:
            status[i] = SensorStatus.HELD
            why = "no sample after t" if after[i] >= count else f"gap of {_ms(stamps[hi[i]] - stamps[lo[i]])}"
            reasons[i] = f"{why}, holding a sample {_ms(held_age[i])} old"
        else:
            reasons[i] = f"last sample {_ms(held_age[i])} old (hold bound {_ms(config.max_hold_ns)})"
    return out, status, age, reasons


def _assemble(names: tuple[str, ...], t: np.ndarray, per_sensor: list[_PerSensor]) -> list[SyncResult]:
    values = np.stack([p[0] for p in per_sensor], axis=1)  # (T, S, 10)
    ages = np.stack([p[2] for p in per_sensor], axis=1)
    return [
        SyncResult(
            t_ns=int(t[k]),
            names=names,
            quat=values[k, :, _QUAT],
            gyro=values[k, :, _GYRO],
            accel=values[k, :, _ACCEL],
            status=tuple(p[1][k] for p in per_sensor),
            age_ns=ages[k],
            reasons=tuple(p[3][k] for p in per_sensor),
        )
        for k in range(t.size)
    ]


class _Buffer:
    """Sorted samples of one sensor, at most ``capacity``, in a 2x array that is compacted when full."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self._stamps = np.zeros(2 * capacity, dtype=np.int64)
        self._rows = np.zeros((2 * capacity, _WIDTH))
        self._start = self._end = 0
        self.evicted = False

    @property
    def stamps(self) -> np.ndarray:
        """(N,) sorted unique stamps."""
        return self._stamps[self._start : self._end]

    @property
    def rows(self) -> np.ndarray:
        """(N, 10) samples in stamp order."""
        return self._rows[self._start : self._end]

    def insert(self, stamp_ns: int, row: np.ndarray) -> str | None:
        """Insert in stamp order, evicting the oldest when full; the rejection reason if not kept."""
        stamps = self.stamps
        pos = int(np.searchsorted(stamps, stamp_ns))
        if pos < stamps.size and stamps[pos] == stamp_ns:
            return "duplicate stamp"
        if pos == 0 and (self.evicted or stamps.size == self.capacity):
            self.evicted = True
            return "older than the buffered data"
        if self._end == self._stamps.size:  # compact; no overlap, as _start >= capacity >= count
            count = self._end - self._start
            self._stamps[:count] = self._stamps[self._start : self._end]
            self._rows[:count] = self._rows[self._start : self._end]
            self._start, self._end = 0, count
        at = self._start + pos
        self._stamps[at + 1 : self._end + 1] = self._stamps[at : self._end]  # numpy copes with the overlap
        self._rows[at + 1 : self._end + 1] = self._rows[at : self._end]
        self._stamps[at], self._rows[at] = stamp_ns, row
        self._end += 1
        if self._end - self._start > self.capacity:
            self._start += 1
            self.evicted = True
        return None

    def shift(self, delta_ns: int) -> None:
        """Move every stamp by ``delta_ns`` (the order stays)."""
        self._stamps[self._start : self._end] += delta_ns


class ImuSampleLike(Protocol):
    """One measurement, e.g. a ``lip_msgs_py.imu.ImuSample`` (NaN components are rejected)."""

    stamp_ns: int
    quat: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray


class ImuSynchronizer:
    """Online per-sensor buffers of the sensors ``names``, queried at LiDAR frame times."""

    def __init__(self, names: Iterable[str], config: SyncConfig | None = None) -> None:
        self.names = tuple(names)
        self.config = config or SyncConfig()
        latency = self.config.latency_ns or (0,) * len(self.names)
        if len(latency) != len(self.names):
            raise ValueError(f"latency_ns has {len(latency)} values for the {len(self.names)} sensors {self.names}")
        self._latency_ns = dict(zip(self.names, latency))
        self._buffers = {n: _Buffer(self.config.capacity) for n in self.names}
        self.rejected: dict[str, Counter[str]] = {n: Counter() for n in self.names}
        #: per sensor, how often its stamps stepped back (lip_ros.core.clock): its buffer was emptied each time
        self.clock_steps: dict[str, int] = dict.fromkeys(self.names, 0)
        self.last_clock_step_ns = 0  # how far back the latest step went
        #: per sensor, the last sample (measurement time, row) if it was far behind the newest
        self._behind: dict[str, tuple[int, np.ndarray] | None] = dict.fromkeys(self.names)

    def add(self, name: str, sample: ImuSampleLike) -> str | None:
        """Buffer one sample of sensor ``name``; returns why it was rejected, None if kept."""
        rows, codes = self.validate([sample])
        return self.insert(name, int(sample.stamp_ns), rows[0], int(codes[0]))

    def validate(self, samples: Sequence[ImuSampleLike]) -> tuple[np.ndarray, np.ndarray]:
        """Samples as (N, 10) rows [unit quat, gyro, accel] and rejection codes (-1: valid) for :meth:`insert`;
        many at once cost about what one does, and each row is what validating it alone gives."""
        return _validate(
            np.array([s.stamp_ns for s in samples], dtype=np.int64),
            np.reshape([s.quat for s in samples], (-1, 4)),
            np.reshape([s.gyro for s in samples], (-1, 3)),
            np.reshape([s.accel for s in samples], (-1, 3)),
            self.config.quat_norm_tolerance,
        )

    def measured_ns(self, name: str, stamp_ns: int) -> int:
        """When a sample of ``name`` stamped ``stamp_ns`` was measured: its stamp less the sensor's latency."""
        return stamp_ns - self._latency_ns[name]

    def latency_ns(self, name: str) -> int:
        """How much later than measured the samples of ``name`` are stamped (taken off on the way in)."""
        return self._latency_ns[name]

    def set_latency(self, name: str, latency_ns: int) -> None:
        """Take ``latency_ns`` off the stamps of ``name`` from now on, and off those buffered (moved to match)."""
        self._buffers[name].shift(self._latency_ns[name] - latency_ns)
        self._latency_ns[name] = latency_ns

    def orientations(self, name: str, stamp_ns: np.ndarray) -> np.ndarray:
        """R_I_S (T, 4) of ``name`` interpolated at the measurement times of samples stamped ``stamp_ns`` (T,), NaN
        where the buffer does not bracket them (nothing is held)."""
        return self._bracketed(name, stamp_ns, 4, lambda a, b, w: _slerp(a[:, _QUAT], b[:, _QUAT], w))

    def specific_forces(self, name: str, stamp_ns: np.ndarray) -> np.ndarray:
        """Specific force (T, 3) in the sensor frame of ``name`` interpolated linearly at the measurement times of
        samples stamped ``stamp_ns`` (T,), NaN where the buffer does not bracket them (nothing is held)."""
        return self._bracketed(name, stamp_ns, 3, _linear(_ACCEL))

    def angular_rates(self, name: str, stamp_ns: np.ndarray) -> np.ndarray:
        """Angular rate (T, 3; rad/s) in the sensor frame of ``name`` interpolated linearly at the measurement times
        of samples stamped ``stamp_ns`` (T,), NaN where the buffer does not bracket them (nothing is held)."""
        return self._bracketed(name, stamp_ns, 3, _linear(_GYRO))

    def relative_rotations(self, name: str, stamp_ns: np.ndarray, ref_ns: int, bias: np.ndarray | None = None
                           ) -> np.ndarray:
        """R_Sref_S (T, 3, 3) of ``name``: its angular rate, less ``bias`` (3,) if given, integrated from the
        measurement time of a sample stamped ``ref_ns`` to those of samples stamped ``stamp_ns`` (T,) (the rate
        interpolated linearly, the turn of each step about its mean rate), so that its orientation output's errors
        (a fusion filter's tilt and heading corrections) do not enter; NaN where the buffer does not bracket a time
        or the samples between leave a gap over ``max_gap_ns``."""
        stamps, rows = self._buffers[name].stamps, self._buffers[name].rows
        times = np.append(np.asarray(stamp_ns, dtype=np.int64), np.int64(ref_ns)) - self._latency_ns[name]
        out = np.full((times.size - 1, 3, 3), np.nan)
        if not stamps.size:
            return out
        before, _, ok = _bracket(stamps, times, self.config)
        if not ok[-1]:
            return out
        first, last = int(before[ok].min()), min(int(before[ok].max()) + 1, stamps.size - 1)
        t, gyro = stamps[first : last + 1], rows[first : last + 1, _GYRO]
        if bias is not None:
            gyro = gyro - bias
        dt = np.diff(t) * 1e-9
        step = axis_angle_to_matrix(0.5 * (gyro[1:] + gyro[:-1]) * dt[:, None])
        turned = np.empty((t.size, 3, 3))  # R_S0_S at each sample, S0 the first's
        turned[0] = np.eye(3)
        for k in range(step.shape[0]):
            turned[k + 1] = turned[k] @ step[k]
        gaps = np.concatenate([[0], np.cumsum(np.diff(t) > self.config.max_gap_ns)])  # gaps before each sample
        k = np.clip(before - first, 0, t.size - 1)
        nxt = np.minimum(k + 1, t.size - 1)
        span = np.maximum(t[nxt] - t[k], 1) * 1e-9
        tau = (times - t[k]) * 1e-9
        rate = gyro[k] + (gyro[nxt] - gyro[k]) * np.clip(tau / span, 0.0, 1.0)[:, None]
        at = turned[k] @ axis_angle_to_matrix(0.5 * (gyro[k] + rate) * tau[:, None])  # R_S0_S at each time
        good = ok[:-1] & (gaps[k[:-1]] == gaps[k[-1]])
        out[good] = np.einsum("ba,nbc->nac", at[-1], at[:-1][good])
        return out

    def _bracketed(self, name: str, stamp_ns: np.ndarray, width: int,
                   blend: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
        """(T, width): ``blend(rows before, rows after, weights)`` at the measurement times of ``stamp_ns``."""
        stamps, rows = self._buffers[name].stamps, self._buffers[name].rows
        t = np.asarray(stamp_ns, dtype=np.int64) - self._latency_ns[name]
        out = np.full((t.size, width), np.nan)
        if stamps.size:
            before, after, ok = _bracket(stamps, t, self.config)
            lo, hi = np.maximum(before, 0), np.minimum(after, stamps.size - 1)
            out[ok] = blend(rows[lo[ok]], rows[hi[ok]], _weights(stamps, t, lo, hi, ok))
        return out

    def insert(self, name: str, stamp_ns: int, row: np.ndarray, code: int) -> str | None:
        """Buffer one sample of sensor ``name`` validated by :meth:`validate` at its measurement time
        (:meth:`measured_ns`); why it was rejected, None if kept."""
        if code < 0:
            self._check_step(name, self.measured_ns(name, stamp_ns), row)
        reason = _REJECTS[code] if code >= 0 else self._buffers[name].insert(self.measured_ns(name, stamp_ns), row)
        if reason is not None:
            self.rejected[name][reason] += 1
        return reason

    def _check_step(self, name: str, measured_ns: int, row: np.ndarray) -> None:
        """Start the buffer of ``name`` again, from the sample before this one, if its clock stepped back: this
        sample and the one before it both far behind its newest (:func:`lip_ros.core.clock.stepped_back`), this one
        after that one. One such sample alone is a late one (inserted in place, or rejected as older than the
        buffered data)."""
        step = stepped_back(measured_ns, self.newest_ns(name))
        before = self._behind[name]
        self._behind[name] = (measured_ns, row) if step else None
        if step and before is not None and 0 < measured_ns - before[0] <= CLOCK_STEP_NS:
            self._buffers[name] = _Buffer(self.config.capacity)
            self._buffers[name].insert(*before)  # the first sample of the new time line: this one goes in after it
            self._behind[name] = None
            self.clock_steps[name] += 1
            self.last_clock_step_ns = step

    def newest_ns(self, name: str) -> int | None:
        """Stamp of the newest buffered sample of ``name``."""
        stamps = self._buffers[name].stamps
        return int(stamps[-1]) if stamps.size else None

    def span_ns(self) -> tuple[int, int] | None:
        """Stamps of the oldest and the newest buffered sample of any sensor (None if nothing is buffered)."""
        spans = [(int(b.stamps[0]), int(b.stamps[-1])) for b in self._buffers.values() if b.stamps.size]
        return (min(s[0] for s in spans), max(s[1] for s in spans)) if spans else None

    def ready(self, t_ns: int, now_ns: int) -> bool:
        """Whether to query ``t_ns`` now: all sensors have data past ``t + settle_ns``, or ``wait_ns`` passed."""
        if now_ns - t_ns >= self.config.wait_ns:
            return True
        newest = (self.newest_ns(n) for n in self.names)
        return all(s is not None and s >= t_ns + self.config.settle_ns for s in newest)

    def query(self, t_ns: int) -> SyncResult:
        """Every sensor at ``t_ns`` (capture-clock nanoseconds)."""
        t = np.array([t_ns], dtype=np.int64)
        per_sensor = [
            _interpolate(b.stamps, b.rows, t, self.config, b.evicted) for b in map(self._buffers.get, self.names)
        ]
        return _assemble(self.names, t, per_sensor)[0]


def sync_batch(
    streams: Mapping[str, ImuArrays], t_ns: np.ndarray, config: SyncConfig | None = None
) -> list[SyncResult]:
    """Every sensor of ``streams`` (samples in arrival order) at each of the times ``t_ns`` (T,), each sensor's
    ``config.latency_ns`` (in the order of ``streams``) taken off its stamps."""
    config = config or SyncConfig()
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    latency = config.latency_ns or (0,) * len(streams)
    if len(latency) != len(streams):
        raise ValueError(f"latency_ns has {len(latency)} values for the {len(streams)} sensors {tuple(streams)}")
    series = [ImuSeries.clean(s, config.quat_norm_tolerance)[0] for s in streams.values()]
    per_sensor = [_interpolate(s.stamp_ns - late, s._rows(), t, config) for s, late in zip(series, latency)]
    return _assemble(tuple(streams), t, per_sensor)
