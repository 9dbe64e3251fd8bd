"""The suit's stride scale against the LiDAR (:class:`lip_ros.hsc4d.trajectory.StrideScale`)."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.hsc4d.trajectory import StrideScale, TrajectoryConfig

_C = TrajectoryConfig()
_RATE_HZ = 10.0


def _scale() -> StrideScale:
    return StrideScale(_C.scale_window_s, _C.scale_min_path_m, _C.max_scale_error, _C.scale_max_grade,
                       _C.scale_grade_window_s)


def _step(forward_m: float, aside_m: float = 0.0, up_m: float = 0.0) -> np.ndarray:
    """A T_Pprev_P whose shift is forward (P's z), aside (P's x) and up (P's y)."""
    T = np.eye(4)
    T[:3, 3] = aside_m, up_m, forward_m
    return T


def _walk(scale: StrideScale, seconds: float, suit_step_m: float, lidar_per_suit: float, aside_sd_m: float = 0.0,
          climb_per_step_m: float = 0.0, kept: bool = True, start_s: float = 0.0, seed: int = 0) -> float:
    """Steps at 10 Hz: the LiDAR's ``lidar_per_suit`` times the suit's forward, with noise aside; the last value."""
    rng = np.random.default_rng(seed)
    value = scale.value
    for k in range(int(seconds * _RATE_HZ)):
        stamp_ns = int((start_s + k / _RATE_HZ) * 1e9)
        lidar = _step(lidar_per_suit * suit_step_m, rng.normal(0.0, aside_sd_m), climb_per_step_m)
        value = scale.add(stamp_ns, lidar, _step(suit_step_m), kept)
    return value


def test_noisy_steps_give_the_scale_unbiased() -> None:
    """Each sweep's registered step 3 cm off aside (the noise of a 12 cm step): the scale along the suit's steps
    is the truth's within 0.5 %, where the steps' lengths would read 3 % long."""
    scale = _scale()
    value = _walk(scale, 20.0, 0.12, 0.96, aside_sd_m=0.03)
    assert value == pytest.approx(0.96, abs=0.005)
    lengths = np.hypot(0.96 * 0.12, np.random.default_rng(0).normal(0.0, 0.03, 200))
    assert lengths.sum() / (0.12 * 200) > 0.96 * 1.025  # what the lengths would say


def test_no_scale_before_the_path() -> None:
    """Under ``scale_min_path_m`` of the suit's path the scale stays 1."""
    scale = _scale()
    assert _walk(scale, 3.0, 0.12, 0.9) == 1.0  # 3.6 m
    assert _walk(scale, 3.0, 0.12, 0.9, start_s=3.0) == pytest.approx(0.9)


def test_climbs_and_held_shifts_do_not_count() -> None:
    """Steps up a stair flight (17 cm a step of 30 cm every 0.5 s) and steps whose registration held its shifts to
    the prediction leave the scale the level walking's."""
    scale = _scale()
    assert _walk(scale, 8.0, 0.12, 0.96) == pytest.approx(0.96)
    assert _walk(scale, 8.0, 0.06, 1.05, climb_per_step_m=0.034, start_s=8.0) == pytest.approx(0.96)
    assert _walk(scale, 8.0, 0.12, 1.05, kept=False, start_s=16.0) == pytest.approx(0.96)
    # a ramp of 5 deg is a climb too; walking on the level again moves the scale
    assert _walk(scale, 4.0, 0.12, 1.05, climb_per_step_m=0.12 * np.tan(np.radians(5.0)), start_s=24.0) == \
        pytest.approx(0.96)
    assert _walk(scale, 8.0, 0.12, 1.05, start_s=28.0) > 0.99


def test_the_pelvis_bob_is_level() -> None:
    """The pelvis rising and falling 2 cm twice a stride (a level walk) counts as level."""
    scale = _scale()
    for k in range(200):
        stamp_ns = int(k / _RATE_HZ * 1e9)
        bob = 0.02 * (np.sin(2 * np.pi * 2.0 * (k + 1) / _RATE_HZ) - np.sin(2 * np.pi * 2.0 * k / _RATE_HZ))
        scale.add(stamp_ns, _step(0.96 * 0.12, up_m=bob), _step(0.12), True)
    assert scale.value == pytest.approx(0.96)
