"""IMU synchronisation (lip_ros.core.imu_sync): interpolation, buffers, gaps, online == batch."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lip_ros.core.imu_sync import (
    FrameStatus,
    ImuSeries,
    ImuSynchronizer,
    SensorStatus,
    SyncConfig,
    sync_batch,
)
from lip_ros.core.rotations import axis_angle_to_matrix, geodesic_angle, matrix_to_quat, quat_to_matrix
from lip_ros.rig.capture import CaptureConfig, CaptureSession

T0 = 1_767_225_600 * 1_000_000_000
MS = 1_000_000
AXIS = np.array([0.48, -0.6, 0.64])
R0 = axis_angle_to_matrix(np.array([0.3, -1.2, 2.0]))


def analytic(t_s: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constant-rate turn about a fixed axis (slerp is exact on it), linear rate and force: (quat, gyro, accel)."""
    quat = matrix_to_quat(R0 @ axis_angle_to_matrix(np.outer(rate * t_s, AXIS)))
    gyro = np.outer(1.0 + t_s, [0.1, -0.2, 0.3])
    accel = np.array([0.5, -1.0, 9.81]) + np.outer(t_s, [2.0, 1.0, -3.0])
    return quat, gyro, accel


def series(stamps: np.ndarray, rate: float, rng: np.random.Generator | None = None) -> ImuSeries:
    """Analytic samples at ``stamps``; with ``rng`` half of the quaternions negated (q and -q are one rotation)."""
    quat, gyro, accel = analytic((stamps - T0) * 1e-9, rate)
    if rng is not None:
        quat = np.where(rng.random(len(quat))[:, None] < 0.5, -quat, quat)
    return ImuSeries(np.asarray(stamps, dtype=np.int64), quat, gyro, accel)


def samples(s: ImuSeries, order: np.ndarray | None = None) -> list[SimpleNamespace]:
    order = np.arange(len(s.stamp_ns)) if order is None else order
    return [SimpleNamespace(stamp_ns=int(s.stamp_ns[k]), quat=s.quat[k], gyro=s.gyro[k], accel=s.accel[k])
            for k in order]


def jittered(rate_hz: float, seconds: float, rng: np.random.Generator) -> np.ndarray:
    n = int(seconds * rate_hz)
    t = T0 + np.rint((rng.uniform(0, 1 / rate_hz) + np.arange(n) / rate_hz) * 1e9)
    return (t + rng.integers(-2 * MS, 2 * MS, n)).astype(np.int64)


def check_analytic(results, rates: dict[str, float]) -> None:
    for r in results:
        for i, name in enumerate(r.names):
            quat, gyro, accel = analytic(np.array([(r.t_ns - T0) * 1e-9]), rates[name])
            assert r.status[i] is SensorStatus.OK
            assert r.quat[i, 3] >= 0.0
            np.testing.assert_allclose(r.quat[i], quat[0] * np.sign(quat[0, 3]), atol=1e-12)
            np.testing.assert_allclose(r.gyro[i], gyro[0], atol=1e-12)
            np.testing.assert_allclose(r.accel[i], accel[0], atol=1e-12)


def test_interpolation_is_exact_on_analytic_signals():
    """Per-sensor rates and jitter, sign flips, and a coarse stream on which nlerp would be 0.2 deg off."""
    rng = np.random.default_rng(1)
    rates = {"a": 3.0, "b": -2.0, "coarse": 10.0}
    streams = {
        "a": series(jittered(60.3, 2.0, rng), rates["a"], rng),
        "b": series(jittered(59.7, 2.0, rng), rates["b"], rng),
        "coarse": series(T0 + np.arange(25, dtype=np.int64) * 100 * MS, rates["coarse"], rng),  # 1 rad per step
    }
    t = T0 + rng.integers(120 * MS, 1900 * MS, 50)
    config = SyncConfig(max_gap_ns=120 * MS)
    results = sync_batch(streams, t, config)
    check_analytic(results, rates)
    assert all(r.frame_status is FrameStatus.OK and r.reason == "" for r in results)
    # exactly at a sample: that sample
    at = sync_batch(streams, streams["coarse"].stamp_ns[[3]], config)[0]
    q = streams["coarse"].quat[3]
    np.testing.assert_allclose(at.quat[2], q * np.sign(q[3]), atol=1e-15)


