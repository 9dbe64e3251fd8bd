"""The fused body: the suit's segments on a pelvis pose, against the rig's truth."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lip_msgs_py import imu_sample
from lip_ros.core.rotations import geodesic_angle, matrix_to_quat, rot_x, rot_z
from lip_ros.core.skeleton import load_skeleton
from lip_ros.hsc4d.suit_body import (
    FEET,
    BodyPose,
    SuitBody,
    SuitBodyConfig,
    bent_legs,
    leg_chains,
    moved_body,
    resized_body,
    unmeasured_chains,
)
from lip_ros.rig.site_capture import SiteCapture, SiteCaptureConfig


@pytest.fixture(scope="module")
def capture() -> SiteCapture:
    return SiteCapture(SiteCaptureConfig(seed=5, seconds=12.0))


def _fed(capture: SiteCapture, scale: float) -> SuitBody:
    body = SuitBody(load_skeleton(), SuitBodyConfig(body_scale=scale))
    for name, stream in capture.suit_streams().items():
        assert all(r is None for r in body.add(name, list(stream.samples(name))[-body.config.capacity:]))
    return body


def _errors(capture: SiteCapture, body: SuitBody, turn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Root-relative joint errors (m) and global rotation errors (rad) over the capture's last 8 s, the body posed
    on the true pelvis seen from a frame turned by ``turn`` about z (the map's heading is arbitrary)."""
    t = np.arange(4.0, 11.9, 0.1)
    truth = capture.truth(t)
    offset = int(round(capture.suit.clock_offset_s * 1e9))
    joints, errors = [], []
    for k, tk in enumerate(t):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = turn @ truth.R_W_M[k], turn @ truth.pelvis[k]
        pose, reason = body.pose(capture.epoch_ns + int(round(tk * 1e9)) + offset, T)
        assert pose is not None and reason == "", reason
        joints.append(pose.joints @ turn)  # back in the site's frame
        errors.append(geodesic_angle(turn.T @ pose.glob_rot, truth.glob_rot[k]))
    joints = np.array(joints)
    return (np.linalg.norm((joints - joints[:, :1]) - (truth.joints - truth.joints[:, :1]), axis=-1),
            np.array(errors))


def test_the_unmeasured_joints_form_chains_between_measured_ones():
    skeleton = load_skeleton()
    measured = {skeleton.index(j) for j in skeleton.suit_imus.values()}
    chains = {skeleton.names[top]: [skeleton.names[j] for j in chain]
              for top, chain in unmeasured_chains(skeleton, measured)}
    assert chains == {"pelvis": ["spine1", "spine2", "spine3"], "spine3": ["neck", "head"],
                      "left_ankle": ["left_foot"], "right_ankle": ["right_foot"], "left_wrist": ["left_hand"],
                      "right_wrist": ["right_hand"]}
    covered = {j for _, chain in unmeasured_chains(skeleton, measured) for j in chain} | measured
    assert covered == set(range(24))


def test_the_body_matches_the_truth_on_the_true_pelvis(capture):
    """With the performer's true size the suit's joints land within a few mm (the spine and neck shared evenly
    between their sensors, noise); the contract's size (6 % off here) costs tens of mm; the map's heading does
    not matter; the measured segments' rotations are the suit's."""
    true_scale = capture.motion.skeleton.scale
    assert abs(true_scale - 1.0) > 0.03  # the test would not see a wrong size otherwise
    turn = rot_z(0.7)
    err, rot_err = _errors(capture, _fed(capture, true_scale), turn)
    assert err.mean() < 0.010 and err.max() < 0.03, (err.mean(), err.max())
    measured = [load_skeleton().index(j) for j in load_skeleton().suit_imus.values()]
    assert np.degrees(rot_err[:, measured]).mean() < 2.0
    wrong_size, _ = _errors(capture, _fed(capture, 1.0), turn)
    assert wrong_size.mean() > 2 * err.mean()


def test_scale_from_the_standing_pelvis_height(capture):
    body = SuitBody(load_skeleton())
    height = capture.truth(np.array([1.0])).pelvis[0, 2] - capture.terrain.surface_height(
        capture.truth(np.array([1.0])).pelvis[:, :2])[0]
    scale = body.scale_to_pelvis_height(height)
    assert scale == pytest.approx(capture.motion.skeleton.scale, rel=0.02)
    assert body.skeleton.pelvis_height == pytest.approx(height)
    with pytest.raises(ValueError):
        body.scale_to_pelvis_height(float("nan"))


