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
    """A T_Pprev_P whose shift is forward (P's z), aside (P's x) and along the pelvis's up (P's y)."""
    T = np.eye(4)
    T[:3, 3] = aside_m, up_m, forward_m
    return T


def _walk(scale: StrideScale, seconds: float, suit_step_m: float, lidar_per_suit: float, aside_sd_m: float = 0.0,
          climb_per_step_m: float = 0.0, kept: bool = True, start_s: float = 0.0, seed: int = 0) -> float:
    """Steps at 10 Hz: the LiDAR's ``lidar_per_suit`` times the suit's forward, with noise aside, rising
    ``climb_per_step_m`` each; the last value."""
    rng = np.random.default_rng(seed)
    value = scale.value
    for k in range(int(seconds * _RATE_HZ)):
        stamp_ns = int((start_s + k / _RATE_HZ) * 1e9)
        lidar = _step(lidar_per_suit * suit_step_m, rng.normal(0.0, aside_sd_m), climb_per_step_m)
        value = scale.add(stamp_ns, lidar, _step(suit_step_m), climb_per_step_m, kept)
    return value


def test_noisy_steps_give_the_scale_unbiased() -> None:
    """Each sweep's registered step 3 cm off aside (the noise of a 12 cm step): the scale along the suit's steps
    is the truth's within 0.5 % (the steps' lengths read 0.989)."""
    assert _walk(_scale(), 20.0, 0.12, 0.96, aside_sd_m=0.03) == pytest.approx(0.96, abs=0.005)


def test_no_scale_before_the_path() -> None:
    """Under ``scale_min_path_m`` of the suit's path the scale stays 1."""
    scale = _scale()
    assert _walk(scale, 3.0, 0.12, 0.9) == 1.0  # 3.6 m walked, 3 m of it judged
    assert _walk(scale, 3.0, 0.12, 0.9, start_s=3.0) == pytest.approx(0.9)


def test_climbs_and_held_shifts_do_not_count() -> None:
    """Steps up a stair flight (17 cm a step of 30 cm every 0.5 s), steps whose registration held its shifts to
    the prediction and steps up a 5 deg ramp leave the scale the level walking's; level walking again moves it."""
    scale = _scale()
    assert _walk(scale, 8.0, 0.12, 0.96) == pytest.approx(0.96)
    assert _walk(scale, 8.0, 0.06, 1.05, climb_per_step_m=0.034, start_s=8.0) == pytest.approx(0.96)
    assert _walk(scale, 8.0, 0.12, 1.05, kept=False, start_s=16.0) == pytest.approx(0.96)
    assert _walk(scale, 8.0, 0.12, 1.05, climb_per_step_m=0.12 * np.tan(np.radians(5.0)), start_s=24.0) == \
        pytest.approx(0.96)
    assert _walk(scale, 8.0, 0.12, 1.05, start_s=32.0) > 0.99


def test_the_steps_next_to_a_flight_do_not_count() -> None:
    """The steps in the fifth of a second before a stair flight and after it: the climb over the second centred on
    each is over 4 % of the path, so the level scale stays exact though they read otherwise (counted by the half
    second after them alone, the steps off the flight would be level)."""
    scale = _scale()
    _walk(scale, 10.0, 0.12, 0.96)
    _walk(scale, 0.2, 0.12, 1.2, start_s=10.0)  # the approach, read 20 % long
    _walk(scale, 3.0, 0.06, 1.05, climb_per_step_m=0.034, start_s=10.2)
    _walk(scale, 0.2, 0.12, 1.2, start_s=13.2)  # the steps off the flight
    assert _walk(scale, 5.0, 0.12, 0.96, start_s=13.4) == pytest.approx(0.96)


def test_a_leaning_wearer_walks_on_the_level() -> None:
    """A wearer leaning 6 deg forward while walking: the pelvis's steps rise along its own up (its y) by a tenth of
    their length, but the rise given is along gravity (none), and it is what counts."""
    scale = _scale()
    lean = np.tan(np.radians(6.0))
    for k in range(150):
        forward = 0.96 * 0.12
        scale.add(int(k / _RATE_HZ * 1e9), _step(forward, up_m=lean * forward), _step(0.12), 0.0, True)
    assert scale.value == pytest.approx(0.96)


def test_the_pelvis_bob_is_level() -> None:
    """The pelvis rising and falling by 4 cm (peak to peak) twice a stride (a level walk) counts as level."""
    scale = _scale()
    for k in range(200):
        stamp_ns = int(k / _RATE_HZ * 1e9)
        bob = 0.02 * (np.sin(2 * np.pi * 2.0 * (k + 1) / _RATE_HZ) - np.sin(2 * np.pi * 2.0 * k / _RATE_HZ))
        scale.add(stamp_ns, _step(0.96 * 0.12, up_m=bob), _step(0.12), bob, True)
    assert scale.value == pytest.approx(0.96)