def test_the_buffers_queries_are_exact_on_analytic_signals():
    """The online buffer's orientations, specific forces and angular rates at arbitrary stamps between samples are
    the analytic signals (slerp and linear interpolation are exact on them); NaN outside the held samples."""
    rng = np.random.default_rng(2)
    s = series(jittered(100.0, 1.0, rng), 3.0, rng)
    sync = ImuSynchronizer(["a"], SyncConfig(capacity=200, max_gap_ns=50 * MS))
    for sample in samples(s):
        assert sync.add("a", sample) is None
    t = np.sort(rng.integers(int(s.stamp_ns[0]), int(s.stamp_ns[-1]), 30))
    quat, gyro, accel = analytic((t - T0) * 1e-9, 3.0)
    got = sync.orientations("a", t)
    np.testing.assert_allclose(got * np.sign(got[:, 3:]), quat * np.sign(quat[:, 3:]), atol=1e-12)
    np.testing.assert_allclose(sync.angular_rates("a", t), gyro, atol=1e-12)
    np.testing.assert_allclose(sync.specific_forces("a", t), accel, atol=1e-12)
    outside = np.array([s.stamp_ns[0] - 20 * MS, s.stamp_ns[-1] + 20 * MS])
    assert np.isnan(sync.angular_rates("a", outside)).all() and np.isnan(sync.specific_forces("a", outside)).all()


def test_the_angular_rate_integrated_is_the_turn_between_two_times():
    """A sensor turning at a constant rate about a fixed axis of its own (its orientation output left constant, as
    if its filter had frozen): the rate integrated from one stamp to others between samples is exactly that turn
    (1e-12), both ways; NaN across a gap over ``max_gap_ns`` and outside the held samples."""
    rng = np.random.default_rng(3)
    stamps = jittered(100.0, 1.0, rng)
    stamps = stamps[(stamps < T0 + 400 * MS) | (stamps > T0 + 500 * MS)]  # a 0.1 s gap
    rate = 2.0 * AXIS
    s = ImuSeries(stamps, np.tile([0.0, 0.0, 0.0, 1.0], (stamps.size, 1)), np.tile(rate, (stamps.size, 1)),
                  np.tile([0.0, 0.0, 9.81], (stamps.size, 1)))
    sync = ImuSynchronizer(["a"], SyncConfig(capacity=200, max_gap_ns=50 * MS))
    for sample in samples(s):
        assert sync.add("a", sample) is None
    ref = T0 + 205 * MS + 300_000
    t = np.array([T0 + 100 * MS + 1, ref, T0 + 333 * MS, int(stamps[30]), T0 + 450 * MS, T0 + 700 * MS,
                  int(stamps[0]) - 1])
    got = sync.relative_rotations("a", t, ref)
    expected = axis_angle_to_matrix(np.outer((t[:4] - ref) * 1e-9, rate))
    np.testing.assert_allclose(got[:4], expected, atol=1e-12)
    assert np.isnan(got[4:]).all()
    assert np.isnan(sync.relative_rotations("a", t[:1], T0 + 450 * MS)).all()


