"""Procedural performer motion (lip_ros.rig.motion): calibration, ground contact, smoothness, limits."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lip_ros.core.skeleton import forward_kinematics, load_skeleton
from lip_ros.rig.motion import (
    ACTIVITIES,
    MIN_DURATION,
    SCENARIOS,
    PerformerMotion,
    make_motion,
    random_motion,
    random_scenario,
)
from lip_ros.rig.motion.posture import sole_points

CENTRE = np.array([7.0, 3.0, 0.0])
LIDAR_HEIGHT = 1.3
DURATION = 32.0
RATE = 200.0  # Hz of the dense checks (smoothness checks use 1 kHz)
CALIBRATION = ("a_pose", "a_to_t", "t_pose", "to_motion")


@pytest.fixture(scope="module")
def motions() -> dict[str, PerformerMotion]:
    return {s: make_motion(s, DURATION, 100 + k, CENTRE, LIDAR_HEIGHT) for k, s in enumerate(SCENARIOS)}


@pytest.fixture(scope="module")
def dense(motions: dict[str, PerformerMotion]) -> dict[str, dict[str, np.ndarray]]:
    """Every motion sampled at RATE: times, pose, global rotations, joint and sole positions."""
    out = {}
    for name, m in motions.items():
        t = np.arange(0.0, m.duration, 1.0 / RATE)
        pose = m.sample(t)
        glob, pos = pose.global_pose(m.skeleton)
        out[name] = {
            "t": t,
            "root": pose.root_pos,
            "local": pose.local_rot,
            "glob": glob,
            "pos": pos,
            "soles": sole_points(m.skeleton, glob, pos),
        }
    return out


def _window(m: PerformerMotion, name: str, t: np.ndarray, margin: float = 0.0) -> np.ndarray:
    p = m.phase(name)
    return (t >= p.t_start + margin) & (t <= p.t_end - margin)


def _heading_frame(glob: np.ndarray) -> np.ndarray:
    """(T, 2) unit forward directions (model z) of the pelvis, projected on the ground."""
    fwd = glob[:, 0, :2, 2]
    return fwd / np.linalg.norm(fwd, axis=-1, keepdims=True)


# --------------------------------------------------------------------------- structure


def test_scenarios_sample_finite_orthonormal(motions, dense):
    for name, d in dense.items():
        local = d["local"]
        assert np.all(np.isfinite(local)) and np.all(np.isfinite(d["root"])), name
        eye = np.swapaxes(local, -1, -2) @ local
        np.testing.assert_allclose(eye, np.broadcast_to(np.eye(3), eye.shape), atol=1e-9, err_msg=name)
        np.testing.assert_allclose(np.linalg.det(local), 1.0, atol=1e-9, err_msg=name)
        assert local.shape == (len(d["t"]), 24, 3, 3) and d["root"].shape == (len(d["t"]), 3)


def test_phases_tile_the_capture(motions):
    for name, m in motions.items():
        phases = m.phases
        assert [p.name for p in phases[:4]] == list(CALIBRATION)
        assert phases[0].t_start == 0.0 and phases[-1].t_end == pytest.approx(m.duration)
        assert m.duration == pytest.approx(DURATION)
        for a, b in zip(phases, phases[1:], strict=False):
            assert a.t_end == pytest.approx(b.t_start) and a.t_end > a.t_start
        activities = [p.name for p in phases[4:] if p.name not in ("transition", "turn")]
        if name == "mixed":
            assert len(activities) >= 2 and set(activities) <= set(ACTIVITIES)
        else:
            assert activities == [name]
        assert m.scenario == name


def test_sample_accepts_scalars_and_holds_outside():
    m = make_motion("squat", 12.0, 3, CENTRE, LIDAR_HEIGHT, calibration=False)
    one = m.sample(2.5)
    assert one.root_pos.shape == (1, 3) and one.local_rot.shape == (1, 24, 3, 3)
    np.testing.assert_array_equal(m.sample(np.array([-1.0])).local_rot, m.sample(np.array([0.0])).local_rot)
    np.testing.assert_array_equal(m.sample(np.array([99.0])).root_pos, m.sample(np.array([m.duration])).root_pos)


def test_body_scale_scales_the_skeleton():
    base = load_skeleton()
    m = make_motion("arms", 15.0, 1, CENTRE, LIDAR_HEIGHT, body_scale=1.07)
    np.testing.assert_allclose(m.skeleton.offsets, 1.07 * base.offsets)
    assert m.skeleton.pelvis_height == pytest.approx(1.07 * base.pelvis_height)
    drawn = [
        make_motion("arms", 15.0, s, CENTRE, LIDAR_HEIGHT).skeleton.pelvis_height / base.pelvis_height for s in range(6)
    ]
    assert all(0.9 <= d <= 1.1 for d in drawn) and np.ptp(drawn) > 0.02


def test_rejects_bad_arguments():
    with pytest.raises(ValueError, match="unknown scenario"):
        make_motion("swim", 30.0, 0, CENTRE, LIDAR_HEIGHT)
    with pytest.raises(ValueError, match="needs duration_s"):
        make_motion("dance", 8.0, 0, CENTRE, LIDAR_HEIGHT)
    with pytest.raises(ValueError, match="area_radius"):
        make_motion("walk", 30.0, 0, CENTRE, LIDAR_HEIGHT, area_radius=0.3)


# --------------------------------------------------------------------------- determinism


def test_same_seed_same_motion_other_seed_other_motion():
    t = np.linspace(0.0, 30.0, 500)
    a = make_motion("mixed", 30.0, 42, CENTRE, LIDAR_HEIGHT).sample(t)
    b = make_motion("mixed", 30.0, 42, CENTRE, LIDAR_HEIGHT).sample(t)
    np.testing.assert_array_equal(a.root_pos, b.root_pos)
    np.testing.assert_array_equal(a.local_rot, b.local_rot)
    c = make_motion("mixed", 30.0, 43, CENTRE, LIDAR_HEIGHT).sample(t)
    assert np.max(np.abs(a.root_pos - c.root_pos)) > 0.1
    assert np.max(np.abs(a.local_rot - c.local_rot)) > 0.1
    for scenario in ("walk", "dance"):  # single activities differ by seed as well
        x = make_motion(scenario, 30.0, 1, CENTRE, LIDAR_HEIGHT).sample(t)
        y = make_motion(scenario, 30.0, 2, CENTRE, LIDAR_HEIGHT).sample(t)
        assert np.max(np.abs(x.local_rot - y.local_rot)) > 0.1


def test_random_motion_is_deterministic_and_varied():
    rng = np.random.default_rng(0)
    drawn = {random_scenario(rng) for _ in range(200)}
    assert drawn == set(SCENARIOS)
    a, b = random_motion(5, 30.0, CENTRE, LIDAR_HEIGHT), random_motion(5, 30.0, CENTRE, LIDAR_HEIGHT)
    assert a.scenario == b.scenario and a.scenario in SCENARIOS
    np.testing.assert_array_equal(a.sample(np.array([20.0])).local_rot, b.sample(np.array([20.0])).local_rot)
    assert len({random_motion(s, 30.0, CENTRE, LIDAR_HEIGHT).scenario for s in range(12)}) >= 3


# --------------------------------------------------------------------------- calibration


@pytest.mark.parametrize("centre", [np.array([4.0, 0.0, 0.0]), np.array([-6.0, 9.0, 0.0]), np.array([3.0, -24.0, 0.5])])
def test_calibration_holds_contract_poses_facing_the_lidar(centre):
    m = make_motion("walk", 25.0, 7, centre, LIDAR_HEIGHT)
    skel = m.skeleton
    for name, pose in (("a_pose", "a_pose"), ("t_pose", "t_pose")):
        p = m.phase(name)
        assert p.t_end - p.t_start >= 2.0
        t = np.linspace(p.t_start, p.t_end, 60)
        sample = m.sample(t)
        glob, pos = sample.global_pose(skel)
        assert np.max(np.ptp(pos, axis=0)) < 0.01  # still: every joint within 1 cm
        assert np.max(np.ptp(glob, axis=0)) < np.radians(0.5)
        np.testing.assert_allclose(
            sample.local_rot[:, 1:], np.broadcast_to(skel.pose_local_rotations(pose)[1:], (60, 23, 3, 3)), atol=1e-9
        )
        # facing the LiDAR: the body's forward axis (model z) points at the origin, horizontally, upright
        fwd, up = glob[0, 0, :, 2], glob[0, 0, :, 1]
        to_lidar = -pos[0, 0, :2] / np.linalg.norm(pos[0, 0, :2])
        cos = np.dot(fwd[:2], to_lidar) / np.linalg.norm(fwd[:2])  # may round to just above 1 when exact
        assert np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) < 3.0
        assert abs(fwd[2]) < 0.02 and up[2] > 0.999
        # arms: A-pose 60 degrees below horizontal, T-pose horizontal, on the correct sides
        for side, wrist, shoulder in ((1.0, 20, 16), (-1.0, 21, 17)):
            arm = pos[0, wrist] - pos[0, shoulder]
            elevation = np.degrees(np.arctan2(arm[2], np.hypot(arm[0], arm[1])))
            assert elevation == pytest.approx(-60.0 if name == "a_pose" else 0.0, abs=1.5)
            lateral = np.dot(arm, glob[0, 0, :, 0])  # along the body's left axis
            assert np.sign(lateral) == side
        soles = sole_points(skel, glob, pos)[..., 2] + LIDAR_HEIGHT
        assert np.min(soles) == pytest.approx(0.0, abs=1e-6)  # standing on the ground
        assert np.hypot(*(pos[0, 0, :2] - centre[:2])) < 1e-9
    transition = m.phase("to_motion")
    assert 0.5 <= transition.t_end - transition.t_start <= 1.0
    assert m.phase("a_to_t").t_end <= m.phase("t_pose").t_start + 1e-12


def test_without_calibration_motion_starts_at_once():
    m = make_motion("walk", 10.0, 3, CENTRE, LIDAR_HEIGHT, calibration=False)
    assert m.phases[0].name == "walk" and m.phases[0].t_start == 0.0
    glob, pos = m.sample(np.array([0.0])).global_pose(m.skeleton)
    to_lidar = -CENTRE[:2] / np.linalg.norm(CENTRE[:2])
    assert np.dot(_heading_frame(glob)[0], to_lidar) > np.cos(np.radians(3.0))


# --------------------------------------------------------------------------- ground, area, joint limits


def test_feet_on_the_ground(motions, dense):
    for name, d in dense.items():
        lowest = np.min(d["soles"][..., 2], axis=-1) + LIDAR_HEIGHT
        assert lowest.min() > -0.01, name  # never (more than 1 cm) into the ground
        if name in ("walk", "squat", "arms", "martial", "dance"):
            assert lowest.max() < 0.02, name  # a foot is always on the ground
        else:
            assert np.median(lowest) < 0.01 and lowest.max() < 0.8, name
    jump, run = (np.min(dense[n]["soles"][..., 2], axis=-1) + LIDAR_HEIGHT for n in ("jump", "run"))
    assert np.mean(jump > 0.1) > 0.03  # jumps leave the ground ...
    assert np.mean(run > 0.015) > 0.005  # ... and so does running, briefly


def test_planted_feet_do_not_slide(motions, dense):
    for name in ("walk", "run", "squat", "martial", "dance"):
        d = dense[name]
        soles = d["soles"]
        height = soles[..., 2] + LIDAR_HEIGHT
        speed = np.linalg.norm(np.gradient(soles[..., :2], 1.0 / RATE, axis=0), axis=-1)
        for side in (0, 1):
            points = [side, 2 + side, 4 + side]  # heel, ball, toe of one foot
            contact = np.where(height[:, points] < 0.003, speed[:, points], np.inf).min(axis=-1)  # the pivot
            contact = contact[np.isfinite(contact)]
            assert len(contact) > 0.3 * len(d["t"]), name
            assert np.percentile(contact, 95) < 0.12, (name, side)


def test_performer_stays_in_the_area(motions, dense):
    for name, d in dense.items():
        r = np.linalg.norm(d["root"][:, :2] - CENTRE[:2], axis=-1)
        assert r.max() <= 3.0, name
    for seed in range(4):  # a small area far from the LiDAR
        centre = np.array([-18.0, 16.0, 0.0])
        m = make_motion("mixed", 40.0, seed, centre, LIDAR_HEIGHT, area_radius=1.6)
        root = m.sample(np.linspace(0.0, m.duration, 2000)).root_pos
        assert np.linalg.norm(root[:, :2] - centre[:2], axis=-1).max() <= 1.6


def test_walks_from_the_rim_turn_along_it_first():
    """Off the centre, facing out, the performer steps round before walking a loop that still fits."""
    turned = 0
    for seed in range(12):
        m = make_motion("mixed", 60.0, seed, CENTRE, LIDAR_HEIGHT)
        names = [p.name for p in m.phases]
        for k in (k for k, n in enumerate(names) if n == "turn"):
            turned += 1
            assert names[k + 1] in ("walk", "run")
            turn, walk = m.phases[k], m.phases[k + 1]
            assert 0.5 < turn.t_end - turn.t_start < 3.0
            t = np.linspace(walk.t_start, walk.t_end, 600)
            root = m.sample(t).root_pos[:, :2]
            assert np.ptp(root, axis=0).max() > 1.5  # a real loop, not stepping in place
            assert np.linalg.norm(root - CENTRE[:2], axis=-1).max() <= 3.0
    assert turned > 0


def test_walkers_cover_the_area(motions, dense):
    for name in ("walk", "run"):
        r = np.linalg.norm(dense[name]["root"][:, :2] - CENTRE[:2], axis=-1)
        assert r.max() > 1.5, name  # they do get around, not step in place


def test_knees_and_elbows_bend_one_way(dense):
    for name, d in dense.items():
        knees = d["local"][:, [4, 5]]
        np.testing.assert_allclose(
            knees[..., 0, :], np.broadcast_to([1.0, 0.0, 0.0], knees[..., 0, :].shape), atol=1e-9
        )
        flexion = np.degrees(np.arctan2(knees[..., 2, 1], knees[..., 1, 1]))
        assert flexion.min() >= -1e-6 and flexion.max() < 150.0, name  # never hyper-extended backwards
        elbows = Rotation.from_matrix(d["local"][:, [18, 19]].reshape(-1, 3, 3)).as_euler("YZX").reshape(-1, 2, 3)
        assert np.all(elbows[:, 0, 0] <= 1e-6) and np.all(elbows[:, 1, 0] >= -1e-6), name  # left: -y, right: +y
        assert np.degrees(np.abs(elbows[..., 0])).max() < 150.0, name


def test_knee_flexion_moves_the_ankle_behind_the_knee(dense):
    d = dense["walk"]
    flexed = np.degrees(np.arctan2(d["local"][:, 4, 2, 1], d["local"][:, 4, 1, 1])) > 40.0
    assert flexed.any()
    thigh = d["pos"][flexed, 4] - d["pos"][flexed, 1]
    shank = d["pos"][flexed, 7] - d["pos"][flexed, 4]
    fwd = d["glob"][flexed, 1, :, 2]  # the thigh's own forward axis
    # the shank turns backwards relative to the thigh: the knee points forward
    assert np.all(np.einsum("ta,ta->t", np.cross(thigh, shank), d["glob"][flexed, 1, :, 0]) > 0)
    assert np.all(np.einsum("ta,ta->t", shank, fwd) < np.einsum("ta,ta->t", thigh, fwd))


# --------------------------------------------------------------------------- plausibility of the activities


def test_walking_swings_arms_against_legs(motions, dense):
    m, d = motions["walk"], dense["walk"]
    p = m.phase("walk")
    cruise = (d["t"] > p.t_start + 3.0) & (d["t"] < p.t_end - 3.0)
    fwd = _heading_frame(d["glob"][cruise])
    rel = d["pos"][cruise] - d["pos"][cruise, :1]
    ahead = np.einsum("tja,ta->tj", rel[..., :2], fwd)  # forward of the pelvis
    for wrist, ankle in ((20, 7), (21, 8)):
        assert np.corrcoef(ahead[:, wrist], ahead[:, ankle])[0, 1] < -0.5  # arm back while the leg is forward
    speed = np.linalg.norm(np.diff(d["root"][cruise, :2], axis=0), axis=-1) * RATE
    assert 0.5 < np.mean(speed) < 2.0
    run = np.linalg.norm(np.diff(dense["run"]["root"][:, :2], axis=0), axis=-1) * RATE
    assert np.percentile(run, 90) > np.mean(speed)  # running is faster


def test_squats_go_down_and_jumps_go_up(dense):
    pelvis = {n: dense[n]["root"][:, 2] + LIDAR_HEIGHT for n in ("squat", "jump", "arms")}
    stand = np.median(pelvis["arms"])
    assert stand - pelvis["squat"].min() > 0.15
    assert pelvis["jump"].max() - stand > 0.08
    assert np.ptp(pelvis["arms"][dense["arms"]["t"] > 8.0]) < 0.05


# --------------------------------------------------------------------------- smoothness


def _positions(m: PerformerMotion, t: np.ndarray) -> np.ndarray:
    return forward_kinematics(m.skeleton, *(lambda p: (p.local_rot, p.root_pos))(m.sample(t)))[1]


def _accel(m: PerformerMotion, t: np.ndarray, dt: float) -> np.ndarray:
    """(T, 24) finite-difference acceleration magnitudes around times ``t``."""
    p = _positions(m, np.concatenate([t - dt, t, t + dt])).reshape(3, len(t), 24, 3)
    return np.linalg.norm(p[0] - 2.0 * p[1] + p[2], axis=-1) / dt**2


def test_motion_is_smooth_at_1khz(motions):
    """Bounded velocity and acceleration; no velocity jumps (they would grow as 1/dt on a finer grid)."""
    for name, m in motions.items():
        t = np.arange(0.0, m.duration, 1e-3)
        acc_max, vel_max = np.zeros(len(t)), 0.0
        for chunk in np.array_split(np.arange(len(t)), 8):
            pos = _positions(m, t[chunk])
            vel_max = max(vel_max, float(np.max(np.linalg.norm(np.diff(pos, axis=0), axis=-1))) / 1e-3)
            acc_max[chunk[1:-1]] = np.max(np.linalg.norm(pos[2:] - 2.0 * pos[1:-1] + pos[:-2], axis=-1), axis=-1) / 1e-6
        assert vel_max < 15.0, name  # no pops: nothing moves more than 1.5 cm per ms
        assert acc_max.max() < 600.0, name
        worst = t[np.argsort(acc_max)[-5:]]
        boundaries = np.array([p.t_start for p in m.phases[1:]])
        for probe in (worst, boundaries):
            coarse, fine = _accel(m, probe, 1e-3), _accel(m, probe, 1e-4)
            assert np.all(fine.max(axis=1) < 1.5 * coarse.max(axis=1) + 5.0), name


def test_sampling_is_fast(motions):
    m = motions["mixed"]
    t = np.linspace(0.0, m.duration, 1000)
    m.sample(t)
    start = time.perf_counter()
    m.sample(t)
    assert time.perf_counter() - start < 0.25


def test_min_durations_are_enough():
    for k, scenario in enumerate(SCENARIOS):
        m = make_motion(scenario, MIN_DURATION[scenario], k, CENTRE, LIDAR_HEIGHT, calibration=False)
        assert m.duration == pytest.approx(MIN_DURATION[scenario])
        assert np.all(np.isfinite(m.sample(np.linspace(0.0, m.duration, 200)).local_rot))
