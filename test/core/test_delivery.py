"""Messages published and never taken, counted from the publishers' sequence numbers (lip_ros.core.delivery)."""

from __future__ import annotations

from lip_ros.core.delivery import MAX_STREAMS, SEQUENCE_UNSUPPORTED, Delivery, DeliveryGaps, not_taken_how
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
    assert not gaps.counting
    for now, seq in ((1.0, 40), (1.1, 41), (1.2, 1), (1.3, 2), (1.4, 2), (1.5, 3)):
        gaps.taken(now, seq)
    assert gaps.counting and gaps.total == Delivery(0, 0)


def test_no_number_or_rmw_s_unsupported_number_counts_nothing() -> None:
    gaps = DeliveryGaps()
    for now, seq in ((1.1, None), (1.2, SEQUENCE_UNSUPPORTED)):
        gaps.taken(now, seq)
    assert not gaps.counting
    for now, seq in ((1.3, 1), (1.4, None), (1.5, 2)):
        gaps.taken(now, seq)
    assert gaps.total == Delivery(0, 0)


def test_each_publisher_s_numbers_are_followed_apart() -> None:
    """Two publishers' numbers interleave (one at 1000, one from 1): a gap in either is counted, the other's
    numbers are not gaps; the publishers followed are bounded."""
    gaps = DeliveryGaps()
    for now, seq in ((1.0, 1000), (1.1, 1), (1.2, 1001), (1.3, 2), (1.4, 1003), (1.5, 3), (1.6, 6)):
        gaps.taken(now, seq)
    assert gaps.total == Delivery(3, 0)
    many = DeliveryGaps()
    for k in range(3 * MAX_STREAMS):  # publishers started again and again, each one message, below the others
        many.taken(2.0, 900 - 10 * k)
    assert len(many._streams) == MAX_STREAMS and many.total == Delivery(0, 0)


def test_a_publisher_matched_late_is_not_a_gap_in_another_s_numbers() -> None:
    """A second publisher's first message taken is numbered ahead of the first's (it published before this
    subscriber was matched): with the topic's count of publishers above the streams followed, a stream of its own;
    with one publisher it is a gap. Streams idle for ``idle_s`` are forgotten."""
    count = [1]
    gaps = DeliveryGaps(idle_s=10.0)
    for now, seq in ((1.0, 500), (1.1, 501)):
        gaps.taken(now, seq, lambda: count[0])
    count[0] = 2
    for now, seq in ((1.2, 700), (1.3, 502), (1.4, 701), (1.5, 504), (1.6, 702)):
        gaps.taken(now, seq, lambda: count[0])
    assert gaps.total == Delivery(1, 0)  # 503
    count[0] = 1
    gaps.taken(20.0, 900, lambda: count[0])  # both streams idle for 18 s: forgotten, a first message
    gaps.taken(20.1, 903, lambda: count[0])
    assert gaps.total == Delivery(3, 0)


def test_losses_dds_reports_are_counted_once_their_gap_is_seen() -> None:
    """DDS says a sample was lost as the next one arrives; the gap shows when that one is taken. A loss whose gap
    never comes (the message after it lost too, and no other taken within the window) is not charged to a later
    overwrite."""
    gaps = DeliveryGaps(window_s=2.0)
    gaps.taken(1.0, 1)
    gaps.lost_in_transport(1.05, 1)
    assert gaps.total == Delivery(0, 0)  # the next message not taken yet
    gaps.taken(1.1, 5)  # 2 lost in transport, 3 and 4 overwritten
    assert gaps.total == Delivery(3, 1) and gaps.total.overwritten == 2
    gaps.lost_in_transport(1.2, 4)  # more than the next gap: the rest waits for the gap after
    gaps.taken(1.3, 8)
    assert gaps.total == Delivery(5, 3)
    gaps.taken(1.4, 10)
    assert gaps.total == Delivery(6, 4)
    gaps.lost_in_transport(1.5, 1)
    gaps.taken(4.0, 13)
    assert gaps.total == Delivery(8, 4)


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
    assert monitor.report(0.5).not_taken is None  # nothing numbered taken yet: not counted
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