def test_out_of_order_duplicates_and_invalid_samples():
    rng = np.random.default_rng(2)
    clean = series(jittered(60.0, 1.0, rng), 2.0)
    order = np.arange(len(clean.stamp_ns))
    for k in range(0, len(order) - 3, 4):  # local reordering, as transport does
        order[k : k + 3] = order[k : k + 3][::-1]
    sync = ImuSynchronizer(["s"])
    for sample in samples(clean, order):
        assert sync.add("s", sample) is None
    dup = samples(clean)[10]
    dup.accel = dup.accel + 100.0  # a second sample with the same stamp: the first one stays
    bad = [
        SimpleNamespace(stamp_ns=T0 + 5 * MS, quat=np.array([0.0, 0.0, 0.0, np.nan]), gyro=np.zeros(3),
                        accel=np.zeros(3)),
        SimpleNamespace(stamp_ns=T0 + 6 * MS, quat=np.array([0.0, 0.0, 0.0, 1.1]), gyro=np.zeros(3),
                        accel=np.zeros(3)),
        SimpleNamespace(stamp_ns=T0 + 7 * MS, quat=np.array([0.0, 0.0, 0.0, 1.0]), gyro=np.zeros(3),
                        accel=np.array([np.inf, 0.0, 0.0])),
    ]
    reasons = [sync.add("s", s) for s in [dup, *bad]]
    assert reasons == ["duplicate stamp", "orientation not finite", "quaternion not unit", "acceleration not finite"]
    assert sum(sync.rejected["s"].values()) == 4
    t = np.sort(rng.integers(clean.stamp_ns[0], clean.stamp_ns[-1], 20))
    check_analytic([sync.query(int(x)) for x in t], {"s": 2.0})
    # the batch cleaner does the same with the samples in the same arrival order
    arrival = samples(clean, order) + [dup, *bad]
    raw = SimpleNamespace(**{k: np.array([getattr(s, k) for s in arrival]) for k in ("stamp_ns", "quat", "gyro",
                                                                                      "accel")})
    cleaned, rejected = ImuSeries.clean(raw)
    assert dict(rejected) == dict(sync.rejected["s"])
    np.testing.assert_array_equal(cleaned.stamp_ns, clean.stamp_ns)
    np.testing.assert_array_equal(cleaned.accel, clean.accel)


def test_gaps_hold_then_miss_with_reasons():
    stamps = T0 + np.concatenate([np.arange(0, 500, 20), np.arange(800, 1000, 20)]).astype(np.int64) * MS
    s = series(stamps, 1.0)
    sync = ImuSynchronizer(["g", "ok"], SyncConfig(max_gap_ns=50 * MS, max_hold_ns=100 * MS))
    for sample in samples(s):
        sync.add("g", sample)
    for sample in samples(series(T0 + np.arange(-100, 1300, 10, dtype=np.int64) * MS, 1.0)):
        sync.add("ok", sample)
    at = {ms: sync.query(T0 + ms * MS) for ms in (-50, 250, 530, 700, 1030, 1200)}
    assert at[250].frame_status is FrameStatus.OK
    held, late = at[530], at[1030]
    assert held.status == (SensorStatus.HELD, SensorStatus.OK) and held.frame_status is FrameStatus.DEGRADED
    assert held.age_ns[0] == 50 * MS  # the last sample before the gap, at 480 ms
    np.testing.assert_array_equal(held.accel[0], s.accel[24])
    assert held.reason == "g: gap of 320 ms, holding a sample 50 ms old"
    assert late.status[0] is SensorStatus.HELD and late.age_ns[0] == 50 * MS
    assert late.reason == "g: no sample after t, holding a sample 50 ms old"
    for ms, why in ((-50, "no sample before t"), (700, "last sample 220 ms old (hold bound 100 ms)"),
                    (1200, "last sample 220 ms old (hold bound 100 ms)")):
        r = at[ms]
        assert r.status == (SensorStatus.MISSING, SensorStatus.OK) and r.frame_status is FrameStatus.SKIP
        assert np.isnan(r.quat[0]).all() and np.isnan(r.accel[0]).all() and r.reason == f"g: {why}"
    empty = ImuSynchronizer(["x"]).query(T0)
    assert empty.frame_status is FrameStatus.SKIP and empty.reason == "x: no data"


