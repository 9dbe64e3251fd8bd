"""The hip mounting's estimate (lip_ros.hsc4d.mount): its spin from the ground at the start, its hip from the wearer's
body at the start, levelled with gravity at the start, turned about the body's axis by walking, its lever arm
from the body's turns, its rotation from the walk's turns (hand-eye)."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.core.body import BodyModel
from lip_ros.core.frames import R_L_M_FACING_X, UP_M
from lip_ros.core.rotations import axis_angle_to_matrix, matrix_to_axis_angle, rot_x, rot_z
from lip_ros.core.skeleton import calibration_pose, load_skeleton
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
    decide (their mean up within half a degree of gravity's), a spin 30 deg or more off the nominal is the
    correction to use (and the status says to set ``mount_spin_deg``), a smaller one is left to levelling and the
    walk's yaw."""
    rng = np.random.default_rng(1)
    true = HipMountPrior(tilt_up_deg=28.0, spin_deg=spin_deg)
    check = SpinCheck(HipMountPrior())
    reading = check.spin_of(check.ground_up(_ground_in_lidar(true, rng)))
    assert abs((reading - spin_deg + 180.0) % 360.0 - 180.0) < 0.5
    decided = [check.add(_ground_in_lidar(true, rng)) for _ in range(SpinCheckConfig().sweeps)]
    assert decided == [False] * (len(decided) - 1) + [True] and check.decided
    assert _angle_deg(np.eye(3), rotation_between(check.up_L, true.R_M_L.T @ [0.0, 1.0, 0.0])) < 0.5  # the up, in L
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
    assert level.ground_up(_ground_in_lidar(HipMountPrior(tilt_up_deg=3.0, spin_deg=180.0), rng)) is None
    while not level.add(_ground_in_lidar(HipMountPrior(tilt_up_deg=3.0, spin_deg=180.0), rng)):
        pass
    assert level.correction_deg == 0.0 and "not read in 30 sweeps" in level.status
    assert SpinCheck(HipMountPrior()).ground_up(_ground_in_lidar(HipMountPrior(spin_deg=90.0), rng, 3.0)) is None
    split = SpinCheck(HipMountPrior())
    for spin in (0.0, 40.0, 0.0, 40.0, 0.0):
        split.add(_ground_in_lidar(HipMountPrior(spin_deg=spin), rng))
    assert split.correction_deg == 0.0 and "disagree" in split.status and split.up_L is None
    skipped = SpinCheck(HipMountPrior())
    skipped.skip("as saved (resumed)")
    assert skipped.decided and skipped.add(_ground_in_lidar(HipMountPrior(spin_deg=180.0), rng))
    assert skipped.correction_deg == 0.0


