"""Rotation conversions in numpy, batched over leading axes.

Conventions used across lip_ros:

* rotation matrices act on column vectors (``v_parent = R @ v_child``);
* quaternions are ``(x, y, z, w)`` as in ROS messages and scipy;
* the 6D representation (Zhou et al. 2019) is the first two *columns* of the
  matrix, concatenated: ``[R[:, 0], R[:, 1]]``;
* Euler angles for JointState are intrinsic Z-Y-X: ``R = Rz(a) @ Ry(b) @ Rx(c)``.
"""

from __future__ import annotations

import itertools
import warnings

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "axis_angle_to_matrix",
    "matrix_to_axis_angle",
    "quat_to_matrix",
    "matrix_to_quat",
    "six_d_to_matrix",
    "matrix_to_six_d",
    "euler_zyx_to_matrix",
    "matrix_to_euler_zyx",
    "rot_x",
    "rot_y",
    "rot_z",
    "geodesic_angle",
    "project_to_so3",
    "nearest_axes_turn",
]


def _flat(a: np.ndarray, tail: tuple[int, ...]) -> tuple[np.ndarray, tuple[int, ...]]:
    a = np.asarray(a, dtype=np.float64)
    lead = a.shape[: a.ndim - len(tail)]
    return a.reshape((-1,) + tail), lead


def axis_angle_to_matrix(aa: np.ndarray) -> np.ndarray:
    """(..., 3) axis-angle vectors to (..., 3, 3) matrices."""
    flat, lead = _flat(aa, (3,))
    return Rotation.from_rotvec(flat).as_matrix().reshape(lead + (3, 3))


def matrix_to_axis_angle(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) matrices to (..., 3) axis-angle vectors."""
    flat, lead = _flat(rot, (3, 3))
    return Rotation.from_matrix(flat).as_rotvec().reshape(lead + (3,))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w), normalised first, to (..., 3, 3)."""
    flat, lead = _flat(q, (4,))
    return Rotation.from_quat(flat).as_matrix().reshape(lead + (3, 3))


def matrix_to_quat(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) matrices to (..., 4) quaternions (x, y, z, w) with w >= 0."""
    flat, lead = _flat(rot, (3, 3))
    q = Rotation.from_matrix(flat).as_quat(canonical=True)
    return q.reshape(lead + (4,))


def six_d_to_matrix(d6: np.ndarray) -> np.ndarray:
    """(..., 6) first-two-columns representation to (..., 3, 3) by Gram-Schmidt."""
    d6 = np.asarray(d6, dtype=np.float64)
    a1, a2 = d6[..., 0:3], d6[..., 3:6]
    b1 = a1 / np.linalg.norm(a1, axis=-1, keepdims=True)
    a2 = a2 - np.sum(b1 * a2, axis=-1, keepdims=True) * b1
    b2 = a2 / np.linalg.norm(a2, axis=-1, keepdims=True)
    b3 = np.cross(b1, b2)
    return np.stack([b1, b2, b3], axis=-1)


def matrix_to_six_d(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) matrices to (..., 6): the first two columns, concatenated."""
    rot = np.asarray(rot, dtype=np.float64)
    return np.concatenate([rot[..., :, 0], rot[..., :, 1]], axis=-1)


def euler_zyx_to_matrix(angles: np.ndarray) -> np.ndarray:
    """(..., 3) angles (z, y, x) to matrices ``Rz(z) @ Ry(y) @ Rx(x)``."""
    flat, lead = _flat(angles, (3,))
    return Rotation.from_euler("ZYX", flat).as_matrix().reshape(lead + (3, 3))


def matrix_to_euler_zyx(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) matrices to (..., 3) angles (z, y, x), y in [-pi/2, pi/2]."""
    flat, lead = _flat(rot, (3, 3))
    with warnings.catch_warnings():  # gimbal lock is a valid, handled case
        warnings.simplefilter("ignore", UserWarning)
        eul = Rotation.from_matrix(flat).as_euler("ZYX")
    return eul.reshape(lead + (3,))


def _elementary(angle: np.ndarray, axis: int) -> np.ndarray:
    angle = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(angle.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def rot_x(angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about x for an array of angles."""
    return _elementary(angle, 0)


def rot_y(angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about y for an array of angles."""
    return _elementary(angle, 1)


def rot_z(angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about z for an array of angles."""
    return _elementary(angle, 2)


def geodesic_angle(r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """Angle in radians of ``r1^T r2`` for (..., 3, 3) matrices."""
    rel = np.swapaxes(np.asarray(r1), -1, -2) @ np.asarray(r2)
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


def project_to_so3(m: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (SVD) for (..., 3, 3) arrays."""
    u, _, vt = np.linalg.svd(np.asarray(m, dtype=np.float64))
    det = np.linalg.det(u @ vt)
    u = u.copy()
    u[..., :, 2] *= det[..., None]
    return u @ vt


def _axes_turns() -> np.ndarray:
    """(24, 3, 3) the rotations that take the axes onto the axes (signed permutations, determinant +1)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[list(perm), range(3)] = signs
            if np.linalg.det(m) > 0.0:
                out.append(m)
    return np.array(out)


_AXES_TURNS = _axes_turns()


def nearest_axes_turn(rot: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) that takes the axes onto the axes (one of 24: another axis convention) nearest ``rot``."""
    return _AXES_TURNS[int(np.argmax(np.einsum("kij,ij->k", _AXES_TURNS, np.asarray(rot, dtype=np.float64))))].copy()
