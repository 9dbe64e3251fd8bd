"""The SMPL 24-joint skeleton of the interface contract and its kinematics (the joint chain compiled with numba).

Model frame M: x = the body's left, y = up, z = forward; zero pose = T-pose.
The global rotation of joint j is ``R_global[parent] @ R_local[j]`` and its
position ``p[parent] + R_global[parent] @ offset[j]``. For the root (pelvis)
the "local" rotation is its orientation in the world frame (for lip_ros the
LiDAR frame ``os_lidar``) and ``root_pos`` its position there.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np
import yaml

from lip_ros.core.kinematics_kernel import chain
from lip_ros.core.rotations import axis_angle_to_matrix, euler_zyx_to_matrix, matrix_to_euler_zyx
from lip_ros.resources import params_path

__all__ = [
    "Skeleton",
    "load_skeleton",
    "forward_kinematics",
    "calibration_pose",
    "joint_state_names",
    "local_rotations_to_joint_angles",
    "joint_angles_to_local_rotations",
    "NUM_JOINTS",
    "AXIS_SUFFIXES",
    "PROPORTION_GROUPS",
]

NUM_JOINTS = 24
AXIS_SUFFIXES = ("_rz", "_ry", "_rx")
#: Segment groups whose lengths ``Skeleton.with_proportions`` scales, each by the rest offsets of these joints
#: (the bones ending in them; both sides alike).
PROPORTION_GROUPS: dict[str, tuple[str, ...]] = {
    "hips": ("left_hip", "right_hip"),
    "thigh": ("left_knee", "right_knee"),
    "shank": ("left_ankle", "right_ankle"),
    "spine": ("spine1", "spine2", "spine3", "neck"),
    "shoulders": ("left_collar", "right_collar", "left_shoulder", "right_shoulder"),
    "upper_arm": ("left_elbow", "right_elbow"),
    "forearm": ("left_wrist", "right_wrist"),
}
_LEG_CHAINS = (("left_hip", "left_knee", "left_ankle"), ("right_hip", "right_knee", "right_ankle"))


@dataclass(frozen=True)
class Skeleton:
    """Topology, rest offsets and sensor placement of the contract skeleton."""

    names: tuple[str, ...]
    parents: np.ndarray  # (24,) int, -1 for the root
    offsets: np.ndarray  # (24, 3) rest offsets from the parent, metres, model frame
    pelvis_height: float  # pelvis above the soles at rest, metres
    lip_imus: dict[str, dict[str, str]] = field(default_factory=dict)
    suit_imus: dict[str, str] = field(default_factory=dict)
    calibration_poses: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    scale: float = 1.0  # size relative to the contract skeleton (see ``scaled``)

    def index(self, name: str) -> int:
        """Index of the joint called ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"unknown joint {name!r}") from None

    def children(self, j: int) -> list[int]:
        """Indices of the joints whose parent is ``j``."""
        return [int(c) for c in np.flatnonzero(self.parents == j)]

    def pose_local_rotations(self, pose: str) -> np.ndarray:
        """(24, 3, 3) local rotations of a named calibration pose ('a_pose', 't_pose')."""
        rot = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
        for joint, aa in self.calibration_poses[pose].items():
            rot[self.index(joint)] = axis_angle_to_matrix(aa)
        return rot

    def scaled(self, scale: float) -> Skeleton:
        """The same skeleton with bone lengths and pelvis height multiplied by ``scale``."""
        return Skeleton(
            self.names,
            self.parents,
            self.offsets * scale,
            self.pelvis_height * scale,
            self.lip_imus,
            self.suit_imus,
            self.calibration_poses,
            self.scale * scale,
        )

    def with_proportions(self, factors: dict[str, float]) -> Skeleton:
        """The same skeleton with the bones of each :data:`PROPORTION_GROUPS` group in ``factors`` lengthened by its
        factor (a body shaped otherwise than a uniformly scaled contract skeleton); the pelvis height follows the
        legs. ``scale`` is kept: it stays the overall size."""
        unknown = set(factors) - set(PROPORTION_GROUPS)
        if unknown:
            raise KeyError(f"unknown proportion groups {sorted(unknown)}; known: {sorted(PROPORTION_GROUPS)}")
        if any(f <= 0.0 for f in factors.values()):
            raise ValueError(f"proportion factors must be positive: {factors}")
        gain = np.ones(NUM_JOINTS)
        for group, f in factors.items():
            gain[[self.index(j) for j in PROPORTION_GROUPS[group]]] = f
        offsets = self.offsets * gain[:, None]
        drop = [sum(-offsets[self.index(j), 1] + self.offsets[self.index(j), 1] for j in chain)
                for chain in _LEG_CHAINS]
        return replace(self, offsets=offsets, pelvis_height=self.pelvis_height + float(np.mean(drop)))


