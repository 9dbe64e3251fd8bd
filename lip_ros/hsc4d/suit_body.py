"""The fused body: the suit's 17 segment orientations on the fused pelvis trajectory, in ``map`` (ROS-free).

Each suit IMU reports the global rotation of one joint (``suit_imus`` of the
skeleton) in the suit's inertial frame I, whose heading is unknown and
drifts. The fused trajectory gives the pelvis's pose in ``map``, T_map_P, at a
sweep's reference time; with the suit's own pelvis rotation R_I_P at that
moment, R_map_I = R_map_P R_I_P^T turns every segment into ``map`` (I's heading
cancels). The seven joints the suit does not measure get their rotation from
their neighbours: a chain between two measured joints (spine1 and spine2
between the pelvis and spine3, the neck between spine3 and the head) shares
the turn between them evenly; an end joint (feet, hands) follows its parent.
Forward kinematics from the fused pelvis position, on the contract skeleton
scaled to the performer (``body_scale``: the size the suit's software is
given), places the 24 joints. The suit's samples are stamped on its own clock:
ask at LiDAR-clock time plus the offset the jump gave.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lip_ros.core.imu_sync import FrameStatus, ImuSampleLike, ImuSynchronizer, SyncConfig
from lip_ros.core.rotations import axis_angle_to_matrix, matrix_to_axis_angle, quat_to_matrix
from lip_ros.core.skeleton import NUM_JOINTS, Skeleton, forward_kinematics

__all__ = ["SuitBodyConfig", "BodyPose", "SuitBody", "unmeasured_chains", "moved_body", "LEGS", "FEET", "leg_chains",
           "bent_legs", "resized_body"]

#: each leg's joints from the hip down to the foot joint (left, right): the scene-aware optimisation turns the hip,
#: knee and ankle to place the foot
LEGS = (("left_hip", "left_knee", "left_ankle", "left_foot"), ("right_hip", "right_knee", "right_ankle", "right_foot"))
#: the joints placed on the ground
FEET = tuple(leg[-1] for leg in LEGS)


@dataclass(frozen=True)
class SuitBodyConfig:
    """Buffer bounds of the suit's samples and the performer's size."""

    #: samples kept per segment: 20 s at 100 Hz, for the poses of the sweeps held until the jump (up to
    #: TrajectoryConfig.hold_s, 15 s) and the suit's clock offset (up to 1 s)
    capacity: int = 2048
    max_gap_ns: int = 50_000_000  # widest gap interpolated across (four lost samples at 100 Hz)
    max_hold_ns: int = 50_000_000  # a segment's last sample is held this long past it, then it is missing
    body_scale: float = 1.0  # the performer's size relative to the contract skeleton

    def __post_init__(self) -> None:
        if self.capacity < 2 or self.max_gap_ns <= 0 or self.max_hold_ns < 0 or not self.body_scale > 0.0:
            raise ValueError(f"invalid {self}")


@dataclass(frozen=True)
class BodyPose:
    """The body at one moment in ``map``: local rotations (24, 3, 3) (the root's is its global one), global
    rotations (24, 3, 3) and joint positions (24, 3)."""

    local_rot: np.ndarray
    glob_rot: np.ndarray
    joints: np.ndarray


def moved_body(pose: BodyPose, T_from: np.ndarray, T_to: np.ndarray) -> BodyPose:
    """The body posed on the pelvis pose ``T_from`` (4, 4) carried rigidly onto ``T_to`` (the suit's segments
    reach ``map`` through the pelvis pose alone, so this is the body :meth:`SuitBody.pose` gives on ``T_to``); any
    leading dimensions (N frames: ``pose``'s arrays (N, 24, ...), the poses (N, 4, 4))."""
    turn = T_to[..., :3, :3] @ np.swapaxes(T_from[..., :3, :3], -1, -2)
    local = pose.local_rot.copy()
    local[..., 0, :, :] = turn @ local[..., 0, :, :]
    joints = T_to[..., None, :3, 3] + np.einsum("...ab,...jb->...ja", turn, pose.joints - T_from[..., None, :3, 3])
    return BodyPose(local, turn[..., None, :, :] @ pose.glob_rot, joints)


def resized_body(pose: BodyPose, ratio: float | np.ndarray) -> BodyPose:
    """``pose`` (any leading dimensions) on a skeleton ``ratio`` times its size (a scalar, or one per leading
    index): its joints moved about the pelvis (the root), its rotations kept."""
    ratio = np.asarray(ratio, dtype=np.float64)[..., None, None]
    root = pose.joints[..., :1, :]
    return BodyPose(pose.local_rot, pose.glob_rot, root + ratio * (pose.joints - root))


def _leg_joints(skeleton: Skeleton) -> np.ndarray:
    """(2, 4) the indices of :data:`LEGS` in ``skeleton``."""
    return np.array([[skeleton.index(name) for name in leg] for leg in LEGS])


def leg_chains(skeleton: Skeleton, local_rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each leg (:data:`LEGS`) of a body: the hip's, knee's and ankle's local rotations (..., 2, 3, 3, 3) of
    ``local_rot`` (..., 24, 3, 3), and the skeleton's bones down the leg (2, 4, 3): the hip from the pelvis, the
    knee from the hip, the ankle from the knee, the foot joint from the ankle (rest offsets, parent's frame)."""
    joints = _leg_joints(skeleton)
    return np.asarray(local_rot)[..., joints[:, :3], :, :], skeleton.offsets[joints].copy()


def bent_legs(pose: BodyPose, skeleton: Skeleton, legs: np.ndarray) -> BodyPose:
    """``pose`` (any leading dimensions) with the hips', knees' and ankles' local rotations replaced by ``legs``
    (..., 2, 3, 3, 3; :func:`leg_chains`), the rest of the body and the pelvis kept."""
    local = pose.local_rot.copy()
    local[..., _leg_joints(skeleton)[:, :3], :, :] = legs
    glob, positions = forward_kinematics(skeleton, local, pose.joints[..., 0, :])
    return BodyPose(local, glob, positions)


def unmeasured_chains(skeleton: Skeleton, measured: set[int]) -> list[tuple[int, list[int]]]:
    """The joints not measured, as (the measured joint above them, the chain of joints below it down to and
    including the next measured joint, or down to an unmeasured end joint). Each unmeasured joint is in exactly
    one chain; a branching below an unmeasured joint is not supported (ValueError)."""
    out = []
    for top in sorted(measured):
        for child in skeleton.children(top):
            if child in measured:
                continue
            chain = [child]
            while chain[-1] not in measured and len(skeleton.children(chain[-1])) == 1:
                chain.append(skeleton.children(chain[-1])[0])
            if chain[-1] not in measured and skeleton.children(chain[-1]):
                raise ValueError(f"joint {skeleton.names[chain[-1]]} branches but is not measured")
            out.append((top, chain))
    return out


class SuitBody:
    """The suit's segments, buffered per segment, posed on the fused pelvis."""

    def __init__(self, skeleton: Skeleton, config: SuitBodyConfig | None = None) -> None:
        self.config = c = config or SuitBodyConfig()
        self._contract = skeleton
        self.skeleton = skeleton.scaled(c.body_scale)
        self.segments = tuple(skeleton.suit_imus)
        self._joint = np.array([skeleton.index(skeleton.suit_imus[s]) for s in self.segments])
        if skeleton.index("pelvis") not in self._joint:
            raise ValueError("the suit has no pelvis sensor")
        self.pelvis_segment = self.segments[list(self._joint).index(skeleton.index("pelvis"))]
        measured = set(int(j) for j in self._joint)
        self._chains = unmeasured_chains(skeleton, measured)
        self.sync = ImuSynchronizer(self.segments, SyncConfig(capacity=c.capacity, max_gap_ns=c.max_gap_ns,
                                                              max_hold_ns=c.max_hold_ns))

    def add(self, segment: str, samples: Sequence[ImuSampleLike]) -> list[str | None]:
        """Samples of ``segment`` (suit clock; many at once cost about what one does); for each, why it was
        rejected, None if kept."""
        if not samples:
            return []
        rows, codes = self.sync.validate(samples)
        return [self.sync.insert(segment, int(s.stamp_ns), row, int(code))
                for s, row, code in zip(samples, rows, codes, strict=True)]

    def scale_to_pelvis_height(self, height_m: float) -> float:
        """Scale the skeleton so that its pelvis stands ``height_m`` above its soles (e.g. the fused pelvis's
        height above the ground while the wearer stands still); the scale relative to the contract skeleton."""
        if not (np.isfinite(height_m) and height_m > 0.0):
            raise ValueError(f"pelvis height must be > 0, got {height_m}")
        scale = float(height_m) / self._contract.pelvis_height
        self.skeleton = self._contract.scaled(scale)
        return scale

    def pelvis_rotation(self, suit_ns: int) -> np.ndarray | None:
        """R_I_P (3, 3): the pelvis segment's orientation in the suit's world at suit-clock time ``suit_ns``, or None
        when a segment has no sample near it."""
        result = self.sync.query(int(suit_ns))
        if result.frame_status == FrameStatus.SKIP:
            return None
        return quat_to_matrix(result.quat[self.segments.index(self.pelvis_segment)])

    def pose(self, suit_ns: int, T_map_P: np.ndarray) -> tuple[BodyPose | None, str]:
        """The body at suit-clock time ``suit_ns`` on the fused pelvis pose ``T_map_P`` (4, 4); (None, why) when
        a segment has no sample near it, else (pose, "") or (pose, which segments were held)."""
        result = self.sync.query(int(suit_ns))
        if result.frame_status == FrameStatus.SKIP:
            return None, result.reason
        R_I = quat_to_matrix(result.quat)  # (17, 3, 3)
        R_map_I = T_map_P[:3, :3] @ R_I[self.segments.index(self.pelvis_segment)].T
        glob = np.full((NUM_JOINTS, 3, 3), np.nan)
        glob[self._joint] = R_map_I @ R_I
        parents = self.skeleton.parents
        for top, chain in self._chains:
            if chain[-1] in self._joint:  # between two measured joints: share the turn evenly
                turn = matrix_to_axis_angle(glob[top].T @ glob[chain[-1]]) / len(chain)
                for k, j in enumerate(chain[:-1], start=1):
                    glob[j] = glob[top] @ axis_angle_to_matrix(k * turn)
            else:
                for j in chain:
                    glob[j] = glob[parents[j]]
        local = np.empty_like(glob)
        local[0] = glob[0]
        local[1:] = np.swapaxes(glob[parents[1:]], -1, -2) @ glob[1:]
        glob, joints = forward_kinematics(self.skeleton, local, T_map_P[:3, 3])
        return BodyPose(local, glob, joints), "" if result.frame_status == FrameStatus.OK else result.reason
