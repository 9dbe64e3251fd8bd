"""The hip mounting's estimate (lip_ros.hsc4d.mount): its spin from the ground at the start, its hip from the wearer's
own returns at the start, levelled with gravity at the start, turned about the body's axis by walking, its lever arm
from the body's turns, its rotation from the walk's turns (hand-eye)."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.core.frames import R_L_M_FACING_X
from lip_ros.core.rotations import axis_angle_to_matrix, matrix_to_axis_angle, rot_x, rot_z
from lip_ros.hsc4d.mount import (
    HipMountPrior,
    LeverArmEstimator,
    MountRotationEstimator,
    MountYawEstimator,
    SideCheck,
    SideCheckConfig,
    SpinCheck,
    SpinCheckConfig,
    levelled_mount_rotation,
    rotation_between,
)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(matrix_to_axis_angle(a.T @ b))))


def _ground_in_lidar(mount: HipMountPrior, rng: np.random.Generator, height_m: float = 1.0) -> np.ndarray:
    """Points (N, 3) in L of flat ground 1.2-5.8 m around a wearer standing upright, the sensor mounted as
    ``mount`` ``height_m`` above it, a few points of noise (1 cm)."""
    radius, azimuth = np.sqrt(rng.uniform(1.2**2, 5.8**2, 3000)), rng.uniform(-np.pi, np.pi, 3000)
    ground = np.column_stack([radius * np.cos(azimuth), radius * np.sin(azimuth), rng.normal(0.0, 0.01, 3000)])
    R_W_L = R_L_M_FACING_X @ mount.R_M_L  # the body facing the world's x, upright
    return (ground - [0.0, 0.0, height_m]) @ R_W_L


@pytest.mark.parametrize("spin_deg", [0.0, 90.0, 180.0, -135.0, 20.0])
def test_the_spin_about_the_sensors_axis_is_read_from_the_ground(spin_deg):
    """Whatever the sensor's spin, the ground's up lies the tilt from its axis and turns about it with the spin:
    one sweep of ground reads the spin against the nominal mounting's within half a degree; five agreeing sweeps
    decide, a spin 30 deg or more off the nominal is the correction to use (and the status says to set
    ``mount_spin_deg``), a smaller one is left to levelling and the walk's yaw."""
    rng = np.random.default_rng(1)
    true = HipMountPrior(tilt_up_deg=28.0, spin_deg=spin_deg)
    check = SpinCheck(HipMountPrior())
    reading = check.reading_deg(_ground_in_lidar(true, rng))
    assert abs((reading - spin_deg + 180.0) % 360.0 - 180.0) < 0.5
    decided = [check.add(_ground_in_lidar(true, rng)) for _ in range(SpinCheckConfig().sweeps)]
    assert decided == [False] * (len(decided) - 1) + [True] and check.decided
    if abs(spin_deg) >= SpinCheckConfig().min_error_deg:
        assert abs((check.correction_deg - spin_deg + 180.0) % 360.0 - 180.0) < 0.5
        assert -180.0 <= check.spin_deg <= 180.0 and abs((check.spin_deg - spin_deg + 180.0) % 360.0 - 180.0) < 0.5
        assert f"used {check.spin_deg:.0f} deg (set mount_spin_deg to it)" in check.status
    else:
        assert check.correction_deg == 0.0 and check.status.startswith("as configured")


def test_the_spin_stays_as_configured_when_the_ground_does_not_tell():
    """A sensor hardly tilted shows no spin in the ground's up; ground a hip's height under nothing (a sensor on a
    mast), or readings that disagree (a wall taken for the ground in some sweeps): the spin stays as configured,
    and the status says why."""
    rng = np.random.default_rng(2)
    level = SpinCheck(HipMountPrior(tilt_up_deg=3.0))
    assert level.reading_deg(_ground_in_lidar(HipMountPrior(tilt_up_deg=3.0, spin_deg=180.0), rng)) is None
    while not level.add(_ground_in_lidar(HipMountPrior(tilt_up_deg=3.0, spin_deg=180.0), rng)):
        pass
    assert level.correction_deg == 0.0 and "not read in 30 sweeps" in level.status
    assert SpinCheck(HipMountPrior()).reading_deg(_ground_in_lidar(HipMountPrior(spin_deg=90.0), rng, 3.0)) is None
    split = SpinCheck(HipMountPrior())
    for spin in (0.0, 40.0, 0.0, 40.0, 0.0):
        split.add(_ground_in_lidar(HipMountPrior(spin_deg=spin), rng))
    assert split.correction_deg == 0.0 and "disagree" in split.status
    skipped = SpinCheck(HipMountPrior())
    skipped.skip("as saved (resumed)")
    assert skipped.decided and skipped.add(_ground_in_lidar(HipMountPrior(spin_deg=180.0), rng))
    assert skipped.correction_deg == 0.0


