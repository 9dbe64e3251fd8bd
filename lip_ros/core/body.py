"""A performer's body surface: capsules around the bones of the contract skeleton.

Every body part is a capsule (a segment swept by a sphere): horizontal capsules
stacked up the torso give it its width and shallow depth, one capsule per limb
bone, a short vertical capsule for the head. An endpoint of a capsule is a
joint position plus an offset in that joint's bone frame (equal to the model
frame M at rest: x left, y up, z forward), so the surface follows any pose of
forward kinematics. Offsets and radii are given for the reference skeleton
(pelvis 0.95 m above the soles, a body about 1.73 m tall); a scaled skeleton
scales them all, the per-performer ``girth`` scales the radii only.

All functions take one pose, ``glob_rot`` (24, 3, 3) global joint rotations and
``joint_pos`` (24, 3) joint positions, both in the world frame, as returned by
``lip_ros.core.skeleton.forward_kinematics``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lip_ros.core.capsule_rays import first_hits
from lip_ros.core.skeleton import Skeleton

__all__ = ["BodyModel", "TORSO_PARTS", "LIMB_PARTS", "capsule_distances"]

# The capsule table below is drawn for the contract skeleton (scale 1); it scales with ``skeleton.scale``.

_SKIN, _CLOTH = 0, 1
#: Capsules thickened by ``torso_girth`` and (both sides) by ``limb_girth``: a body shaped otherwise than uniformly.
TORSO_PARTS = ("pelvis", "abdomen", "lower_chest", "chest")
LIMB_PARTS = ("upper_arm", "forearm", "thigh", "shank")

# name, (joint, offset), (joint, offset), radius, material. Offsets are in the
# joint's bone frame. Parts named "left_*" are mirrored (x -> -x) to the right.
_End = tuple[str, tuple[float, float, float]]
_PARTS: tuple[tuple[str, _End, _End, float, int], ...] = (
    ("pelvis", ("pelvis", (0.075, -0.065, -0.01)), ("pelvis", (-0.075, -0.065, -0.01)), 0.105, _CLOTH),
    ("abdomen", ("spine1", (0.07, 0.0, 0.01)), ("spine1", (-0.07, 0.0, 0.01)), 0.105, _CLOTH),
    ("lower_chest", ("spine2", (0.075, 0.0, 0.0)), ("spine2", (-0.075, 0.0, 0.0)), 0.11, _CLOTH),
    ("chest", ("spine3", (0.08, 0.06, -0.01)), ("spine3", (-0.08, 0.06, -0.01)), 0.115, _CLOTH),
    ("neck", ("neck", (0.0, 0.0, 0.0)), ("head", (0.0, 0.0, 0.0)), 0.055, _SKIN),
    ("head", ("head", (0.0, 0.03, 0.015)), ("head", (0.0, 0.11, 0.015)), 0.09, _SKIN),
    ("left_shoulder", ("left_collar", (0.0, 0.0, 0.0)), ("left_shoulder", (0.0, 0.0, 0.0)), 0.06, _CLOTH),
    ("left_upper_arm", ("left_shoulder", (0.0, 0.0, 0.0)), ("left_elbow", (0.0, 0.0, 0.0)), 0.05, _CLOTH),
    ("left_forearm", ("left_elbow", (0.0, 0.0, 0.0)), ("left_wrist", (0.0, 0.0, 0.0)), 0.04, _CLOTH),
    ("left_hand", ("left_wrist", (0.0, 0.0, 0.0)), ("left_hand", (0.05, 0.0, 0.0)), 0.035, _SKIN),
    ("left_thigh", ("left_hip", (0.0, 0.0, 0.0)), ("left_knee", (0.0, 0.0, 0.0)), 0.075, _CLOTH),
    ("left_shank", ("left_knee", (0.0, 0.0, 0.0)), ("left_ankle", (0.0, 0.0, 0.0)), 0.05, _CLOTH),
    ("left_foot", ("left_ankle", (0.0, -0.05, -0.045)), ("left_foot", (0.0, 0.005, 0.05)), 0.035, _CLOTH),
)


def _mirror(name: str) -> str:
    return "right_" + name[len("left_") :]


def _part_table() -> list[tuple[str, str, np.ndarray, str, np.ndarray, float, int]]:
    """The capsule table with the right side mirrored from the left."""
    rows = []
    flip = np.array([-1.0, 1.0, 1.0])
    for name, (ja, oa), (jb, ob), radius, material in _PARTS:
        rows.append((name, ja, np.array(oa), jb, np.array(ob), radius, material))
        if name.startswith("left_"):
            rows.append((_mirror(name), _mirror(ja), flip * oa, _mirror(jb), flip * ob, radius, material))
    return rows


def _closest_on_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Closest points to ``p`` on the segments ``a``-``b`` (all broadcast over leading axes, last axis 3)."""
    ab = b - a
    denom = np.maximum(np.sum(ab * ab, axis=-1), 1e-18)
    s = np.clip(np.sum((p - a) * ab, axis=-1) / denom, 0.0, 1.0)
    return a + s[..., None] * ab