def test_bounded_buffer_and_readiness():
    stamps = T0 + np.arange(0, 3000, 10, dtype=np.int64) * MS
    s = series(stamps, 1.0)
    config = SyncConfig(capacity=64, wait_ns=200 * MS, settle_ns=20 * MS)
    sync = ImuSynchronizer(["a", "b"], config)
    for sample in samples(s):
        sync.add("a", sample)
    buffer = sync._buffers["a"]
    np.testing.assert_array_equal(buffer.stamps, stamps[-64:])  # compacted several times, newest kept
    np.testing.assert_array_equal(buffer.rows[:, 7:], s.accel[-64:])
    assert sync.add("a", samples(s)[0]) == "older than the buffered data"
    t = int(stamps[-10])
    assert not sync.ready(t, now_ns=t + 50 * MS)  # "b" has nothing yet
    assert sync.ready(t, now_ns=t + 200 * MS)  # waited long enough
    for sample in samples(s)[-11:-8]:  # up to t + 10 ms
        sync.add("b", sample)
    assert not sync.ready(t, now_ns=t + 50 * MS)  # settle_ns wants t + 20 ms
    sync.add("b", samples(s)[-8])
    assert sync.ready(t, now_ns=t + 50 * MS)


@pytest.fixture(scope="module")
def rig_streams():
    """The four DOT streams of a rig capture: per-sensor rates, jitter, drops, noise."""
    return CaptureSession(CaptureConfig(scenario="mixed", seconds=15.0, seed=5)).imu_streams()


def replay_online(streams, t: np.ndarray, config: SyncConfig, latency_ns, rng: np.random.Generator):
    """Feed samples in arrival order (stamp + random transport latency), query each time once ready."""
    events = sorted(
        (int(x.stamp_ns[k] + lat), name, k)
        for name, x in streams.items()
        for k, lat in enumerate(rng.integers(*latency_ns, x.stamp_ns.size))
    )
    sync = ImuSynchronizer(streams, config)
    pending, results = list(t), []
    for now, name, k in events:
        x = streams[name]
        sync.add(name, SimpleNamespace(stamp_ns=x.stamp_ns[k], quat=x.quat[k], gyro=x.gyro[k], accel=x.accel[k]))
        while pending and sync.ready(pending[0], now):
            results.append(sync.query(int(pending.pop(0))))
    results += [sync.query(int(p)) for p in pending]
    arrival = {name: [] for name in streams}
    for _, name, k in events:
        arrival[name].append(k)
    in_order = {name: SimpleNamespace(**{f: getattr(x, f)[arrival[name]] for f in ("stamp_ns", "quat", "gyro",
                                                                                   "accel")})
                for name, x in streams.items()}
    return results, in_order


@pytest.mark.parametrize("latency_ms, settle_ms", [((5, 6), 0), ((5, 40), 60)])
def test_online_equals_batch_bit_for_bit(rig_streams, latency_ms, settle_ms):
    """In-order arrival; then reordering by up to 35 ms of transport jitter (settle_ns covers it and a period)."""
    rng = np.random.default_rng(settle_ms)
    start = max(x.stamp_ns[0] for x in rig_streams.values())
    t = start + np.arange(-2, 145) * 100 * MS + rng.integers(30 * MS, 70 * MS, 147)  # frame stamp + mean point t
    config = SyncConfig(settle_ns=settle_ms * MS)
    online, arrival = replay_online(rig_streams, t, config, (latency_ms[0] * MS, latency_ms[1] * MS), rng)
    batch = sync_batch(arrival, t, config)
    assert len(online) == len(batch) == len(t)
    assert all(a.same_as(b) for a, b in zip(online, batch))
    status = [r.frame_status for r in batch]
    assert status[0] is FrameStatus.SKIP and status.count(FrameStatus.OK) >= 140  # before the data: skipped
    r = batch[50]
    for i, name in enumerate(r.names):  # between the readings just before and after t
        x = rig_streams[name]
        k = np.searchsorted(x.stamp_ns, r.t_ns)
        ends = quat_to_matrix(x.quat[k - 1 : k + 1])
        span = geodesic_angle(ends[0], ends[1])
        assert geodesic_angle(quat_to_matrix(r.quat[i]), ends[0]) + geodesic_angle(quat_to_matrix(r.quat[i]), ends[1]) \
            == pytest.approx(span, abs=1e-6)