def _own_returns_in_lidar(mount: HipMountPrior, body_side: float, rng: np.random.Generator, count: int = 200
                          ) -> np.ndarray:
    """Points (N, 3) in L: ``count`` returns of the wearer 0.65-0.85 m from the sensor, 0.2-0.6 m to its
    ``body_side`` (+1: left, the pelvis frame's +x; 0: half on each side), and ground 1.5-6 m away, the sensor mounted
    as ``mount`` (its rotation) 1 m above it."""
    side = np.where(rng.random(count) < 0.5, 1.0, -1.0) if body_side == 0 else np.full(count, body_side)
    lateral = side * rng.uniform(0.2, 0.6, count)
    rest = rng.normal(size=(count, 2))
    rest *= (np.sqrt(rng.uniform(0.65**2, 0.85**2, count) - lateral**2) / np.linalg.norm(rest, axis=1))[:, None]
    own_M = np.column_stack([lateral, rest])  # (x left, y up, z forward) from the sensor
    ground = _ground_in_lidar(mount, rng)
    ground = ground[np.linalg.norm(ground, axis=1) > 1.5]
    return np.concatenate([own_M @ mount.R_M_L, ground])  # M -> L: R_M_L^T p, as rows


@pytest.mark.parametrize(("worn", "spin_deg"), [("right", 0.0), ("left", 0.0), ("left", 180.0)])
def test_the_hip_the_sensor_is_worn_on_is_read_from_the_wearers_own_returns(worn, spin_deg):
    """The wearer stands toward the body's middle of a hip-worn sensor: its own returns lie to the sensor's left
    on the right hip (the nominal lever arm's), to its right on the left hip, in the pelvis frame's axes through the
    mounting's rotation (spun or not). Three agreeing sweeps decide: on the nominal hip the lever arm stays; on
    the other it is mirrored across the body's middle, and the status says to set ``mount_lever_m``."""
    rng = np.random.default_rng(3)
    mount = HipMountPrior(spin_deg=spin_deg)
    body_side = 1.0 if worn == "right" else -1.0
    sweeps = [_own_returns_in_lidar(mount, body_side, rng) for _ in range(SideCheckConfig().sweeps)]
    check = SideCheck(HipMountPrior())
    assert check.reading(sweeps[0], mount.R_M_L) == body_side and not check.decided
    check.check(sweeps, mount.R_M_L)
    assert check.decided
    if worn == "right":
        assert check.lever_m == HipMountPrior().lever_m and not check.mirrored
        assert check.status == "as configured (the wearer's own returns: the right hip)"
    else:
        assert check.lever_m == (0.15, 0.0, -0.1) and check.mirrored
        assert "on the left hip" in check.status and "(set mount_lever_m to it)" in check.status


def test_the_hip_stays_as_configured_when_the_wearers_own_returns_do_not_tell():
    """No own returns (the body outside the field of view or nearer than the sensor's minimum range), returns on
    both sides in every sweep, sweeps telling both hips, a nominal lever arm at the body's middle, or a check
    skipped: the lever arm stays as configured, and the status says why. Non-finite points are left out."""
    rng = np.random.default_rng(4)
    mount = HipMountPrior()
    cases = {
        "told a side in 0 of 4 sweeps": [_ground_in_lidar(mount, rng) for _ in range(4)],
        "told a side in 0 of 3 sweeps": [_own_returns_in_lidar(mount, 0.0, rng) for _ in range(3)],
        "told both sides (2 sweeps the right hip, 1 the left)":
            [_own_returns_in_lidar(mount, side, rng) for side in (1.0, -1.0, 1.0)],
    }
    for status, sweeps in cases.items():
        check = SideCheck(mount)
        check.check(sweeps, mount.R_M_L)
        assert check.lever_m == mount.lever_m and not check.mirrored and status in check.status
    middle = SideCheck(HipMountPrior(lever_m=(0.0, 0.0, -0.15)))
    middle.check([_own_returns_in_lidar(mount, -1.0, rng) for _ in range(3)], mount.R_M_L)
    assert middle.lever_m == (0.0, 0.0, -0.15) and "not to a side" in middle.status
    nan = np.full((50, 3), np.nan)
    found = SideCheck(mount)
    found.check([np.concatenate([_own_returns_in_lidar(mount, -1.0, rng), nan]) for _ in range(3)], mount.R_M_L)
    assert found.mirrored
    skipped = SideCheck(mount)
    skipped.skip("as saved (resumed)")
    skipped.check([_own_returns_in_lidar(mount, -1.0, rng) for _ in range(3)], mount.R_M_L)
    assert skipped.decided and not skipped.mirrored and skipped.status == "as saved (resumed)"


