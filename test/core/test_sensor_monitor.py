"""SensorMonitor: rates, staleness, rejections and recovery, on a synthetic clock."""

from __future__ import annotations

import math

import pytest

from lip_msgs_py import DiagnosticLevel
from lip_ros.core.sensor_monitor import SensorMonitor, SilenceChange


def feed(m: SensorMonitor, t0: float, t1: float, rate: float, stamp0: int = 0) -> float:
    t = t0
    while t < t1:
        m.accept(t, stamp0 + int(t * 1e9))
        t += 1.0 / rate
    return t


def test_no_data_is_stale() -> None:
    r = SensorMonitor("imu", 60.0).report(10.0)
    assert r.health == DiagnosticLevel.STALE and r.message == "no data" and r.age_s is None


def test_rate_ok_then_stale_then_recovers() -> None:
    m = SensorMonitor("imu", 60.0, stale_after_s=0.5)
    feed(m, 0.0, 3.0, 60.0)
    r = m.report(3.0)
    assert r.health == DiagnosticLevel.OK and r.rate_hz == pytest.approx(60.0, abs=1.0)
    assert m.report(4.0).health == DiagnosticLevel.STALE
    feed(m, 4.0, 7.0, 60.0)
    assert m.report(7.0).health == DiagnosticLevel.OK


def test_a_silence_is_said_once_when_it_starts_and_once_when_it_ends_with_its_length() -> None:
    m = SensorMonitor("imu", 60.0, stale_after_s=0.5)
    assert m.silence_change(5.0) is None  # nothing received yet: not a silence (the node says so itself)
    t = feed(m, 0.0, 3.0, 60.0)
    last = t - 1.0 / 60.0
    assert m.silence_change(3.0) is None and m.silence_change(last + 0.49) is None
    assert m.silence_change(3.7) == SilenceChange("silent", pytest.approx(3.7 - last))
    assert m.silence_change(4.5) is None  # said once
    feed(m, 5.0, 5.2, 60.0)  # several messages before the next look: the silence is the first one's gap
    assert m.silence_change(5.2) == SilenceChange("back", pytest.approx(5.0 - last))
    assert m.silence_change(5.3) is None
    assert m.silence_change(6.0).kind == "silent"  # and again
    feed(m, 6.5, 6.6, 60.0)
    assert m.silence_change(6.6).kind == "back"


def test_a_silence_between_two_looks_is_said_with_its_length() -> None:
    m = SensorMonitor("lidar", 10.0, stale_after_s=1.0)
    t = feed(m, 10.0, 12.0, 10.0)
    assert m.silence_change(12.0) is None
    feed(m, t + 1.4, 14.0, 10.0)  # silent 1.5 s, between the looks at 12 and 14
    assert m.silence_change(14.0) == SilenceChange("was_silent", pytest.approx(1.5))
    assert m.silence_change(14.5) is None
    feed(m, 14.0, 14.95, 10.0)  # gaps under stale_after_s: no silence
    assert m.silence_change(15.0) is None


def test_a_silence_across_a_reset_of_the_receive_clock_ends_without_a_length() -> None:
    m = SensorMonitor("imu", 60.0, stale_after_s=0.5)
    feed(m, 100.0, 101.0, 60.0)
    assert m.silence_change(102.0).kind == "silent"
    feed(m, 10.0, 10.1, 60.0, stamp0=10**12)  # a bag played again
    change = m.silence_change(10.1)
    assert change.kind == "back" and math.isnan(change.seconds)


def test_receive_time_zero_starts_no_silence() -> None:
    """A node on /clock takes messages at time 0 before the clock's first tick: no silence from 0 to the tick."""
    m = SensorMonitor("imu", 60.0, stale_after_s=0.5)
    m.accept(0.0, 1_000)
    assert m.silence_change(1.7e9) is None  # the clock ticked, nothing since
    feed(m, 1.7e9, 1.7e9 + 1.0, 60.0, stamp0=-10**18)
    assert m.silence_change(1.7e9 + 1.0) is None


def test_low_rate_warns() -> None:
    m = SensorMonitor("lidar", 10.0)
    feed(m, 0.0, 3.0, 3.0)
    r = m.report(3.0)
    assert r.health == DiagnosticLevel.WARN and "expected 10.0 Hz" in r.message


