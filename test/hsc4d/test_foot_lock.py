"""The foot lock of the HSC4D bodies: a leg reaching for a point, standing feet held, anchors let go."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.core.rotations import matrix_to_axis_angle, rot_x, rot_z
from lip_ros.core.skeleton import Skeleton, forward_kinematics, load_skeleton
from lip_ros.hsc4d.foot_lock import FootLock, FootLockConfig, leg_reaching, locked_bodies
from lip_ros.hsc4d.suit_body import FEET, LEGS, BodyPose


@pytest.fixture(scope="module")
def skeleton() -> Skeleton:
    return load_skeleton().scaled(1.05)


def _pose(skeleton: Skeleton, root: np.ndarray, yaw: float = 0.4, knee: float = 0.4) -> BodyPose:
    """The A-pose with its knees bent by ``knee`` (rad), turned by ``yaw``, its pelvis at ``root``."""
    local = skeleton.pose_local_rotations("a_pose").copy()
    local[0] = rot_z(yaw) @ local[0]
    for leg in LEGS:
        local[skeleton.index(leg[1])] = local[skeleton.index(leg[1])] @ rot_x(knee)
    glob, joints = forward_kinematics(skeleton, local, np.asarray(root, dtype=np.float64))
    return BodyPose(local, glob, joints)


def test_a_leg_reaching_for_a_point_moves_its_ankle_there_and_nothing_else(skeleton):
    """The ankle lands on the point with its orientation kept (the foot moves with it, turned as before), the bones
    keep their lengths, the rotations are the positions' (forward kinematics), the rest of the body stays; a point
    out of the leg's reach is refused."""
    pose = _pose(skeleton, [1.0, 2.0, 0.9])
    hip, knee, ankle, foot = (skeleton.index(n) for n in LEGS[0])
    shift = np.array([0.03, 0.02, 0.015])
    held = leg_reaching(pose, skeleton, 0, pose.joints[ankle] + shift)
    assert held is not None
    assert np.allclose(held.joints[ankle], pose.joints[ankle] + shift, atol=1e-9)
    assert np.allclose(held.joints[foot], pose.joints[foot] + shift, atol=1e-9)
    for j in (ankle, foot):
        assert np.allclose(held.glob_rot[j], pose.glob_rot[j], atol=1e-12)
    for a, b in ((hip, knee), (knee, ankle), (ankle, foot)):
        assert np.linalg.norm(held.joints[b] - held.joints[a]) == pytest.approx(
            np.linalg.norm(pose.joints[b] - pose.joints[a]), abs=1e-9)
    glob, joints = forward_kinematics(skeleton, held.local_rot, held.joints[0])
    assert np.allclose(glob, held.glob_rot, atol=1e-9) and np.allclose(joints, held.joints, atol=1e-9)
    moved = {skeleton.names[j] for j in np.flatnonzero(np.linalg.norm(held.joints - pose.joints, axis=1) > 1e-12)}
    assert moved == {"left_knee", "left_ankle", "left_foot"}
    turned = {skeleton.names[j] for j in np.flatnonzero(np.abs(held.local_rot - pose.local_rot).max(axis=(1, 2))
                                                        > 1e-12)}
    assert turned <= {"left_hip", "left_knee", "left_ankle"}
    same = leg_reaching(pose, skeleton, 0, pose.joints[ankle])
    for a, b in ((same.local_rot, pose.local_rot), (same.glob_rot, pose.glob_rot), (same.joints, pose.joints)):
        assert np.allclose(a, b, atol=1e-9)
    assert leg_reaching(pose, skeleton, 0, pose.joints[hip] + [0.0, 0.0, -1.5]) is None  # beyond the leg's length
    assert leg_reaching(pose, skeleton, 0, pose.joints[hip] + [0.0, 0.0, -0.01]) is None  # nearer than a fold


@pytest.mark.parametrize("shift", [[0.0, 0.01, 0.0], [0.0, 0.0, 0.03], [0.0, 0.0, -0.03], [0.01, 0.0, 0.0]])
def test_a_nearly_straight_leg_bends_its_knee_about_its_hinge_and_never_back(skeleton, shift):
    """A leg whose knee is bent by 1 degree, its ankle raised, moved forward, back or out: the knee turns about its
    hinge (the skeleton's knees bend about its left-right axis, x; the other components a small part of the
    turn), bends further for the raised ankle, and never comes behind the line from the hip to the ankle; back,
    the leg would be longer than its knee straightened about its hinge: refused."""
    pose = _pose(skeleton, [0.0, 0.0, 0.9], yaw=0.0, knee=np.radians(1.0))
    hip, knee, ankle, _ = (skeleton.index(n) for n in LEGS[0])
    held = leg_reaching(pose, skeleton, 0, pose.joints[ankle] + shift)
    if shift[2] < 0.0:  # back: longer than the knee straightened about its hinge reaches
        assert held is None
        return
    assert held is not None
    line = held.joints[ankle] - held.joints[hip]
    forward = np.cross(line / np.linalg.norm(line), held.glob_rot[hip] @ [1.0, 0.0, 0.0])
    assert (held.joints[knee] - held.joints[hip]) @ forward > -1e-3  # not behind the hip-ankle line
    bend = matrix_to_axis_angle(held.local_rot[knee]) - matrix_to_axis_angle(pose.local_rot[knee])
    assert np.hypot(bend[1], bend[2]) < 0.2 * abs(bend[0]), np.degrees(bend)
    if shift[1] > 0.0:
        assert bend[0] > np.radians(5.0), np.degrees(bend)  # raised 1 cm: the knee bends


