"""The legs' length from the walk (lip_ros.hsc4d.leg_scale) on walks whose true ratio is known."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.hsc4d.leg_scale import LegScale, LegScaleConfig, standing_steps

RATE_HZ = 10.0


def _stance_pairs(ratio: float, seconds: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A straight walk at 1 m/s over feet planted 0.6 m apart (one standing at a time), legs ``ratio`` times the
    bones': the pelvis's steps (M, 3) and the standing foot's offset's change at the bones' size (M, 3), with 2 mm
    of the LiDAR's jitter on the pelvis and 0.2 deg of the suit's noise on the legs each frame (3 mm at the foot;
    such noise on the legs biases the ratio low by its square over the legs' step's, 0.1 % here, 2 % at 1 deg)."""
    t = np.arange(0.0, seconds, 1.0 / RATE_HZ)
    pelvis = np.column_stack([t, np.zeros_like(t), np.full_like(t, 0.95)])
    plant = np.floor((pelvis[:, 0] + 0.3) / 0.6) * 0.6  # the foot under the pelvis, planted every 0.6 m
    foot = np.column_stack([plant, np.full_like(t, 0.1), np.zeros_like(t)])
    offsets = (foot - pelvis) / ratio + rng.normal(0.0, np.radians(0.2) * 0.9 / np.sqrt(3.0), pelvis.shape)
    seen = pelvis + rng.normal(0.0, 0.002, pelvis.shape)
    stance = np.zeros((len(t), 2), dtype=bool)  # the second foot never stands: one foot planted again and again
    stance[1:, 0] = plant[1:] == plant[:-1]  # a new plant: the pairs into and out of it are not one stance's
    return standing_steps(seen, np.stack([offsets, offsets], axis=1), stance)


def test_the_ratio_of_the_pelvis_steps_to_the_legs_is_the_legs_length_over_the_bones():
    rng = np.random.default_rng(0)
    for ratio in (0.96, 1.0, 1.04):
        walk = LegScale()
        assert walk.add(*_stance_pairs(ratio, 20.0, rng)) >= 120  # 200 frames, 4 pairs of each 6-frame plant
        assert walk.ratio == pytest.approx(ratio, rel=0.01)  # measured within 0.6 % on five seeds


def test_a_foot_the_suit_calls_standing_as_it_lifts_counts_for_nothing():
    """A third of the pairs a lifting foot's (its offset 10-30 cm further off, upwards and on): the plain least
    squares take the ratio 60-70 % off; the biweight from 1 keeps it within 1 % (measured within 0.5 %)."""
    rng = np.random.default_rng(1)
    steps, legs = _stance_pairs(1.04, 30.0, rng)
    lifting = rng.random(len(legs)) < 1.0 / 3.0
    legs[lifting] += rng.uniform(0.1, 0.3, (int(lifting.sum()), 1)) * np.array([0.6, 0.0, 0.8])
    plain = float(-np.einsum("ka,ka->", legs, steps) / np.einsum("ka,ka->", legs, legs))
    assert abs(plain / 1.04 - 1.0) > 0.2
    walk = LegScale()
    walk.add(steps, legs)
    assert walk.ratio == pytest.approx(1.04, rel=0.01)


def test_no_ratio_until_enough_walking_and_not_outside_the_bounds():
    rng = np.random.default_rng(2)
    config = LegScaleConfig()
    walk = LegScale(config)
    steps, legs = _stance_pairs(1.02, 20.0, rng)
    still = np.zeros((500, 3))  # standing still: nothing turned, nothing told
    assert walk.add(still, still + 0.001) == 0 and len(walk) == 0
    assert walk.add(steps[: config.min_pairs - 1], legs[: config.min_pairs - 1]) == config.min_pairs - 1
    assert walk.ratio is None
    bad = legs[:5].copy()
    bad[0, 0] = np.nan
    assert walk.add(steps[:5], bad) == 4  # a NaN pair is left out
    assert walk.ratio == pytest.approx(1.02, rel=0.01)
    far = _stance_pairs(1.27, 20.0, rng)  # not the body's size: the legs' sensors are wrong
    wide = LegScale(LegScaleConfig(bounds=(0.8, 1.3)))
    wide.add(*far)
    assert wide.ratio == pytest.approx(1.27, rel=0.01)  # the fit finds it ...
    bounded = LegScale()
    bounded.add(*far)
    assert bounded.ratio is None  # ... and the bounds refuse it
    lost = LegScale()
    lost.add(*_stance_pairs(1.6, 20.0, rng))  # every pair 6 cm off the body's size: none counts
    assert lost.ratio is None


def test_the_newest_pairs_are_kept():
    rng = np.random.default_rng(3)
    walk = LegScale(LegScaleConfig(capacity=100))
    walk.add(*_stance_pairs(0.97, 30.0, rng))
    walk.add(*_stance_pairs(1.03, 30.0, rng))
    assert len(walk) == 100 and walk.ratio == pytest.approx(1.03, rel=0.01)


def test_standing_steps_pairs_the_frames_a_foot_stands_in_both():
    pelvis = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.2, 0.0, 1.0], [0.3, 0.0, 1.0]])
    offsets = np.arange(24.0).reshape(4, 2, 3)
    stance = np.array([[True, False], [True, False], [False, True], [False, True]])
    steps, legs = standing_steps(pelvis, offsets, stance)
    np.testing.assert_allclose(steps, [[0.1, 0.0, 0.0], [0.1, 0.0, 0.0]])
    np.testing.assert_allclose(legs, [offsets[1, 0] - offsets[0, 0], offsets[3, 1] - offsets[2, 1]])


def test_config_checks():
    with pytest.raises(ValueError):
        LegScaleConfig(min_pairs=0)
    with pytest.raises(ValueError):
        LegScaleConfig(bounds=(1.1, 1.2))
    with pytest.raises(ValueError):
        LegScaleConfig(outlier_m=0.0)
