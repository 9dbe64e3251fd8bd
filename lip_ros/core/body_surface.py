"""Fixed points on a performer's capsule body, in bone-local coordinates: the "mesh vertices" of evaluation.

The LIP paper's mesh error compares SMPL vertices of the true and the
estimated pose. Here the body is :class:`lip_ros.core.body.BodyModel`'s
capsules, so the "vertices" are points drawn once on the rest-pose surface
and attached to their capsule: each point keeps its capsule k, its position s
along the capsule's axis (0 at end a, 1 at end b) and its radial offset v in
the bone frame of the joint that carries end a. Posed, a point is
``a_k + s (b_k - a_k) + R_ja v``: exact for capsules whose ends ride on one
bone (torso, limbs), a close approximation where end b rides on the next one
(hands, feet, neck). The same points follow any pose, truth or estimate.
"""

from __future__ import annotations

import numpy as np

from lip_ros.core.body import BodyModel
from lip_ros.core.skeleton import NUM_JOINTS, forward_kinematics

__all__ = ["BodySurface"]

_PROBE_SPACING = 100.0  # m between probe joints: far more than any capsule end's offset from its joint


def _carrying_joints(body: BodyModel) -> np.ndarray:
    """(K,) the joint whose bone frame carries each capsule's end a.

    A capsule end is a joint position plus an offset in that joint's frame
    (``BodyModel``); with the joints spread ``_PROBE_SPACING`` apart along x and
    unrotated, the end's x over the spacing rounds to its joint's index.
    """
    probe = np.zeros((NUM_JOINTS, 3))
    probe[:, 0] = _PROBE_SPACING * np.arange(NUM_JOINTS)
    a, _, _ = body.capsules(np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)), probe)
    return np.rint(a[:, 0] / _PROBE_SPACING).astype(int)


class BodySurface:
    """``count`` fixed surface points of ``body`` (drawn with ``seed``), posed by :meth:`points`."""

    def __init__(self, body: BodyModel, count: int = 2000, seed: int = 0) -> None:
        self.body = body
        rest_rot = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
        _, rest_pos = forward_kinematics(body.skeleton, rest_rot)
        rest = body.sample_surface(rest_rot, rest_pos, count, np.random.default_rng(seed))
        a, b, r = body.capsules(rest_rot, rest_pos)
        ab = b - a
        s = np.clip(np.einsum("nkc,kc->nk", rest[:, None] - a, ab) / np.maximum(np.sum(ab * ab, axis=1), 1e-18),
                    0.0, 1.0)
        axis_point = a + s[..., None] * ab  # (N, K, 3)
        gap = np.abs(np.linalg.norm(rest[:, None] - axis_point, axis=-1) - r)
        self._capsule = np.argmin(gap, axis=1)  # the capsule each point lies on
        rows = np.arange(count)
        self._s = s[rows, self._capsule]
        self._radial = rest - axis_point[rows, self._capsule]  # in M = every bone frame at rest
        self._joint = _carrying_joints(body)[self._capsule]

    @property
    def count(self) -> int:
        """Number of points N."""
        return len(self._s)

    def points(self, glob_rot: np.ndarray, joint_pos: np.ndarray) -> np.ndarray:
        """(..., N, 3) the points on the body posed by global rotations (..., 24, 3, 3) and joints (..., 24, 3)."""
        a, b, _ = self.body.capsules(glob_rot, joint_pos)
        a, b = a[..., self._capsule, :], b[..., self._capsule, :]
        return a + self._s[:, None] * (b - a) + self._rotate(glob_rot, self._radial)

    def normals(self, glob_rot: np.ndarray) -> np.ndarray:
        """(..., N, 3) outward unit normals of the points in the pose with global rotations (..., 24, 3, 3)."""
        return self._rotate(glob_rot, self._radial / np.linalg.norm(self._radial, axis=1, keepdims=True))

    def _rotate(self, glob_rot: np.ndarray, local: np.ndarray) -> np.ndarray:
        """Per point, a bone-local vector (N, 3) turned by its carrying joint's global rotation."""
        return np.einsum("...nij,nj->...ni", np.asarray(glob_rot)[..., self._joint, :, :], local)
