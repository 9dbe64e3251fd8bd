"""Rig domains: STANDARD draws what the rig always drew, SHIFTED lies outside TRAINING, the performer's shape and
the occluder are what the scene and the truth say."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lip_ros.core.body import LIMB_PARTS, TORSO_PARTS, BodyModel
from lip_ros.core.skeleton import PROPORTION_GROUPS, load_skeleton
from lip_ros.lip.evaluation.captures import FIRST_SEEDS, heldout_configs
from lip_ros.lip.train.rigdata import LIDAR_HEIGHT_M
from lip_ros.rig.capture import CaptureConfig, CaptureSession
from lip_ros.rig.domain import DOMAINS, SHIFTED, STANDARD, TRAINING, Occluder
from lip_ros.rig.imu import DOT_ALONG, DOT_SURFACE_M, ImuNoise
from lip_ros.rig.scene import Scene

#: The RigDomain ranges that a draw takes from (the rest are fixed settings of captures).
DRAWN = ("proportions", "torso_girth", "limb_girth", "imu_along", "imu_surface_m", "imu_noise_factor", "energy",
         "tempo")


def test_standard_draws_the_rig_as_it_was():
    for seed in (0, 1_000_000, 77):
        d = STANDARD.draw(seed)
        assert d.proportions == {} and d.torso_girth == d.limb_girth == 1.0 and d.occluder is None
        assert (d.imu_along, d.imu_surface_m, d.point_dropout) == (DOT_ALONG, DOT_SURFACE_M, 0.0)
        assert d.imu_noise() == ImuNoise()
    # the held-out set of the standard domain is the one of before domains existed
    first = heldout_configs(8)[0]
    assert (first.seed, first.scenario, first.distance_m, first.bearing_deg, first.lidar_height_m) == (
        1_000_000, "walk", 17.7, 34.7, 1.2)


def test_every_shifted_choice_lies_outside_training():
    for name in DRAWN:
        lo, hi = getattr(SHIFTED, name)
        t_lo, t_hi = getattr(TRAINING, name)
        assert hi < t_lo or lo > t_hi, f"{name}: SHIFTED {lo, hi} overlaps TRAINING {t_lo, t_hi}"
    assert SHIFTED.lidar_height_m[0] > LIDAR_HEIGHT_M[1]  # mounted higher than any training LiDAR
    for seed in range(40):
        s, t = SHIFTED.draw(seed), TRAINING
        assert all(abs(f - 1.0) > t.proportions[1] for f in s.proportions.values())
        assert s.torso_girth > t.torso_girth[1] and s.limb_girth < t.limb_girth[0]
        assert s.imu_along < t.imu_along[0] and s.imu_surface_m > t.imu_surface_m[1]
        assert s.imu_noise_factor > t.imu_noise_factor[1] and s.occluder is not None
    for config in heldout_configs(8, domain="shifted"):
        assert config.domain == "shifted" and config.seed >= FIRST_SEEDS["shifted"]
        assert SHIFTED.lidar_height_m[0] <= config.lidar_height_m <= SHIFTED.lidar_height_m[1]


def test_draws_are_deterministic_and_differ_between_seeds():
    for domain in DOMAINS.values():
        assert domain.draw(5) == domain.draw(5)
    assert TRAINING.draw(5) != TRAINING.draw(6)
    noisy = SHIFTED.draw(0).imu_noise()
    assert noisy.gyro_noise == pytest.approx(3.0 * ImuNoise().gyro_noise) and noisy.tilt_tau == ImuNoise().tilt_tau


def test_proportions_lengthen_their_bones_and_the_legs_lift_the_pelvis():
    base = load_skeleton()
    longer = base.with_proportions({"thigh": 1.1, "shank": 1.1, "forearm": 0.9})
    for j in PROPORTION_GROUPS["thigh"] + PROPORTION_GROUPS["shank"]:
        np.testing.assert_allclose(longer.offsets[base.index(j)], 1.1 * base.offsets[base.index(j)])
    for j in PROPORTION_GROUPS["forearm"]:
        np.testing.assert_allclose(longer.offsets[base.index(j)], 0.9 * base.offsets[base.index(j)])
    untouched = [base.index(j) for j in ("spine1", "left_elbow", "left_hip", "left_foot")]
    np.testing.assert_array_equal(longer.offsets[untouched], base.offsets[untouched])
    legs = np.mean([-(base.offsets[base.index(f"{s}_knee"), 1] + base.offsets[base.index(f"{s}_ankle"), 1])
                    for s in ("left", "right")])
    assert longer.pelvis_height == pytest.approx(base.pelvis_height + 0.1 * legs)
    assert longer.scale == base.scale and base.with_proportions({}).pelvis_height == base.pelvis_height
    with pytest.raises(KeyError, match="unknown proportion groups"):
        base.with_proportions({"tail": 1.2})


def test_torso_and_limb_girths_thicken_their_capsules_only():
    plain = BodyModel(load_skeleton(), girth=1.1)
    shaped = BodyModel(load_skeleton(), girth=1.1, torso_girth=1.4, limb_girth=0.75)
    for name, a, b in zip(plain.names, plain.radius, shaped.radius, strict=True):
        part = name.split("_", 1)[-1]
        factor = 1.4 if name in TORSO_PARTS else 0.75 if part in LIMB_PARTS else 1.0
        assert b == pytest.approx(factor * a), name


def test_the_occluder_hides_what_its_box_blocks():
    occluder = Occluder(distance_m=1.5, lateral_m=0.3, width_m=1.6, height_m=0.9)
    centre, ground = np.array([9.0, 4.0, 0.0]), -1.4
    rng = np.random.default_rng(0)
    points = rng.uniform([centre[0] - 1.0, centre[1] - 1.0, ground], [centre[0] + 1.0, centre[1] + 1.0, ground + 2.0],
                         size=(4000, 3))
    scene = Scene(ground_z=-100.0).with_box(*occluder.box(centre, ground))
    dist = np.linalg.norm(points, axis=1)
    blocked = scene.raycast(np.zeros(3), points / dist[:, None])[0] < dist
    hides = occluder.hides(points, centre, ground)
    assert 0.1 < hides.mean() < 0.6  # the wall hides some of the area, not all of it
    assert np.mean(hides == blocked) > 0.99  # the thin plane against the 10 cm thick box: edges may differ


def test_a_shifted_capture_has_its_shape_sensors_and_wall():
    session = CaptureSession(CaptureConfig(scenario="walk", seconds=12.0, seed=1_200_000, domain="shifted",
                                           lidar_height_m=3.5))
    draw = session.draw
    assert session.body.torso_girth == draw.torso_girth and session.body.limb_girth == draw.limb_girth
    np.testing.assert_allclose(session.motion.skeleton.offsets,
                               load_skeleton().with_proportions(draw.proportions).scaled(
                                   session.motion.skeleton.scale).offsets)
    assert len(session.scene.boxes) == len(CaptureSession(dataclasses.replace(session.config, domain="standard"))
                                           .scene.boxes) + 1
    spec = session.imu_truth.specs[0]
    bone = session.motion.skeleton.offsets[session.motion.skeleton.children(
        session.motion.skeleton.index(spec.bone_joint))].mean(axis=0)
    along = float(spec.offset_in_bone @ bone / (bone @ bone))
    assert along == pytest.approx(draw.imu_along, abs=1e-9)
    with pytest.raises(ValueError, match="domain"):
        CaptureConfig(domain="elsewhere")