def test_missing_or_bad_suit_data_gives_no_pose_and_says_why():
    body = SuitBody(load_skeleton())
    q = matrix_to_quat(np.eye(3))
    for name in body.segments[1:]:  # every segment but the pelvis
        body.add(name, [imu_sample(k * 10_000_000, name, q, np.zeros(3), np.zeros(3)) for k in range(10)])
    pose, reason = body.pose(50_000_000, np.eye(4))
    assert pose is None and "pelvis" in reason
    bad = [SimpleNamespace(stamp_ns=0, quat=np.array([np.nan, 0.0, 0.0, 1.0]), gyro=np.zeros(3), accel=np.zeros(3)),
           SimpleNamespace(stamp_ns=10_000_000, quat=np.zeros(4), gyro=np.zeros(3), accel=np.zeros(3))]
    assert all(r is not None for r in body.add("pelvis", bad))
    body.add("pelvis", [imu_sample(k * 10_000_000, "p", q, np.zeros(3), np.zeros(3)) for k in range(10)])
    pose, reason = body.pose(50_000_000, np.eye(4))
    assert pose is not None and reason == "" and np.isfinite(pose.joints).all()
    pose, reason = body.pose(2_000_000_000, np.eye(4))  # long after the last sample
    assert pose is None and reason


def test_a_body_moved_to_another_pelvis_pose_is_the_body_posed_there(capture):
    """moved_body (the optimised and refined bodies) gives what posing on the new pelvis pose gives, one frame or
    many at once."""
    body = _fed(capture, 1.0)
    ns = capture.epoch_ns + 8 * 10**9 + int(round(capture.suit.clock_offset_s * 1e9))
    T_from, T_to = np.eye(4), np.eye(4)
    T_from[:3, :3], T_from[:3, 3] = rot_z(0.3), [1.0, 2.0, 0.9]
    T_to[:3, :3], T_to[:3, 3] = rot_z(0.5) @ rot_x(0.05), [1.2, 1.9, 1.0]
    posed, _ = body.pose(ns, T_from)
    there, _ = body.pose(ns, T_to)
    moved = moved_body(posed, T_from, T_to)
    for a, b in ((moved.local_rot, there.local_rot), (moved.glob_rot, there.glob_rot), (moved.joints, there.joints)):
        assert np.allclose(a, b, atol=1e-9)
    stacked = BodyPose(*(np.stack([getattr(posed, f)] * 2) for f in ("local_rot", "glob_rot", "joints")))
    both = moved_body(stacked, np.stack([T_from, T_from]), np.stack([T_to, T_from]))
    assert np.allclose(both.joints[0], there.joints) and np.allclose(both.joints[1], posed.joints)


def test_legs_taken_out_and_bent_back_give_the_body_and_move_only_the_legs(capture):
    """leg_chains and bent_legs (the scene optimisation's legs): the feet the optimiser computes from a leg are the
    skeleton's; the legs put back unchanged give the same body; a turned hip moves that leg's joints only."""
    from lip_ros.hsc4d.scene_optimisation import feet_offsets

    body = _fed(capture, 1.1)
    ns = capture.epoch_ns + 8 * 10**9 + int(round(capture.suit.clock_offset_s * 1e9))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rot_z(0.3) @ rot_x(0.1), [1.0, 2.0, 0.9]
    pose, _ = body.pose(ns, T)
    skeleton = body.skeleton
    legs, bones = leg_chains(skeleton, pose.local_rot)
    feet = [skeleton.index(f) for f in FEET]
    assert np.allclose(feet_offsets(T[None, :3, :3], legs[None], bones[None])[0], pose.joints[feet] - T[:3, 3])
    same = bent_legs(pose, skeleton, legs)
    for a, b in ((same.local_rot, pose.local_rot), (same.glob_rot, pose.glob_rot), (same.joints, pose.joints)):
        assert np.allclose(a, b, atol=1e-12)
    turned = legs.copy()
    turned[0, 0] = rot_x(0.2) @ turned[0, 0]  # the left hip
    bent = bent_legs(pose, skeleton, turned)
    moved = np.flatnonzero(np.linalg.norm(bent.joints - pose.joints, axis=-1) > 1e-9)
    assert {skeleton.names[j] for j in moved} == {"left_knee", "left_ankle", "left_foot"}


def test_a_resized_body_is_the_body_posed_on_a_skeleton_that_size(capture):
    """resized_body (the optimised and refined bodies at the walk's legs' length): what posing on the skeleton
    scaled by the ratio gives, one frame or many at once with a ratio each."""
    ns = capture.epoch_ns + 8 * 10**9 + int(round(capture.suit.clock_offset_s * 1e9))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rot_z(0.3), [1.0, 2.0, 0.9]
    posed, _ = _fed(capture, 1.0).pose(ns, T)
    larger, _ = _fed(capture, 1.04).pose(ns, T)
    resized = resized_body(posed, 1.04)
    for a, b in ((resized.local_rot, larger.local_rot), (resized.glob_rot, larger.glob_rot),
                 (resized.joints, larger.joints)):
        assert np.allclose(a, b, atol=1e-9)
    stacked = BodyPose(*(np.stack([getattr(posed, f)] * 2) for f in ("local_rot", "glob_rot", "joints")))
    both = resized_body(stacked, np.array([1.04, 1.0]))
    assert np.allclose(both.joints[0], larger.joints) and np.allclose(both.joints[1], posed.joints)