def test_rotation_between_takes_one_direction_onto_another():
    rng = np.random.default_rng(0)
    for _ in range(20):
        a, b = rng.normal(size=3), rng.normal(size=3)
        R = rotation_between(a, b)
        assert np.allclose(R @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-12)
        assert np.allclose(R @ np.cross(a, b), np.cross(a, b), atol=1e-12)  # about their common normal
    assert np.allclose(rotation_between([1.0, 0.0, 0.0], [2.0, 0.0, 0.0]), np.eye(3))
    with pytest.raises(ValueError):
        rotation_between([1.0, 0.0, 0.0], [-1.0, 0.0, 0.0])


def test_levelling_puts_gravity_where_the_ground_says_and_leaves_the_turn_about_it():
    """A mounting 4 deg off the nominal: levelled with one still pose's up (pelvis and sensor) it maps that up
    exactly, and what is left of its error is a turn about the body's axis only."""
    nominal = HipMountPrior().R_M_L
    true = nominal @ axis_angle_to_matrix(np.radians([2.0, -3.0, 1.5]))
    up_M = np.array([0.05, 0.99, -0.08])
    up_M /= np.linalg.norm(up_M)
    levelled = levelled_mount_rotation(nominal, up_M, true.T @ up_M)
    assert np.allclose(levelled.T @ up_M, true.T @ up_M, atol=1e-12)
    rest = matrix_to_axis_angle(true @ levelled.T)  # in M
    assert _angle_deg(true, levelled) < _angle_deg(true, nominal)
    assert np.allclose(np.cross(rest, up_M), 0.0, atol=1e-9)


def test_walking_turns_the_mounting_about_the_body_axis_onto_the_truth():
    """Registered steps (5 mm noise each) from a sensor turned 2.5 deg about the body's axis against the suit's
    prediction through the mounting: the first 5 m window gives the turn (within 0.5 deg), and the running mean
    of the windows after it brings the mounting within 0.2 deg of the truth over 100 m (measured 0.08)."""
    rng = np.random.default_rng(1)
    nominal = HipMountPrior().R_M_L
    axis_M = np.array([0.0, 1.0, 0.0])
    true = nominal @ axis_angle_to_matrix(np.radians(2.5) * (nominal.T @ axis_M))
    estimate, estimator = nominal, MountYawEstimator()
    corrections = []
    for k in range(800):  # 0.12 m steps, forward and a little aside
        step_M = np.array([0.02 * np.sin(k / 7.0), 0.01 * np.cos(k / 3.0), 0.12])
        registered = true.T @ step_M + rng.normal(0.0, 0.005, 3)
        predicted = estimate.T @ step_M
        axis = estimate.T @ axis_M
        angle = estimator.add(registered, predicted, axis)
        if angle is not None:
            corrections.append(np.degrees(angle))
            estimate = estimate @ axis_angle_to_matrix(-angle * axis)
    assert estimator.windows >= 18
    assert abs(corrections[0] + 2.5) < 0.5  # registered steps turned by -2.5 deg from the prediction
    assert _angle_deg(true, estimate) < 0.2


