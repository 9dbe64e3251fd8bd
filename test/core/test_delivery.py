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
    numbers = [900 - 10 * k for k in range(3 * MAX_STREAMS)]
    for k, seq in enumerate(numbers):  # publishers started again and again, each one message, below the others
        many.taken(2.0 + 0.1 * k, seq)
    assert sorted(many._streams) == sorted(numbers[-MAX_STREAMS:]) and many.total == Delivery(0, 0)


def test_a_publisher_matched_late_is_not_a_gap_in_another_s_numbers() -> None:
    """A second publisher's first message taken is numbered ahead of the first's (it published before this
    subscriber was matched): with more publishers matched than streams followed, a stream of its own; a number a
    stream is at already is no gap in another."""
    count = [1]
    gaps = DeliveryGaps()
    for now, seq in ((1.0, 500), (1.1, 501)):
        gaps.taken(now, seq, lambda: count[0])
    count[0] = 2
    for now, seq in ((1.2, 700), (1.3, 502), (1.4, 701), (1.5, 504), (1.6, 702), (1.7, 702)):
        gaps.taken(now, seq, lambda: count[0])
    assert gaps.total == Delivery(1, 0)  # 503


def test_a_gap_across_an_outage_is_counted() -> None:
    """Nothing arrives for 14 s while the one publisher goes on: its stream is still followed."""
    gaps = DeliveryGaps()
    for now, seq in ((1.0, 1), (1.1, 2), (15.0, 152)):
        gaps.taken(now, seq, lambda: 1)
    assert gaps.total == Delivery(149, 0)


def test_losses_dds_reports_are_counted_once_their_gap_is_seen() -> None:
    """DDS says a sample was lost as the next one arrives; the gap shows when that one is taken. Losses are
    matched to the gaps within the window, and never more than the gaps; one older is not charged to a later
    overwrite."""
    gaps = DeliveryGaps(window_s=2.0)
    gaps.taken(1.0, 1)
    gaps.lost_in_transport(1.05, 1)
    assert gaps.total == Delivery(0, 0)  # the next message not taken yet
    gaps.taken(1.1, 5)  # 2 lost in transport, 3 and 4 overwritten
    assert gaps.total == Delivery(3, 1) and gaps.total.overwritten == 2
    gaps.lost_in_transport(1.2, 4)  # 2 for the gap before (its messages not told apart), 2 wait for the next
    assert gaps.total == Delivery(3, 3)
    gaps.taken(1.3, 8)
    assert gaps.total == Delivery(5, 5)
    gaps.taken(1.4, 10)
    assert gaps.total == Delivery(6, 5)
    gaps.taken(4.0, 13)  # no loss reported for it: overwritten
    assert gaps.total == Delivery(8, 5)
    gaps.lost_in_transport(6.5, 1)  # no gap within the window before; its own never seen (the messages after
    gaps.taken(9.0, 16)  # it lost too, up to a gap more than the window later: not that loss)
    assert gaps.total == Delivery(10, 5)


def test_a_loss_dds_reports_after_its_gap_was_taken_is_that_gap_s() -> None:
    """A node that takes its queue inside a long callback sees the gap before the executor hands it the loss
    event; one reported more than ``window_s`` after, or before a reset of the receive clock, matches nothing."""
    gaps = DeliveryGaps(window_s=2.0)
    gaps.taken(1.0, 1)
    gaps.taken(1.1, 5)
    gaps.lost_in_transport(1.2, 3)
    assert gaps.total == Delivery(3, 3)
    gaps.taken(1.3, 9)
    gaps.lost_in_transport(3.5, 1)  # 2.2 s after the gap
    assert gaps.total == Delivery(6, 3)
    gaps.lost_in_transport(5.0, 2)
    gaps.taken(1.0, 12)  # the receive clock went back (a bag played again): not the loss at 5.0 s
    assert gaps.total == Delivery(8, 3)
    assert gaps.recent(1.0) == Delivery(2, 0)


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