def capsule_distances(points: np.ndarray, a: np.ndarray, b: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(N, K) signed distance of points (N, 3) to capsules (ends a, b (K, 3), radii r (K,)), negative inside."""
    p = points[:, None, :]
    q = _closest_on_segment(p, a[None], b[None])
    return np.linalg.norm(p - q, axis=-1) - r


@dataclass(frozen=True)
class _Capsules:
    """Capsules of one pose: endpoints (K, 3), radii (K,)."""

    a: np.ndarray
    b: np.ndarray
    r: np.ndarray


class BodyModel:
    """Capsule body of one performer around ``skeleton``, thickened by ``girth`` (all capsules), ``torso_girth``
    (:data:`TORSO_PARTS`) and ``limb_girth`` (:data:`LIMB_PARTS`).

    ``reflectivity`` of each capsule (NIR, 0..1) is ``skin_reflectivity`` for
    head, neck and hands and ``clothing_reflectivity`` elsewhere.
    """

    def __init__(
        self,
        skeleton: Skeleton,
        girth: float = 1.0,
        clothing_reflectivity: float = 0.4,
        skin_reflectivity: float = 0.55,
        torso_girth: float = 1.0,
        limb_girth: float = 1.0,
    ) -> None:
        if min(girth, torso_girth, limb_girth) <= 0.0:
            raise ValueError("girths must be positive")
        self.skeleton = skeleton
        self.girth = float(girth)
        self.torso_girth, self.limb_girth = float(torso_girth), float(limb_girth)
        size = skeleton.scale
        table = _part_table()
        self.names: tuple[str, ...] = tuple(row[0] for row in table)
        shape = np.array([torso_girth if n in TORSO_PARTS else limb_girth if n.split("_", 1)[-1] in LIMB_PARTS
                          else 1.0 for n in self.names])
        self._ja = np.array([skeleton.index(row[1]) for row in table])
        self._oa = size * np.stack([row[2] for row in table])
        self._jb = np.array([skeleton.index(row[3]) for row in table])
        self._ob = size * np.stack([row[4] for row in table])
        self.radius: np.ndarray = size * self.girth * shape * np.array([row[5] for row in table])
        materials = np.array([row[6] for row in table])
        self.reflectivity: np.ndarray = np.where(materials == _SKIN, skin_reflectivity, clothing_reflectivity)

    @property
    def num_capsules(self) -> int:
        """Number of capsules K."""
        return len(self.names)

    def capsules(self, glob_rot: np.ndarray, joint_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Capsule endpoints a (..., K, 3), b (..., K, 3) and radii (K,) of a pose (batched over leading axes)."""
        glob_rot = np.asarray(glob_rot, dtype=np.float64)
        joint_pos = np.asarray(joint_pos, dtype=np.float64)
        a = joint_pos[..., self._ja, :] + np.einsum("...kij,kj->...ki", glob_rot[..., self._ja, :, :], self._oa)
        b = joint_pos[..., self._jb, :] + np.einsum("...kij,kj->...ki", glob_rot[..., self._jb, :, :], self._ob)
        return a, b, self.radius

    def _pose(self, glob_rot: np.ndarray, joint_pos: np.ndarray) -> _Capsules:
        a, b, r = self.capsules(glob_rot, joint_pos)
        if a.ndim != 2:
            raise ValueError("expected one pose: glob_rot (24, 3, 3), joint_pos (24, 3)")
        return _Capsules(a, b, r)

    def surface_distance(self, points: np.ndarray, glob_rot: np.ndarray, joint_pos: np.ndarray) -> np.ndarray:
        """(N,) signed distance of points (N, 3) to the body surface, negative inside."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        caps = self._pose(glob_rot, joint_pos)
        return capsule_distances(points, caps.a, caps.b, caps.r).min(axis=1)

    def bounding_sphere(self, glob_rot: np.ndarray, joint_pos: np.ndarray) -> tuple[np.ndarray, float]:
        """Centre (3,) and radius of a sphere enclosing the whole body."""
        caps = self._pose(glob_rot, joint_pos)
        ends = np.concatenate([caps.a, caps.b])
        rr = np.concatenate([caps.r, caps.r])
        centre = 0.5 * ((ends - rr[:, None]).min(axis=0) + (ends + rr[:, None]).max(axis=0))
        return centre, float(np.max(np.linalg.norm(ends - centre, axis=1) + rr))

    def raycast(
        self, origin: np.ndarray, dirs: np.ndarray, glob_rot: np.ndarray, joint_pos: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hits of unit rays from ``origin`` (3,) along ``dirs`` (N, 3) with the body.

        Returns range (N,) (inf where missed), cosine of the incidence angle (N,)
        and the reflectivity of the surface hit (N,) (both 0 where missed). Only
        (ray, capsule) pairs whose capsule's bounding sphere the ray passes are tested.
        """
        caps = self._pose(glob_rot, joint_pos)
        origin = np.asarray(origin, dtype=np.float64)
        dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        n = len(dirs)
        best, met = first_hits(origin, dirs, caps.a, caps.b, caps.r)
        ray = np.flatnonzero(met >= 0)
        cap = met[ray]
        hit = origin + best[ray, None] * dirs[ray]
        normal = hit - _closest_on_segment(hit, caps.a[cap], caps.b[cap])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        cos_inc = np.zeros(n)
        refl = np.zeros(n)
        cos_inc[ray] = np.clip(-np.sum(normal * dirs[ray], axis=1), 0.0, 1.0)
        refl[ray] = self.reflectivity[cap]
        return best, cos_inc, refl

    def sample_surface(
        self, glob_rot: np.ndarray, joint_pos: np.ndarray, n: int, rng: np.random.Generator
    ) -> np.ndarray:
        """(n, 3) points uniformly distributed on the outer surface of the body.

        Points are drawn on every capsule in proportion to its area and kept only
        where no other capsule covers them (rejection), so overlaps are not
        oversampled.
        """
        caps = self._pose(glob_rot, joint_pos)
        axis = caps.b - caps.a
        length = np.linalg.norm(axis, axis=1)
        u = axis / np.maximum(length, 1e-12)[:, None]
        helper = np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        e1 = np.cross(u, helper)
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(u, e1)
        side_area = 2.0 * np.pi * caps.r * length
        area = side_area + 4.0 * np.pi * caps.r**2
        kept: list[np.ndarray] = []
        remaining = n
        while remaining > 0:
            m = max(2 * remaining, 256)
            k = rng.choice(len(area), size=m, p=area / area.sum())
            on_side = rng.random(m) * area[k] < side_area[k]
            phi = rng.uniform(0.0, 2.0 * np.pi, m)
            ring = np.cos(phi)[:, None] * e1[k] + np.sin(phi)[:, None] * e2[k]
            side = caps.a[k] + rng.random(m)[:, None] * axis[k] + caps.r[k, None] * ring
            v = rng.standard_normal((m, 3))
            v /= np.linalg.norm(v, axis=1, keepdims=True)
            end = np.where((np.sum(v * u[k], axis=1) < 0.0)[:, None], caps.a[k], caps.b[k])
            p = np.where(on_side[:, None], side, end + caps.r[k, None] * v)
            dist = capsule_distances(p, caps.a, caps.b, caps.r)
            dist[np.arange(m), k] = np.inf
            p = p[dist.min(axis=1) >= -1e-9][:remaining]
            kept.append(p)
            remaining -= len(p)
        return np.concatenate(kept)
