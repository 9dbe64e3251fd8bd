"""The pose graph fusing LiDAR landmarks with the suit's relative motion (lip_ros.hsc4d.pose_graph, on gtsam),
the suit's track as relative motion (lip_ros.hsc4d.suit_track) and the 4-DoF trajectory alignment."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.core.metrics import align_yaw_translation
from lip_ros.core.rotations import axis_angle_to_matrix, matrix_to_quat, rot_z
from lip_ros.hsc4d.mount import HipMountPrior
from lip_ros.hsc4d.pose_graph import LiveTrajectoryGraph, PoseGraphConfig, fuse_batch
from lip_ros.hsc4d.suit_track import SuitTrack

#: an upright pelvis (x left, y up, z forward) facing +x of the world
_UPRIGHT = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _walk(n: int = 600, climb: slice = slice(300, 360)) -> np.ndarray:
    """(n, 4, 4) pelvis poses at 10 Hz: 1.2 m/s along a slow S-curve, climbing 3 cm a step over ``climb``."""
    T = np.tile(np.eye(4), (n, 1, 1))
    yaw = 0.4 * np.sin(np.arange(n) * 0.1 / 5.0)
    T[:, :3, :3] = rot_z(yaw) @ _UPRIGHT
    for k in range(1, n):
        T[k, :3, 3] = T[k - 1, :3, 3] + 0.12 * T[k, :3, 2] + [0.0, 0.0, 0.03 * (climb.start <= k < climb.stop)]
    return T


def _inputs(truth: np.ndarray, gap: slice, rng: np.random.Generator) -> tuple[list, list]:
    """Landmarks (2 cm, 0.5 deg noise; none over ``gap``) and the suit's steps (4 % long, no vertical)."""
    landmarks, suit = [], [None]
    for k, T in enumerate(truth):
        noisy = T.copy()
        noisy[:3, 3] += rng.normal(0.0, 0.02, 3)
        noisy[:3, :3] = noisy[:3, :3] @ axis_angle_to_matrix(rng.normal(0.0, np.radians(0.5), 3))
        landmarks.append(None if gap.start <= k < gap.stop else noisy)
        if k:
            step = np.linalg.inv(truth[k - 1]) @ T
            step[:3, 3] *= 1.04
            step[1, 3] = 0.0  # P's y: the suit knows no stairs
            suit.append(step)
    return landmarks, suit