def test_rejections_warn_while_recent_and_are_counted_forever() -> None:
    m = SensorMonitor("imu", 60.0, window_s=2.0)
    feed(m, 0.0, 1.0, 60.0)
    m.reject(1.0, "zero quaternion")
    m.reject(1.0, "zero quaternion")
    feed(m, 1.0, 2.0, 60.0)
    r = m.report(2.0)
    assert r.health == DiagnosticLevel.WARN and "zero quaternion x2" in r.message
    feed(m, 2.0, 5.0, 60.0)
    r = m.report(5.0)
    assert r.health == DiagnosticLevel.OK and r.rejected == {"zero quaternion": 2}
    assert r.received == r.accepted + 2


def test_out_of_order_stamps_counted() -> None:
    m = SensorMonitor("imu", 60.0)
    m.accept(0.0, 100)
    m.accept(0.1, 90)
    m.accept(0.2, 100)
    m.accept(0.3, 110)
    assert m.report(0.3).out_of_order == 2


def test_a_clock_step_is_a_warning_while_it_is_recent_and_not_out_of_order() -> None:
    """Stamps 5 s back, then (a PTP step) 5 s ahead of the receive clock: each a WARN naming it for the window,
    counted, never counted out of order; a true gap (receive clock and stamps both move on) is no step."""
    m = SensorMonitor("lidar", 10.0, stale_after_s=1.0)
    t = feed(m, 0.0, 3.0, 10.0, stamp0=100 * 10**9)
    m.accept(t, 95 * 10**9 + int(t * 1e9))  # 5 s back
    r = m.report(t + 0.1)
    assert r.health == DiagnosticLevel.WARN and "stamps stepped back 4.9 s" in r.message  # behind the newest
    assert r.clock_steps == 1 and r.out_of_order == 0
    t = feed(m, t + 0.1, t + 3.0, 10.0, stamp0=95 * 10**9)
    assert m.report(t).health == DiagnosticLevel.OK and m.report(t).out_of_order == 0
    m.accept(t, 100 * 10**9 + int(t * 1e9))  # 5 s ahead of the receive clock
    assert "stamps stepped ahead 5.0 s" in m.report(t).message and m.report(t).clock_steps == 2
    t = feed(m, t + 0.1, t + 3.0, 10.0, stamp0=100 * 10**9)
    t = feed(m, t + 5.0, t + 6.0, 10.0, stamp0=100 * 10**9)  # 5 s without data: a gap, not a step
    assert m.report(t).health == DiagnosticLevel.OK and m.report(t).clock_steps == 2


def test_the_receive_clock_going_back_starts_the_rate_window_again() -> None:
    """A bag played again rewinds /clock: the rate is the new time line's, not both time lines' together."""
    m = SensorMonitor("imu", 60.0)
    feed(m, 100.0, 103.0, 60.0)
    t = feed(m, 10.0, 12.0, 60.0, stamp0=10**12)  # new stamps go on forward: no stamp step
    r = m.report(t)
    assert r.rate_hz == pytest.approx(60.0, abs=1.0) and r.health == DiagnosticLevel.OK and r.age_s < 0.1


@pytest.mark.parametrize(("expected_hz", "stamped_hz", "warns"), [(10.0, 20.0, True), (20.0, 10.0, True),
                                                                  (10.0, 10.0, False), (10.0, 11.0, False)])
def test_a_sensor_stamping_each_period_is_warned_of_a_rate_unlike_the_expected_one(expected_hz, stamped_hz, warns):
    """An OS1 in a 20 Hz mode where 10 was configured (or the reverse): the rate measured from the stamps is
    reported, and the messages missing from a gap are counted in it (three of a 20 Hz sensor's, not one). Until
    five intervals are known they are counted in the expected period (a 10 Hz sensor expected at 20: one each)."""
    m = SensorMonitor("lidar", expected_hz, count_missing=True)
    period_ns = round(1e9 / stamped_hz)
    stamps = [k * period_ns for k in range(60) if not 10 <= k < 13]  # three missing
    for stamp in stamps:
        m.accept(stamp * 1e-9 + 0.01, stamp)
    r = m.report(stamps[-1] * 1e-9 + 0.02)  # the gap more than window_s before
    assert ("stamped" in r.message) == warns and r.health == (DiagnosticLevel.WARN if warns else DiagnosticLevel.OK)
    if warns:
        assert f"({stamped_hz:.1f} Hz), expected {expected_hz:.1f} Hz" in r.message
    before_known = 5 if stamped_hz < expected_hz / 1.5 else 0
    assert r.missing == 3 + before_known and m.measured_rate_hz == pytest.approx(stamped_hz)