def _walk(skeleton: Skeleton, n: int, rng: np.random.Generator) -> tuple[np.ndarray, BodyPose, np.ndarray]:
    """``n`` frames at 10 Hz of a body whose pelvis wanders by a centimetre a frame (its feet with it), and the
    suit's own feet: the left standing still throughout, the right swinging at 1 m/s."""
    t = 0.1 * np.arange(n)
    roots = np.array([1.0, 2.0, 0.9]) + np.cumsum(rng.normal(0.0, 0.006, (n, 3)), axis=0)
    poses = [_pose(skeleton, r) for r in roots]
    bodies = BodyPose(*(np.stack([getattr(p, f) for p in poses]) for f in ("local_rot", "glob_rot", "joints")))
    suit = np.zeros((n, 2, 3))
    suit[:, 1, 0] = t  # 1 m/s
    return t, bodies, suit


def test_a_standing_foot_is_held_where_its_stance_began_and_a_swinging_one_is_not(skeleton):
    """From the second frame (a foot's speed needs two) the standing foot joint keeps the horizontal position the
    body gave it then, at the mean height the body gave it since; the swinging leg and the pelvis are the body's."""
    t, bodies, suit = _walk(skeleton, 30, np.random.default_rng(1))
    out = locked_bodies(skeleton, t, bodies, suit)
    left, right = (skeleton.index(f) for f in FEET)
    assert np.array_equal(out.joints[:2], bodies.joints[:2])  # no speed yet, then the stance begins
    own = bodies.joints[:, left]
    assert np.abs(np.diff(own[1:, :2], axis=0)).max() > 0.005  # the body's own foot slides
    assert np.allclose(out.joints[1:, left, :2], own[1, :2], atol=1e-9)
    mean_z = np.cumsum(own[1:, 2]) / np.arange(1, len(own))
    assert np.allclose(out.joints[1:, left, 2], mean_z, atol=1e-9)
    assert np.array_equal(out.joints[:, right], bodies.joints[:, right])
    assert np.array_equal(out.joints[:, 0], bodies.joints[:, 0])


def test_a_foot_held_too_far_from_the_body_is_let_go_and_held_again_there(skeleton):
    """The pelvis steps 8 cm (a trajectory corrected): the standing foot follows it in that frame and is held
    from there; a frame without the suit's feet keeps it held, more than ``max_frame_gap_s`` without them or
    between frames starts the stances again."""
    t, bodies, suit = _walk(skeleton, 12, np.random.default_rng(2))
    step = np.array([0.08, 0.0, 0.0])
    bodies.joints[6:] += step  # a rigid step of the whole body
    lock = FootLock(skeleton, FootLockConfig())
    left = skeleton.index(FEET[0])
    out = []
    for k in range(12):
        pose = BodyPose(bodies.local_rot[k], bodies.glob_rot[k], bodies.joints[k])
        out.append(lock.step(float(t[k]), pose, suit[k]).joints)
    out = np.array(out)
    assert lock.released == 1
    assert np.array_equal(out[6], bodies.joints[6])  # let go: the body's own
    assert np.allclose(out[7:, left, :2], bodies.joints[6, left, :2], atol=1e-9)  # held again from there
    assert lock.standing() == [True, False]
    # a frame without the suit's feet (its odometry late): the standing foot stays held
    pose = BodyPose(bodies.local_rot[11], bodies.glob_rot[11], bodies.joints[11] + [0.01, 0.0, 0.0])
    held = lock.step(1.2, pose, None)
    assert lock.standing() == [True, False] and np.allclose(held.joints[left, :2], out[-1, left, :2], atol=1e-9)
    # more than max_frame_gap_s without them: the stances start again, nothing held
    assert lock.step(1.8, pose, None) is pose and lock.standing() == [False, False]
    assert lock.step(1.9, pose, suit[11]) is pose  # no speed yet
    assert lock.step(5.0, pose, suit[11]) is pose and lock.standing() == [False, False]  # after a gap