def _parse(doc: dict) -> Skeleton:
    rows = sorted((int(k), v) for k, v in doc["joints"].items())
    if [k for k, _ in rows] != list(range(NUM_JOINTS)):
        raise ValueError("skeleton must list joints 0..23")
    names = tuple(str(v[0]) for _, v in rows)
    parents = np.array([int(v[1]) for _, v in rows], dtype=np.int64)
    if parents[0] != -1 or any(parents[j] >= j for j in range(1, NUM_JOINTS)):
        raise ValueError("skeleton parents must precede their children, root first")
    offsets = np.array([v[2] for _, v in rows], dtype=np.float64)
    poses = {
        name: {j: np.asarray(aa, dtype=np.float64) for j, aa in (joints or {}).items()}
        for name, joints in doc.get("calibration_poses", {}).items()
    }
    return Skeleton(
        names=names,
        parents=parents,
        offsets=offsets,
        pelvis_height=float(doc["pelvis_height_at_rest"]),
        lip_imus={k: dict(v) for k, v in doc.get("lip_imus", {}).items()},
        suit_imus=dict(doc.get("suit_imus", {})),
        calibration_poses=poses,
    )


@lru_cache(maxsize=4)
def load_skeleton(path: str | Path | None = None) -> Skeleton:
    """Load the skeleton YAML (default: the package's ``params/smpl24_skeleton.yaml``)."""
    path = Path(path) if path is not None else params_path("smpl24_skeleton.yaml")
    with open(path, encoding="utf-8") as f:
        return _parse(yaml.safe_load(f))


def forward_kinematics(
    skeleton: Skeleton,
    local_rot: np.ndarray,
    root_pos: np.ndarray | None = None,
    offsets: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations (..., 24, 3, 3) and positions (..., 24, 3) from local rotations.

    ``local_rot[..., 0]`` is the root orientation in the world frame, ``root_pos``
    (..., 3) the root position (zero if omitted); ``offsets`` overrides the
    skeleton's rest offsets, e.g. for a scaled body, and may be batched.
    """
    local_rot = np.asarray(local_rot, dtype=np.float64)
    lead = local_rot.shape[:-3]
    off = skeleton.offsets if offsets is None else np.asarray(offsets, dtype=np.float64)
    root = np.zeros(3) if root_pos is None else np.asarray(root_pos, dtype=np.float64)
    glob, pos = chain(local_rot.reshape((-1, NUM_JOINTS, 3, 3)),
                      np.broadcast_to(off, lead + (NUM_JOINTS, 3)).reshape((-1, NUM_JOINTS, 3)),
                      np.broadcast_to(root, lead + (3,)).reshape((-1, 3)), np.asarray(skeleton.parents, np.int64))
    return glob.reshape(lead + (NUM_JOINTS, 3, 3)), pos.reshape(lead + (NUM_JOINTS, 3))


def calibration_pose(skeleton: Skeleton, pose: str) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations (24, 3, 3) and positions (24, 3) of a named calibration pose ('a_pose', 't_pose') of
    ``skeleton`` in its model frame M, the pelvis at the origin."""
    return forward_kinematics(skeleton, skeleton.pose_local_rotations(pose))


def joint_state_names(skeleton: Skeleton) -> list[str]:
    """The 69 JointState / URDF joint names: ``<joint>_rz, _ry, _rx`` for joints 1..23."""
    return [name + suffix for name in skeleton.names[1:] for suffix in AXIS_SUFFIXES]


def local_rotations_to_joint_angles(local_rot: np.ndarray) -> np.ndarray:
    """(..., 24, 3, 3) local rotations to (..., 69) Z-Y-X angles of joints 1..23."""
    local_rot = np.asarray(local_rot)
    eul = matrix_to_euler_zyx(local_rot[..., 1:, :, :])
    return eul.reshape(local_rot.shape[:-3] + (3 * (NUM_JOINTS - 1),))


def joint_angles_to_local_rotations(angles: np.ndarray, root_rot: np.ndarray | None = None) -> np.ndarray:
    """(..., 69) Z-Y-X angles to (..., 24, 3, 3) local rotations (root: ``root_rot`` or identity)."""
    angles = np.asarray(angles, dtype=np.float64)
    lead = angles.shape[:-1]
    rot = np.empty(lead + (NUM_JOINTS, 3, 3))
    rot[..., 0, :, :] = np.eye(3) if root_rot is None else root_rot
    rot[..., 1:, :, :] = euler_zyx_to_matrix(angles.reshape(lead + (NUM_JOINTS - 1, 3)))
    return rot