def _standing_sweep(mount: HipMountPrior, lever_m: tuple[float, float, float] | None = None, scene: str = "room",
                    min_range_m: float = 0.5, beams: int = 64, columns: int = 512) -> np.ndarray:
    """Points (N, 3) in L of one sweep (``beams`` x ``columns`` over +-16.6 deg) of a sensor
    mounted as ``mount`` (at ``lever_m`` if given) on the contract skeleton's body standing in its A-pose, arms and
    all, in ``scene``: "room" (flat ground, a wall all round 4 m away), "field" (the ground only) or "sky" (nothing
    beyond the body), returns nearer than ``min_range_m`` lost."""
    skeleton = load_skeleton()
    glob, joints = calibration_pose(skeleton, "a_pose")
    elevation, azimuth = np.meshgrid(np.radians(np.linspace(-16.6, 16.6, beams)),
                                     np.linspace(-np.pi, np.pi, columns, endpoint=False))
    dirs_L = np.column_stack([(np.cos(elevation) * np.cos(azimuth)).ravel(),
                              (np.cos(elevation) * np.sin(azimuth)).ravel(), np.sin(elevation).ravel()])
    origin = np.array(mount.lever_m if lever_m is None else lever_m)
    dirs_M = dirs_L @ mount.R_M_L.T
    ranges = BodyModel(skeleton).raycast(origin, dirs_M, glob, joints)[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        if scene != "sky":  # the soles' level, 0.95 m under the pelvis
            down = np.where(dirs_M[:, 1] < -1e-6, (-0.95 - origin[1]) / dirs_M[:, 1], np.inf)
            ranges = np.minimum(ranges, np.where(down <= 30.0, down, np.inf))
        if scene == "room":  # |o + t d| = 4 m in the horizontal (x, z)
            o, d = origin[[0, 2]], dirs_M[:, [0, 2]]
            qa, qb = np.sum(d * d, axis=1), d @ o
            ranges = np.minimum(ranges, (-qb + np.sqrt(qb * qb - qa * (o @ o - 16.0))) / qa)
    seen = np.isfinite(ranges) & (ranges >= min_range_m)
    return dirs_L[seen] * ranges[seen, None]


@pytest.mark.parametrize(("worn", "spin_deg", "lever_m", "min_range_m", "beams", "columns"), [
    ("right", 0.0, None, 0.5, 64, 512), ("left", 0.0, (0.15, 0.0, -0.1), 0.5, 64, 512),
    ("left", 180.0, (0.15, 0.0, -0.1), 0.5, 64, 512),
    ("left", 0.0, (0.2, 0.04, -0.02), 0.5, 64, 512),  # a lever arm off the nominal by 5-8 cm
    ("right", 0.0, (-0.11, -0.05, -0.18), 0.5, 64, 512),
    ("right", 0.0, None, 0.1, 64, 512), ("left", 0.0, (0.15, 0.0, -0.1), 0.1, 64, 512),  # the near arm seen
    ("left", 0.0, (0.15, 0.0, -0.1), 0.5, 16, 256), ("right", 0.0, None, 0.5, 128, 512),  # sparser, denser
])
def test_the_hip_the_sensor_is_worn_on_is_read_from_the_wearers_body(worn, spin_deg, lever_m, min_range_m, beams,
                                                                      columns):
    """The wearer's torso and thighs block a hip-worn sensor's rays toward the body's middle: no return lies beyond
    them on the hip it is worn on, while the ground is seen where they would stand on the other. Read through the
    mounting's rotation (spun or not), with the lever arm off the nominal by a few centimetres, with the wearer's own
    returns from 0.1 m (its near arm among them: they take no part), three sweeps decide:
    on the nominal hip the lever arm stays; on the other it is mirrored across the body's middle, and the status
    says to set ``mount_lever_m``. Non-finite and zero points are left out. A sensor of 16 beams at 256 columns
    (an eighth of the returns) or 128 at 512 (twice as many) tells it too."""
    mount = HipMountPrior(spin_deg=spin_deg)
    sweep = _standing_sweep(mount, lever_m, min_range_m=min_range_m, beams=beams, columns=columns)
    right, left = SideCheck(mount).seen_through(sweep, mount.R_M_L)
    if worn == "right":
        assert right == 0 and left > 100
    else:
        assert left == 0 and right > 100
    check = SideCheck(mount)
    check.check([np.concatenate([sweep, np.full((50, 3), np.nan), np.zeros((5, 3))])] * SideCheckConfig().sweeps,
                mount.R_M_L, mount.R_M_L.T @ UP_M)
    assert check.decided
    assert check.hip == worn
    if worn == "right":
        assert check.lever_m == mount.lever_m and not check.mirrored
        assert check.status == "as configured (the wearer's body at the start: the right hip)"
    else:
        assert check.lever_m == (0.15, 0.0, -0.1) and check.mirrored
        assert "puts the LiDAR on the left hip" in check.status and "(set mount_lever_m to it)" in check.status


def test_a_mounting_tilted_otherwise_than_the_nominal_is_levelled_before_the_hip_is_read():
    """A sensor tilted 48 deg where the nominal says 30, on the left hip: the check reads the sweeps through the
    nominal rotation levelled with the ground's up that the spin check read from them (the wearer upright), which
    puts the body where it stands: the other hip's body is then seen through by about twice as many returns as
    through the nominal rotation (1600 against 800 here), and the left hip is told."""
    true, nominal = HipMountPrior(tilt_up_deg=48.0), HipMountPrior()
    sweep = _standing_sweep(true, (0.15, 0.0, -0.1))
    spin = SpinCheck(nominal)
    while not spin.add(sweep):
        pass
    assert spin.up_L is not None and spin.correction_deg == 0.0
    assert _angle_deg(np.eye(3), rotation_between(spin.up_L, true.R_M_L.T @ [0.0, 1.0, 0.0])) < 0.5
    check, used = SideCheck(nominal), []
    seen_through = check.seen_through
    check.seen_through = lambda points, R_M_L: used.append(R_M_L) or seen_through(points, R_M_L)
    check.check([sweep] * 3, nominal.R_M_L, spin.up_L)
    assert check.hip == "left" and check.mirrored and len(used) == 3
    assert _angle_deg(used[0], true.R_M_L) < 3.0 < _angle_deg(nominal.R_M_L, true.R_M_L)
    assert check.seen_through(sweep, used[0])[0] > 1.5 * check.seen_through(sweep, nominal.R_M_L)[0]


def test_a_sweep_tells_a_side_only_when_the_other_sides_body_is_seen_through_and_its_own_hardly():
    """The rule of :meth:`SideCheck.reading` on the counts of returns seen through each side's body: at least the
    returns of ``min_seen_through_deg2`` of the view on the other side (as densely as the sweep's returns sample
    it), at most ``max_share`` of that on this side; nothing from a sweep too sparse to tell its density (a fixed
    count, 30 until session 48, fails at 3 a square degree)."""
    check, c = SideCheck(HipMountPrior()), SideCheckConfig()
    for per_deg2 in (1, 3):  # a 1 x 1 deg grid over +-15 deg, and 3 times as many columns
        el, az = np.meshgrid(np.radians(np.arange(-15.0, 15.5, 1.0)), np.radians(np.arange(0.0, 360.0, 1.0 / per_deg2)))
        sweep = 5.0 * np.column_stack([(np.cos(el) * np.cos(az)).ravel(), (np.cos(el) * np.sin(az)).ravel(),
                                       np.sin(el).ravel()])
        least = c.min_seen_through_deg2 * per_deg2
        cases = {(0, least * 1.05): 1, (least * 1.05, 0): -1, (0, least * 0.95): None,
                 (10 * per_deg2, 40 * per_deg2): 1, (11 * per_deg2, 40 * per_deg2): None,
                 (40 * per_deg2, 10 * per_deg2): -1, (40 * per_deg2, 11 * per_deg2): None, (0, 0): None}
        for counts, told in cases.items():
            check.seen_through = lambda points, R_M_L, counts=counts: counts
            assert check.reading(sweep, np.eye(3)) == told, (per_deg2, counts)
    check.seen_through = lambda points, R_M_L: (0, 1000)
    assert check.reading(sweep[:50], np.eye(3)) is None


def test_the_hip_stays_as_configured_when_the_wearers_body_does_not_tell():
    """Nothing seen beyond the body (the sky), a wearer on an open field (the ground seen only under the rays that
    would meet the other hip's body), fewer sweeps than ``sweeps``, sweeps telling both hips, a nominal lever arm
    at the body's middle, the mounting's rotation not confirmed by the ground (no up: a sensor hardly tilted,
    whose spin the ground does not show; read through the nominal rotation, a level sensor spun half a turn puts
    the rig's right-hip wearers on the left), or a check skipped: the lever arm stays as configured, and the
    status says why. Only the first ``sweeps`` sweeps are read."""
    mount = HipMountPrior()
    up = mount.R_M_L.T @ UP_M
    right, left = _standing_sweep(mount), _standing_sweep(mount, (0.15, 0.0, -0.1))
    cases = [
        ("did not tell a side (sweep 1 of the first 3 read)", [_standing_sweep(mount, scene="sky")] * 4),
        # an open field: the ground is seen only under the rays that meet the other hip's body, too few of them
        ("did not tell a side (sweep 1 of the first 3 read)", [_standing_sweep(mount, (0.15, 0.0, -0.1), "field")] * 3),
        ("did not tell a side (sweep 2 of the first 3 read)", [left, _standing_sweep(mount, scene="sky"), left]),
        ("2 sweeps read, 3 needed", [left, left]),
        ("told both sides (2 sweeps the right hip, 1 the left)", [left, right, right, left]),
    ]
    for status, sweeps in cases:
        check = SideCheck(mount)
        check.check(sweeps, mount.R_M_L, up)
        assert check.lever_m == mount.lever_m and not check.mirrored and check.hip is None and status in check.status
    unconfirmed = SideCheck(mount)
    unconfirmed.check([left] * 3, mount.R_M_L, None)
    assert not unconfirmed.mirrored and "the ground at the start did not confirm" in unconfirmed.status
    middle = SideCheck(HipMountPrior(lever_m=(0.0, 0.0, -0.15)))
    middle.check([left] * 3, mount.R_M_L, up)
    assert middle.lever_m == (0.0, 0.0, -0.15) and "not to a side" in middle.status
    skipped = SideCheck(mount)
    skipped.skip("as saved (resumed)")
    skipped.check([left] * 3, mount.R_M_L, up)
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