def _pose(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, p
    return out


def test_the_lever_arm_comes_from_the_turns_of_walking():
    """60 s of walking at 10 Hz (1.2 m/s, turning, the hip yawing 5 deg each stride) with a sensor 2.5 cm
    left and 2 cm behind its nominal place: registrations with 3 mm of noise, the suit's poses in its own world
    (turned 40 deg) with a 3 % stride-scale error. The estimate of the horizontal lever comes within 5 mm of the
    truth (the stride scale found with it) and the vertical stays nominal, through a jump whose registrations are
    5 cm off (the pelvis pitching 20 deg); the estimate is given once per 5 s at most, once it is good to 1 cm."""
    rng = np.random.default_rng(2)
    prior = HipMountPrior()
    true_lever = np.asarray(prior.lever_m) + [0.025, 0.01, -0.02]
    T_M_L = _pose(prior.R_M_L, true_lever)
    R_W_M0 = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # x left, y up, z forward in z-up W
    estimator = LeverArmEstimator(prior.lever_m)
    position, updates = np.zeros(3), []
    for k in range(600):
        t = k / 10.0
        heading = 1.6 * np.sin(t / 4.0) + np.radians(5.0) * np.sin(2.0 * np.pi * t)
        jump = 10.0 <= t < 11.0
        R_W_M = rot_z(heading) @ R_W_M0 @ rot_x(np.radians(20.0 if jump else 2.0 * np.sin(4.0 * np.pi * t)))
        position = position + 0.12 * np.array([np.cos(heading), np.sin(heading), 0.0])
        T_W_L = _pose(R_W_M, position) @ T_M_L
        T_W_L[:3, 3] += rng.normal(0.0, 0.003, 3) + (0.05 if jump else 0.0)
        T_I_P = _pose(rot_z(0.7) @ R_W_M, rot_z(0.7) @ position * 1.03)
        lever = estimator.add(int(t * 1e9), T_W_L, T_I_P, prior.R_M_L)
        if lever is not None:
            updates.append((t, lever))
    assert np.all(np.diff([t for t, _ in updates]) >= 5.0)
    assert np.allclose(updates[-1][1], estimator.lever_m)
    error = estimator.lever_m - true_lever
    assert np.hypot(error[0], error[2]) < 0.005, error
    assert estimator.lever_m[1] == prior.lever_m[1] and estimator.sigma_m[1] == 0.0
    assert 0.0 < estimator.sigma_m[0] < 0.01 and estimator.intervals > 500  # the prior: 0.03
    assert abs(estimator.scale - 1.0 / 1.03) < 0.005


def _walk_rotations(seconds: float, sway_deg: float, rng: np.random.Generator) -> list[np.ndarray]:
    """The pelvis's rotations R_I_P at 10 Hz: walking with a 90 deg turn every 8 s, the hips yawing 5 deg and
    swaying ``sway_deg`` (pitch and roll) each stride, upright (the pelvis frame's y up)."""
    upright = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # M's y along the world's z
    out = []
    for k in range(int(seconds * 10)):
        t = k / 10.0
        heading = np.radians(90.0) * np.clip((t % 8.0) - 6.0, 0.0, 1.0) + np.radians(90.0) * (t // 8.0)
        stride = 2.0 * np.pi * t
        sway = np.radians(sway_deg) * np.array([np.sin(stride), 0.0, np.cos(stride)])
        out.append(rot_z(heading + np.radians(5.0) * np.sin(stride)) @ upright @ axis_angle_to_matrix(sway))
    return out


def test_the_walks_turns_give_the_mounting_rotation_without_the_ground():
    """Hand-eye rotations: a sensor mounted 12 deg off the nominal (about a tilted axis), its registered
    rotations 0.1 deg noisy, in an odometry frame turned anyhow against the suit's world: nothing until the
    turns excite two directions; then within 0.3 deg of the truth (all three angles; measured 0.22). A walk
    with no sway of the hips excites one direction only (the vertical) and gives nothing."""
    rng = np.random.default_rng(2)
    nominal = HipMountPrior().R_M_L
    true = nominal @ axis_angle_to_matrix(np.radians(12.0) * np.array([0.6, 0.8, 0.0]))
    W = axis_angle_to_matrix(np.array([0.3, -1.1, 0.7]))  # the odometry frame O in the suit's world I
    estimator, first = MountRotationEstimator(), None
    for k, R_I_P in enumerate(_walk_rotations(30.0, 3.0, rng)):
        noise = axis_angle_to_matrix(rng.normal(0.0, np.radians(0.1), 3))
        estimator.add(k * 100_000_000, W.T @ R_I_P @ true @ noise, R_I_P)
        if first is None and estimator.R_M_L is not None:
            first = k
    assert first is not None and first > 20  # not from the first two seconds
    assert estimator.excitation_deg[1] >= estimator.min_excitation_deg
    assert _angle_deg(estimator.R_M_L, true) < 0.3
    flat = MountRotationEstimator()
    for k, R_I_P in enumerate(_walk_rotations(30.0, 0.0, rng)):
        flat.add(k * 100_000_000, W.T @ R_I_P @ true, R_I_P)
    assert flat.excitation_deg[0] > 100.0 and flat.R_M_L is None
