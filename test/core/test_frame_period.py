"""FramePeriod: a periodic sensor's period from its stamps, through drops, duplicates and clock steps."""

from __future__ import annotations

import pytest

from lip_ros.core.frame_period import FramePeriod

MS = 1_000_000


def test_the_period_is_known_after_enough_intervals_and_a_dropped_frame_does_not_move_it() -> None:
    period = FramePeriod(window=9, min_intervals=5)
    for k, stamp in enumerate(s * 50 * MS + (k % 3) * MS for k, s in enumerate([0, 1, 2, 3, 5, 6, 7, 8])):
        period.add(stamp)
        assert (period.period_s is None) == (k < 5)
    assert period.period_s == pytest.approx(0.050, abs=0.002) and period.rate_hz == pytest.approx(20.0, rel=0.05)


def test_a_repeated_stamp_is_no_interval_and_a_step_back_starts_again() -> None:
    period = FramePeriod(min_intervals=2)
    for stamp in (0, 100 * MS, 100 * MS, 200 * MS):
        period.add(stamp)
    assert period.period_s == pytest.approx(0.1)
    period.add(50 * MS)  # the clock stepped back
    assert period.period_s is None
    for stamp in (150 * MS, 250 * MS):
        period.add(stamp)
    assert period.period_s == pytest.approx(0.1)
    with pytest.raises(ValueError):
        FramePeriod(window=3, min_intervals=4)