def test_latency_is_taken_off_each_sensors_stamps():
    """Samples stamped late by a known latency per sensor (a driver stamping on arrival) give, with that latency
    configured, exactly what the samples stamped at their measurement time give; invalid latencies are refused."""
    rng = np.random.default_rng(5)
    names, rates, latency_ms = ("a", "b"), {"a": 2.0, "b": -1.5}, (35, 52)
    on_time = {n: series(jittered(60.0, 2.0, rng), rates[n]) for n in names}
    late = {n: ImuSeries(s.stamp_ns + latency_ms[i] * MS, s.quat, s.gyro, s.accel)
            for i, (n, s) in enumerate(on_time.items())}
    plain = ImuSynchronizer(names)
    corrected = ImuSynchronizer(names, SyncConfig(latency_ns=tuple(v * MS for v in latency_ms)))
    uncorrected = ImuSynchronizer(names)
    for n in names:
        for x in samples(on_time[n]):
            assert plain.add(n, x) is None
        for x in samples(late[n]):
            assert corrected.add(n, x) is None and uncorrected.add(n, x) is None
    assert corrected.measured_ns("b", T0) == T0 - 52 * MS
    t = np.arange(T0 + 300 * MS, T0 + 1700 * MS, 100 * MS)
    for t_ns in t.tolist():
        a, b, c = plain.query(t_ns), corrected.query(t_ns), uncorrected.query(t_ns)
        np.testing.assert_allclose(b.quat, a.quat, atol=1e-12)
        assert np.abs(c.quat - a.quat).max() > 1e-3  # without the latency taken off, another moment
    check_analytic([corrected.query(t_ns) for t_ns in t.tolist()], rates)
    batch = sync_batch(late, t, SyncConfig(latency_ns=tuple(v * MS for v in latency_ms)))
    np.testing.assert_allclose([r.quat for r in batch], [plain.query(t_ns).quat for t_ns in t.tolist()], atol=1e-12)
    with pytest.raises(ValueError, match="latency_ns has 1 values"):
        ImuSynchronizer(names, SyncConfig(latency_ns=(MS,)))
    with pytest.raises(ValueError, match="invalid"):
        SyncConfig(latency_ns=(MS, -MS))


def test_a_clock_step_back_starts_the_sensors_buffer_again():
    """Stamps 5 s back (a bag played again, a PTP step): the buffer of the old time line is let go at the second
    sample of the new one, which interpolates at once with the first (before, the first was lost: a LiDAR frame
    between the two had no sample before it); one late sample alone is no step."""
    rng = np.random.default_rng(4)
    stamps = jittered(60.0, 2.0, rng)
    old, new = series(stamps, 2.0), series(stamps - 5000 * MS, 2.0)
    sync = ImuSynchronizer(["s"])
    for sample in samples(old):
        assert sync.add("s", sample) is None
    assert sync.add("s", samples(old)[0]) == "duplicate stamp"  # late alone, then on the old time line again
    assert sync.add("s", samples(old)[-1]) == "duplicate stamp" and sync.clock_steps["s"] == 0
    for sample in samples(new):
        assert sync.add("s", sample) is None
    assert sync.clock_steps["s"] == 1 and sync.last_clock_step_ns >= 5000 * MS - 20 * MS
    assert sync.span_ns() == (int(new.stamp_ns[0]), int(new.stamp_ns[-1]))  # nothing of the old time line left
    t = np.sort(rng.integers(new.stamp_ns[0], new.stamp_ns[-1], 20))
    check_analytic([sync.query(int(x)) for x in t], {"s": 2.0})
