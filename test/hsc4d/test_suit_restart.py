"""A new capture told from the suit's odometry across a clock step back (lip_ros.hsc4d.suit_restart)."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.core.rotations import matrix_to_quat, rot_z
from lip_ros.hsc4d.suit_restart import SuitRestart, SuitRestartConfig

S = 1_000_000_000
MS = 1_000_000
LEVEL = matrix_to_quat(np.eye(3))


def _walk(restart: SuitRestart, t0_ns: int, start: np.ndarray, n: int, speed: float = 1.5) -> list[str | None]:
    """``n`` samples 10 ms apart of a walk along x from ``start``; what ``add`` said of each."""
    return [restart.add(t0_ns + k * 10 * MS, start + [speed * k * 0.01, 0.0, 0.0], LEVEL) for k in range(n)]


def test_a_step_back_with_the_pelvis_where_it_was_is_the_same_capture():
    restart = SuitRestart()
    assert not any(_walk(restart, 10 * S, np.zeros(3), 100))
    # a PTP step of 5 s: the walk goes on from where it was (0.99 m at the last sample before)
    assert not any(_walk(restart, 5 * S + 1 * S, np.array([1.0, 0.0, 0.0]), 50))


def test_a_step_back_with_the_pelvis_elsewhere_is_a_new_capture():
    restart = SuitRestart()
    _walk(restart, 0, np.zeros(3), 1400)  # 14 s: 21 m along x
    said = _walk(restart, 0, np.zeros(3), 10)  # played again: back at the start
    assert said[0] is not None and not any(said[1:])
    assert "stepped back 13.990 s" in said[0] and "jumped 20.98 m" in said[0]


def test_a_turn_alone_across_the_step_is_a_new_capture_and_a_jump_without_a_step_is_not():
    restart = SuitRestart()
    restart.add(10 * S, np.zeros(3), LEVEL)
    assert restart.add(4 * S, np.zeros(3), matrix_to_quat(rot_z(np.radians(90.0)))) is not None
    # no step back: a jump of the suit's odometry is the suit's own (its stream rejects what is not finite)
    assert restart.add(4 * S + 10 * MS, np.array([5.0, 0.0, 0.0]), LEVEL) is None
    assert restart.add(4 * S + 20 * MS, np.full(3, np.nan), LEVEL) is None  # passed over
    assert restart.add(4 * S + 30 * MS, np.zeros(3), np.zeros(4)) is None
    assert restart.add(-1 * S, np.array([5.0, 0.0, 0.1]), LEVEL) is None  # within 0.5 m of the last good sample


def test_the_limits_are_checked():
    with pytest.raises(ValueError):
        SuitRestartConfig(max_move_m=0.0)
    with pytest.raises(ValueError):
        SuitRestartConfig(max_turn_deg=180.0)
