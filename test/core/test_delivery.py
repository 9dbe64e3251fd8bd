"""Messages published and never taken, counted from the publisher's sequence numbers (lip_ros.core.delivery)."""

from __future__ import annotations

from lip_ros.core.delivery import SEQUENCE_UNSUPPORTED, Delivery, DeliveryGaps, not_taken_how
from lip_ros.core.sensor_monitor import SensorMonitor


def test_a_gap_in_the_numbers_is_messages_not_taken() -> None:
    gaps = DeliveryGaps()
    for now, seq in ((1.0, 1), (1.1, 2), (1.2, 5), (1.3, 6), (1.4, 8)):
        gaps.taken(now, seq)
    assert gaps.total == Delivery(3, 0)
    assert gaps.total.overwritten == 3


def test_the_first_number_taken_and_a_number_not_above_the_last_start_the_count_again() -> None:
    """A subscriber matched late misses the messages published before it; a restarted publisher numbers from 1."""
    gaps = DeliveryGaps()
    for now, seq in ((1.0, 40), (1.1, 41), (1.2, 1), (1.3, 2), (1.4, 2), (1.5, 3)):
        gaps.taken(now, seq)
    assert gaps.total == Delivery(0, 0)


def test_no_number_or_rmw_s_unsupported_number_counts_nothing() -> None:
    gaps = DeliveryGaps()
    for now, seq in ((1.0, 1), (1.1, None), (1.2, SEQUENCE_UNSUPPORTED), (1.3, 2)):
        gaps.taken(now, seq)
    assert gaps.total == Delivery(0, 0)


def test_gaps_are_not_counted_while_the_topic_has_several_publishers() -> None:
    """Two publishers' numbers interleave; back to one, the count starts from its next message."""
    gaps = DeliveryGaps()
    gaps.taken(1.0, 1)
    gaps.publishers(2)
    assert not gaps.counting
    for now, seq in ((1.1, 10), (1.2, 2), (1.3, 30)):
        gaps.taken(now, seq)
    gaps.publishers(1)
    for now, seq in ((1.4, 50), (1.5, 52)):
        gaps.taken(now, seq)
    assert gaps.counting and gaps.total == Delivery(1, 0)


def test_losses_dds_reports_are_counted_once_their_gap_is_seen() -> None:
    """DDS says a sample was lost as the next one arrives; the gap shows when that one is taken."""
    gaps = DeliveryGaps()
    gaps.taken(1.0, 1)
    gaps.lost_in_transport(1.05, 1)
    assert gaps.total == Delivery(0, 0)  # the next message not taken yet
    gaps.taken(1.1, 5)  # 2 lost in transport, 3 and 4 overwritten
    assert gaps.total == Delivery(3, 1) and gaps.total.overwritten == 2


def test_recent_is_the_window_s_before_now_and_restarts_with_the_receive_clock() -> None:
    gaps = DeliveryGaps(window_s=2.0)
    gaps.taken(1.0, 1)
    gaps.taken(1.5, 3)
    gaps.taken(3.0, 6)
    assert gaps.recent(3.4) == Delivery(3, 0)
    assert gaps.recent(3.6) == Delivery(2, 0)  # the gap seen at 1.5 s is out of the window
    assert gaps.recent(5.1) == Delivery(0, 0)
    gaps.taken(5.2, 9)
    assert gaps.recent(0.5) == Delivery(0, 0)  # a bag played again with its /clock
    assert gaps.total == Delivery(5, 0)


def test_how_a_log_line_says_where_they_went() -> None:
    assert not_taken_how(Delivery(3, 1), True) == "1 lost in transport, 2 overwritten in the input's queue"
    assert not_taken_how(Delivery(3, 0), False) == "lost in transport or overwritten in the input's queue"


def test_a_sensor_monitor_reports_its_messages_not_taken_while_recent() -> None:
    monitor = SensorMonitor("ouster", expected_rate_hz=10.0)
    for k, seq in enumerate((1, 2, 3, 6, 7)):
        now = 1.0 + 0.1 * k
        monitor.delivery.taken(now, seq)
        monitor.accept(now, int(now * 1e9))
    report = monitor.report(1.45)
    assert report.not_taken == 2 and report.lost_in_transport == 0
    assert "2 published and not taken (0 lost in transport, 2 overwritten in the input's queue)" in report.message
    for k in range(22):  # on without gaps for longer than the window
        now = 1.5 + 0.1 * k
        monitor.delivery.taken(now, 8 + k)
        monitor.accept(now, int(now * 1e9))
    later = monitor.report(3.65)
    assert later.not_taken == 2 and later.message == "10.0 Hz"
