"""Pose and translation error metrics (ROS-free, numpy), as the LIP / TransPose / PIP papers define them.

Per-frame functions take arrays with a leading frame axis T and return (T,)
errors in SI units (metres, radians); the caller converts to the reported
units. Joints are (T, J, 3) positions, rotations (T, J, 3, 3).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from lip_ros.core.body import BodyModel
from lip_ros.core.rotations import geodesic_angle

__all__ = [
    "root_relative",
    "mpjpe",
    "pa_mpjpe",
    "mean_distance",
    "angular_error",
    "translation_error",
    "surface_chamfer",
    "jitter",
    "icp_translation",
    "align_yaw_translation",
]


def root_relative(joints: np.ndarray) -> np.ndarray:
    """(T, J, 3) joint positions minus the root's (joint 0)."""
    joints = np.asarray(joints, dtype=np.float64)
    return joints - joints[..., :1, :]


def mean_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(T,) mean Euclidean distance between corresponding points (T, N, 3)."""
    return np.linalg.norm(np.asarray(a, dtype=np.float64) - b, axis=-1).mean(axis=-1)


def mpjpe(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """(T,) mean per-joint position error of the root-relative joints (T, J, 3)."""
    return mean_distance(root_relative(pred), root_relative(true))


def _procrustes(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """``pred`` (T, N, 3) aligned to ``true`` by the best similarity (rotation, scale, translation) per frame."""
    mu_p, mu_t = pred.mean(axis=1, keepdims=True), true.mean(axis=1, keepdims=True)
    p, t = pred - mu_p, true - mu_t
    u, s, vt = np.linalg.svd(np.einsum("tni,tnj->tij", t, p))  # cross-covariance true x pred
    d = np.sign(np.linalg.det(u @ vt))
    s[:, -1] *= d
    u[:, :, -1] *= d[:, None]
    rot = u @ vt  # (T, 3, 3), rotates pred onto true
    scale = s.sum(axis=1) / np.maximum(np.sum(p * p, axis=(1, 2)), 1e-18)
    return scale[:, None, None] * np.einsum("tij,tnj->tni", rot, p) + mu_t


def pa_mpjpe(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """(T,) MPJPE after Procrustes alignment (rotation, uniform scale, translation) of each predicted frame."""
    pred = np.asarray(pred, dtype=np.float64)
    true = np.asarray(true, dtype=np.float64)
    return mean_distance(_procrustes(pred, true), true)


def angular_error(pred_rot: np.ndarray, true_rot: np.ndarray) -> np.ndarray:
    """(T,) mean geodesic angle (rad) between predicted and true global joint rotations (T, J, 3, 3)."""
    return geodesic_angle(np.asarray(pred_rot), np.asarray(true_rot)).mean(axis=-1)


def translation_error(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """(T,) distance between predicted and true root positions (T, 3)."""
    return np.linalg.norm(np.asarray(pred, dtype=np.float64) - true, axis=-1)


def surface_chamfer(points: np.ndarray, body: BodyModel, glob_rot: np.ndarray, joint_pos: np.ndarray) -> float:
    """One-sided chamfer distance from observed points (N, 3) to a posed body: the mean distance of each
    point to the body's surface (exact, on the capsules: the limit of a chamfer distance to ever denser
    surface samples). One-sided because a LiDAR sees one side of the body."""
    if len(points) == 0:
        raise ValueError("chamfer distance of an empty point set")
    return float(np.abs(body.surface_distance(points, glob_rot, joint_pos)).mean())


def jitter(positions: np.ndarray, dt: float) -> float:
    """Mean norm of the third finite difference of positions (T, J, 3) sampled every ``dt`` s, in m/s^3
    (TransPose, PIP). NaN with fewer than 4 frames."""
    positions = np.asarray(positions, dtype=np.float64)
    if len(positions) < 4:
        return float("nan")
    return float(np.linalg.norm(np.diff(positions, n=3, axis=0), axis=-1).mean() / dt**3)


def icp_translation(points: np.ndarray, surface: np.ndarray, iterations: int = 8, tol: float = 1e-4) -> np.ndarray:
    """(3,) translation t that moves ``surface`` (M, 3) onto the observed ``points`` (N, 3): point-to-point ICP
    restricted to a translation, each observed point paired with its nearest surface point (KD-tree on the
    surface, queried at ``points - t``), starting from t = 0. Stops after ``iterations`` or a step below ``tol`` m."""
    tree = cKDTree(surface)
    t = np.zeros(3)
    for _ in range(iterations):
        _, idx = tree.query(points - t)
        step = np.mean(points - t - surface[idx], axis=0)
        t += step
        if np.linalg.norm(step) < tol:
            break
    return t


def align_yaw_translation(estimate: np.ndarray, truth: np.ndarray, fit: np.ndarray | slice = slice(None)
                          ) -> np.ndarray:
    """T (4, 4): the rotation about z and the translation that best map ``estimate`` (N, 3) onto ``truth`` (N, 3)
    over the points ``fit`` (least squares; the 4-DoF alignment of a gravity-aligned trajectory, whose yaw and
    origin are arbitrary). Apply it to the whole estimate: drift outside ``fit`` is not forgiven."""
    a, b = np.asarray(estimate, dtype=np.float64)[fit], np.asarray(truth, dtype=np.float64)[fit]
    if len(a) < 2:
        raise ValueError("a yaw and translation alignment needs at least two points")
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, v = a[:, :2] - ca[:2], b[:, :2] - cb[:2]
    yaw = np.arctan2(np.sum(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]), np.sum(u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1]))
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = cb - T[:3, :3] @ ca
    return T

