"""Clocks that step back (lip_ros.core.clock): the step test, and the time line that goes on across steps."""

from __future__ import annotations

from lip_ros.core.clock import CLOCK_STEP_NS, SteppingClock, stepped_back

S = 1_000_000_000
MS = 1_000_000


def test_a_stamp_far_behind_is_a_step_and_a_little_behind_is_not():
    assert stepped_back(10 * S, None) == 0
    assert stepped_back(10 * S - CLOCK_STEP_NS, 10 * S) == 0  # out of order by the tolerance: not a step
    assert stepped_back(5 * S, 10 * S) == 5 * S


def test_the_time_line_goes_on_across_a_step_back_of_every_stream_of_the_clock():
    clock = SteppingClock()
    imu = [clock.internal("imu", t) for t in range(0, 200 * MS, 10 * MS)]  # 100 Hz until 190 ms
    odometry = [clock.internal("odometry", t) for t in range(5 * MS, 200 * MS, 10 * MS)]
    assert imu[-1] == 190 * MS and odometry[-1] == 195 * MS  # nothing moved before a step
    # the clock steps 5 s back at 200 ms: the first stamp behind is refused, the next confirms the step
    assert clock.internal("imu", 200 * MS - 5 * S) is None
    assert clock.internal("imu", 210 * MS - 5 * S) == 210 * MS
    assert clock.steps_ns == [5 * S]
    # the other stream crosses the same step (refusing its first stamp behind too), by the same size
    assert clock.internal("odometry", 205 * MS - 5 * S) is None
    assert clock.internal("odometry", 215 * MS - 5 * S) == 215 * MS
    assert clock.steps_ns == [5 * S]
    assert clock.internal("imu", 220 * MS - 5 * S) == 220 * MS
    # outputs go back to the clock's reading at each moment: before the step as it was, after it as it is now
    assert clock.external(190 * MS) == 190 * MS
    assert clock.external(220 * MS) == 220 * MS - 5 * S


def test_a_single_stale_message_is_refused_and_is_no_step():
    clock = SteppingClock()
    for t in range(0, 100 * MS, 10 * MS):
        clock.internal("imu", t)
    assert clock.internal("imu", 90 * MS - 2 * S) is None  # a stale message
    assert clock.internal("imu", 100 * MS) == 100 * MS  # the stream goes on: no step
    assert clock.internal("imu", 110 * MS) == 110 * MS and clock.steps_ns == []
    assert clock.internal("imu", 105 * MS) == 105 * MS  # a little out of order: passed on as it is


def test_a_step_ahead_is_left_as_a_gap():
    clock = SteppingClock()
    clock.internal("lidar", 0)
    assert clock.internal("lidar", 5 * S) == 5 * S and clock.steps_ns == []
    assert clock.external(5 * S) == 5 * S


def test_two_steps_add_up():
    clock = SteppingClock()
    for t in (0, 100 * MS, 200 * MS):
        clock.internal("lidar", t)
    clock.internal("lidar", 300 * MS - 3 * S)
    assert clock.internal("lidar", 400 * MS - 3 * S) == 400 * MS
    clock.internal("lidar", 500 * MS - 10 * S)
    assert clock.internal("lidar", 600 * MS - 10 * S) == 600 * MS
    assert clock.steps_ns == [3 * S, 7 * S]
    assert clock.external(350 * MS) == 350 * MS - 3 * S and clock.external(600 * MS) == 600 * MS - 10 * S


def test_without_confirmation_the_first_stamp_behind_is_the_step():
    """A LiDAR's sweeps or another node's output: nothing refused, and the step's size from the stream's spacing."""
    clock = SteppingClock()
    for t in (0, 100 * MS, 200 * MS):
        clock.internal("lidar", t, confirm=False)
    assert clock.internal("lidar", 300 * MS - 5 * S, confirm=False) == 300 * MS
    assert clock.steps_ns == [5 * S] and clock.external(300 * MS) == 300 * MS - 5 * S


def test_a_new_capture_starts_a_new_time_line_and_refuses_what_the_last_one_still_sends():
    """A bag played again at 14 s: the suit's odometry crosses the step (and shows the new capture), its IMU
    stream still sends two samples of the last capture, and the LiDAR has not stepped yet when the capture begins
    again; each stream's first stamp of the new capture starts the new time line, on its own stamps."""
    clock = SteppingClock()
    for t in range(0, 14 * S, 10 * MS):
        clock.internal("odometry", t)
        clock.internal("imu", t + 5 * MS)
    clock.internal("lidar", 13 * S + 950 * MS, confirm=False)
    assert clock.internal("odometry", 0) is None and clock.internal("odometry", 10 * MS) is not None  # stepped
    clock.begin_again(crossed_within_ns=S)
    assert clock.steps_ns == []
    assert clock.internal("odometry", 20 * MS) == 20 * MS  # crossed the step just now: in the new capture
    assert clock.internal("imu", 14 * S - 5 * MS) is None and clock.internal("imu", 14 * S + 5 * MS) is None
    assert clock.refused == "of the capture before a new one began"
    assert clock.internal("imu", 15 * MS) == 15 * MS  # its clock stepped back: the new capture's
    assert clock.internal("imu", 25 * MS) == 25 * MS
    assert clock.internal("lidar", 14 * S + 50 * MS, confirm=False) is None  # a sweep of the last capture, late
    assert clock.internal("lidar", 50 * MS, confirm=False) == 50 * MS
    # the new capture reaches the stamps the last one ended at: the same stream, the same time line
    assert clock.internal("imu", 14 * S + 15 * MS) == 14 * S + 15 * MS and clock.steps_ns == []


def test_after_a_new_capture_a_stream_whose_clock_did_not_step_goes_on_when_told():
    clock = SteppingClock()
    for t in range(0, 2 * S, 100 * MS):
        clock.internal("lidar", t, confirm=False)
    clock.begin_again(ahead_ns=500 * MS)  # the suit began again; the LiDAR's clock goes on
    assert clock.internal("lidar", 2 * S, confirm=False) is None  # its newest was at 1.9 s
    assert clock.internal("lidar", 2 * S + 400 * MS, confirm=False) is None
    assert clock.internal("lidar", 2 * S + 500 * MS, confirm=False) == 2 * S + 500 * MS
    assert clock.internal("lidar", 2 * S + 600 * MS, confirm=False) == 2 * S + 600 * MS
    clock.begin_again()  # without a time after which it is the new capture's: until its clock steps back
    assert clock.internal("lidar", 5 * S, confirm=False) is None
    assert clock.internal("lidar", 1 * S, confirm=False) == 1 * S


def test_a_stream_realigned_goes_on_the_other_clock_s_time_line():
    """A new capture: the suit's clock stepped back 14 s (its time line moved on by 14 s); the LiDAR's first pose
    of it, 13.9 s behind its last, is put where the suit's shift has it, and the stream goes on from there."""
    suit, lidar = SteppingClock(), SteppingClock()
    for t in range(0, 14 * S, 10 * MS):
        suit.internal("imu", t)
    suit.internal("imu", 0)
    assert suit.internal("imu", 10 * MS) == 14 * S + 10 * MS and suit.shift_ns == 14 * S
    for t in range(0, 14 * S, 100 * MS):
        lidar.internal("odometry", t, confirm=False)
    assert lidar.realign("odometry", 50 * MS, suit.shift_ns) == 14 * S + 50 * MS
    assert lidar.internal("odometry", 150 * MS, confirm=False) == 14 * S + 150 * MS
    assert lidar.steps_ns == [14 * S] and lidar.external(14 * S + 150 * MS) == 150 * MS
