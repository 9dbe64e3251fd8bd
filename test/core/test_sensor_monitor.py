"""SensorMonitor: rates, staleness, rejections and recovery, on a synthetic clock."""

from __future__ import annotations

import pytest

from lip_msgs_py import DiagnosticLevel
from lip_ros.core.sensor_monitor import SensorMonitor


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