def _errors(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.linalg.norm(estimate[:, :3, 3] - truth[:, :3, 3], axis=1)


def test_the_graph_bridges_a_gap_in_the_landmarks_with_the_suit_and_follows_the_landmarks_up_a_climb():
    """60 s of walking, a 2 s gap in the landmarks on level ground and a climb of 1.8 m that the suit does not
    see: batch and live both stay near the truth; across the gap the suit carries them (a 4 % stride error over
    2.4 m: up to 10 cm live), up the climb the landmarks do. Measured: batch RMS 2.0 cm, gap max 2.4 cm, climb
    max 4.5 cm; live RMS 2.6 cm, gap max 10.2 cm, climb max 5.0 cm."""
    truth = _walk()
    gap = slice(150, 170)
    landmarks, suit = _inputs(truth, gap, np.random.default_rng(0))
    batch = fuse_batch(landmarks, suit)
    graph = LiveTrajectoryGraph()
    live = np.array([graph.add(int(k * 1e8), landmarks[k], suit[k]) for k in range(len(truth))])
    assert graph.count == len(truth)
    for estimate, rms, in_gap in ((batch, 0.03, 0.06), (live, 0.035, 0.13)):
        err = _errors(estimate, truth)
        assert np.sqrt(np.mean(err**2)) < rms
        assert err[gap].max() < in_gap
        assert err[300:360].max() < 0.07  # the climb: the suit's zero vertical does not win
    held = np.array([landmarks[gap.start - 1]] * (gap.stop - gap.start))  # what holding the last landmark gives
    assert _errors(held, truth[gap]).max() > 2.0


def test_a_lone_wild_landmark_is_outvoted_and_the_first_node_may_lack_one():
    """A landmark 1 m off moves the batch solution by less than 3 cm (the Huber kernel and the suit's chain;
    measured 0.8 cm); without any landmark at the start the chain is anchored at the identity and still follows
    the landmarks (RMS under 3 cm; measured 1.9)."""
    truth = _walk(200, slice(0, 0))
    landmarks, suit = _inputs(truth, slice(0, 5), np.random.default_rng(1))
    wild = landmarks[100].copy()
    wild[:3, 3] += [1.0, 0.0, 0.0]
    landmarks[100] = wild
    batch = fuse_batch(landmarks, suit)
    assert _errors(batch, truth)[100] < 0.03
    assert np.sqrt(np.mean(_errors(batch, truth)[5:] ** 2)) < 0.03
    with pytest.raises(ValueError):
        fuse_batch(landmarks, suit[:-1])
    with pytest.raises(ValueError):
        PoseGraphConfig(lag_s=0.0)


def test_the_live_graph_keeps_only_its_lag():
    """After 60 s at 10 Hz with a 5 s lag the smoother holds about 5 s of nodes (memory stays flat)."""
    truth = _walk(600, slice(0, 0))
    landmarks, suit = _inputs(truth, slice(0, 0), np.random.default_rng(2))
    graph = LiveTrajectoryGraph(PoseGraphConfig(lag_s=5.0))
    for k in range(len(truth)):
        graph.add(int(k * 1e8), landmarks[k], suit[k])
    assert 40 <= len(graph._smoother.timestamps()) <= 60


def test_the_suit_track_gives_the_lidars_motion_and_gravity_whatever_the_suits_heading():
    """A suit whose world is turned by 70 deg and whose clock is 0.4 s ahead: the LiDAR's relative motion
    between two LiDAR-clock times is the truth's, its horizontal part (the pelvis's steps scaled by the stride
    scale) and up (the mounting's) too; nothing
    before the offset is set or outside the samples; bad samples are refused with a reason."""
    truth = _walk(100, slice(50, 70))  # at 10 Hz; the suit samples it at 100 Hz below
    mount = HipMountPrior()
    T_M_L = np.eye(4)
    T_M_L[:3, :3], T_M_L[:3, 3] = mount.R_M_L, mount.lever_m
    offset = 400_000_000
    track = SuitTrack(mount, capacity=2000)
    heading = np.eye(4)
    heading[:3, :3] = rot_z(np.radians(70.0))
    for k in range(len(truth) - 1):  # 10 samples between frames: the same pose moved linearly
        for j in range(10):
            w = j / 10.0
            T = heading @ truth[k]
            position = (1 - w) * T[:3, 3] + w * (heading @ truth[k + 1])[:3, 3]
            assert track.add(int((k + w) * 1e8) + offset, position, matrix_to_quat(T[:3, :3])) is None
    assert track.lidar_motion(int(2e8), int(3e8)) is None
    track.set_offset(offset)
    motion = track.lidar_motion(int(20e8), int(21e8))
    expected = np.linalg.inv(truth[20] @ T_M_L) @ truth[21] @ T_M_L
    assert np.allclose(motion, expected, atol=1e-6)
    horizontal, up = track.horizontal_motion(int(20e8), int(21e8))
    assert np.allclose(up, mount.R_M_L.T @ [0.0, 1.0, 0.0], atol=1e-9)
    d = expected[:3, 3]
    assert np.allclose(horizontal, d - (d @ up) * up, atol=1e-6) and abs(horizontal @ up) < 1e-9
    track.stride_scale = 1.1  # the stride scale the trajectory measured: the pelvis's horizontal steps 1.1 times
    stepped = truth[21].copy()
    stepped[:2, 3] = truth[20][:2, 3] + 1.1 * (truth[21][:2, 3] - truth[20][:2, 3])
    d = (np.linalg.inv(truth[20] @ T_M_L) @ stepped @ T_M_L)[:3, 3]
    assert np.allclose(track.horizontal_motion(int(20e8), int(21e8))[0], d - (d @ up) * up, atol=1e-6)
    assert np.allclose(track.lidar_motion(int(20e8), int(21e8)), expected, atol=1e-6)  # the motion itself unscaled
    assert track.lidar_motion(int(-1e8), int(1e8)) is None and track.pelvis(int(200e8)) is None
    assert track.add(int(200e8), [np.nan, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]) == "not finite"
    assert "norm" in track.add(int(200e8), [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 2.0])
    assert "after" in track.add(0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])


def test_the_yaw_and_translation_alignment_recovers_a_turned_and_shifted_trajectory():
    """A trajectory turned by 40 deg about z and shifted: the alignment fitted on its first 30 points maps all
    of it back exactly; fitted on a part that drifted, the rest keeps its error."""
    rng = np.random.default_rng(3)
    truth = np.cumsum(rng.normal(0.0, 0.1, (200, 3)), axis=0)
    estimate = truth @ rot_z(np.radians(40.0)).T + [3.0, -2.0, 0.5]
    T = align_yaw_translation(estimate, truth, slice(0, 30))
    assert np.allclose(estimate @ T[:3, :3].T + T[:3, 3], truth, atol=1e-9)
    drifted = estimate.copy()
    drifted[100:] += [0.5, 0.0, 0.0]
    T = align_yaw_translation(drifted, truth, slice(0, 30))
    err = np.linalg.norm(drifted @ T[:3, :3].T + T[:3, 3] - truth, axis=1)
    assert err[:100].max() < 1e-9 and np.allclose(err[100:], 0.5)
    with pytest.raises(ValueError):
        align_yaw_translation(estimate, truth, slice(0, 1))
