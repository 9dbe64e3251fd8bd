"""A body's standing feet held where they stood: a causal foot lock (ROS-free).

The fused body (:mod:`lip_ros.hsc4d.suit_body`) hangs the suit's segments on the fused pelvis: a standing foot moves
with every error of the pelvis's trajectory and of the suit's leg segments, about a centimetre a frame at 10 Hz where a
true standing foot joint moves about half that, nearly all of it as it lands. :class:`FootLock` takes, frame by frame
and using nothing later, which foot stands from the suit's own feet (its segments on its own odometry: a foot it calls
standing is still there) and holds that foot joint where the body put it when its stance began (the height: the mean
over the stance so far): the hip and the knee are turned (two-bone IK; the ankle keeps its orientation in ``map``, so
the foot below it does too) until the foot joint is on its anchor. The pelvis and the rest of the body are not touched.
The body node holds the fused body's feet and the optimised body's (one lock each), the refinement the refined body's
(``RefinementConfig.foot_lock``). A hold that would move the foot joint more than ``release_m`` (the pelvis's trajectory
corrected under it, a stance the suit calls too long, a leg that cannot reach) lets the anchor go: the foot joint is the
body's own there, and held from there. Docs: docs/hsc4d/graph.md ("The standing feet").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lip_ros.core.rotations import axis_angle_to_matrix
from lip_ros.core.skeleton import Skeleton
from lip_ros.hsc4d.suit_body import LEGS, BodyPose

__all__ = ["FootLockConfig", "FOOT_LOCK", "FootLock", "locked_bodies", "leg_reaching"]


@dataclass(frozen=True)
class FootLockConfig:
    """When a foot is held, and how far at most."""

    #: a foot stands while the suit's own foot moved slower than this since the last frame (m/s; the suit's
    #: dead reckoning keeps its standing foot still, its swing foot moves at a metre a second and more; 0.5 and 0.7
    #: held more of the stances and took more of the body's errors into its legs: docs/hsc4d/graph.md)
    stance_speed_mps: float = 0.3
    release_m: float = 0.05  # a foot joint held further than this from the body's own lets its anchor go
    max_frame_gap_s: float = 0.5  # this long without the suit's feet (or between frames): the stances start again

    def __post_init__(self) -> None:
        if not (self.stance_speed_mps > 0.0 and self.release_m > 0.0 and self.max_frame_gap_s > 0.0):
            raise ValueError(f"invalid {self}")


#: The foot lock the body node and the refinement run (``foot_lock`` true).
FOOT_LOCK = FootLockConfig()


def _turn_onto(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) that turns the direction of ``u`` (3,) onto that of ``v``."""
    u, v = u / np.linalg.norm(u), v / np.linalg.norm(v)
    axis = np.cross(u, v)
    s = float(np.linalg.norm(axis))
    if s < 1e-12:
        return np.eye(3)  # parallel (antiparallel cannot happen: the turns asked for are small)
    return axis_angle_to_matrix(axis / s * np.arctan2(s, float(u @ v)))


def leg_reaching(pose: BodyPose, skeleton: Skeleton, leg: int, ankle_to: np.ndarray) -> BodyPose | None:
    """``pose`` with leg ``leg`` (index into :data:`LEGS`)'s hip and knee turned so that its ankle joint is at
    ``ankle_to`` (3,), the ankle's orientation kept (so the foot below it moves with the ankle); None if the leg
    cannot reach. The knee keeps its place about the line from the hip to the ankle in the thigh's own axes: its
    offset along the knee's hinge (the skeleton's left-right axis, turned with the thigh) stays, and it comes
    forward or back of the line as far as the bones' lengths ask, on the side it is now (``ankle_to`` at the
    ankle: the pose itself); a leg straighter than that lets it be cannot reach."""
    hip, knee, ankle, _ = (skeleton.index(name) for name in LEGS[leg])
    H, K, A = pose.joints[hip], pose.joints[knee], pose.joints[ankle]
    thigh, shank = float(np.linalg.norm(K - H)), float(np.linalg.norm(A - K))
    d = float(np.linalg.norm(ankle_to - H))
    if not abs(thigh - shank) < d < thigh + shank:
        return None
    lateral = skeleton.offsets[skeleton.index(LEGS[0][0])] - skeleton.offsets[skeleton.index(LEGS[1][0])]
    hinge = pose.glob_rot[hip] @ (lateral / np.linalg.norm(lateral))
    now, new = _leg_axes(A - H, hinge), _leg_axes(ankle_to - H, hinge)
    if now is None or new is None:
        return None  # the leg along its hinge: no forward to bend to
    _, out, across = now @ (K - H)  # the knee's place about the hip-ankle line now
    along = (thigh**2 - shank**2 + d**2) / (2.0 * d)  # the new knee's distance from the hip along the new line
    forward2 = thigh**2 - across**2 - along**2
    if forward2 < 0.0:
        return None  # straighter than a knee turning about its hinge can be
    K_new = H + new.T @ np.array([along, np.copysign(np.sqrt(forward2), out), across])
    turn_hip = _turn_onto(K - H, K_new - H)
    turn_knee = _turn_onto(turn_hip @ (A - K), ankle_to - K_new) @ turn_hip
    glob = pose.glob_rot.copy()
    glob[hip], glob[knee] = turn_hip @ glob[hip], turn_knee @ glob[knee]
    local = pose.local_rot.copy()
    parents = skeleton.parents
    for j in (hip, knee, ankle):  # the ankle's orientation kept: its local rotation under the new knee
        local[j] = glob[parents[j]].T @ glob[j]
    joints = pose.joints.copy()
    joints[knee] = K_new
    below = [ankle]  # the ankle and every joint under it move with it
    for j in below:
        below += skeleton.children(j)
    joints[below] += ankle_to - A
    return BodyPose(local, glob, joints)


def _leg_axes(leg: np.ndarray, hinge: np.ndarray) -> np.ndarray | None:
    """(3, 3) rows: along the hip-ankle line ``leg`` (3,), forward of it (the way a knee bending about ``hinge``
    goes), and across (along the hinge); None if the line is along the hinge."""
    u = leg / np.linalg.norm(leg)
    forward = np.cross(u, hinge)
    norm = float(np.linalg.norm(forward))
    if norm < 1e-6:
        return None
    forward /= norm
    return np.stack([u, forward, np.cross(u, forward)])


class FootLock:
    """The foot lock of one capture, frame by frame (:meth:`step`); :meth:`reset` for a new one.

    A standing foot joint is held at the horizontal position the body gave it when its stance began, and at the
    mean height the body gave it over the stance so far (a height held from the stance's first frame kept that
    frame's error for the whole stance: the contact error grew, docs)."""

    def __init__(self, skeleton: Skeleton, config: FootLockConfig | None = None) -> None:
        self.config = config or FootLockConfig()
        self.skeleton = skeleton
        self._feet = [skeleton.index(leg[-1]) for leg in LEGS]
        self._ankles = [skeleton.index(leg[2]) for leg in LEGS]
        self.released = 0  #: anchors let go (further than release_m from the body's own foot, or out of reach)
        self.reset()

    def reset(self) -> None:
        """Forget the stances (a new capture, or a gap)."""
        self._last: tuple[float, np.ndarray] | None = None  # (t, the suit's feet (2, 3)) of the last frame
        self._anchor: list[np.ndarray | None] = [None, None]  # each standing foot's (x, y, summed z, frames)

    def standing(self) -> list[bool]:
        """Which feet stand now (held from the next frame on)."""
        return [a is not None for a in self._anchor]

    def step(self, t_s: float, pose: BodyPose, suit_feet: np.ndarray | None) -> BodyPose:
        """The body at time ``t_s`` (s) with its standing feet held; ``suit_feet`` (2, 3): the suit's own foot
        joints (its segments on its own odometry). None (not known for this frame): the feet that stood stay
        standing, until ``max_frame_gap_s`` after the last frame that had them; then the stances start again."""
        last = self._last
        if last is not None and not 0.0 < t_s - last[0] <= self.config.max_frame_gap_s:
            self.reset()  # too long without the suit's feet, or the time went back
            last = None
        if suit_feet is None or not np.isfinite(suit_feet).all():
            standing = self.standing()
        else:
            self._last = (t_s, np.asarray(suit_feet, dtype=np.float64))
            if last is None:
                return pose
            speed = np.linalg.norm(self._last[1] - last[1], axis=1) / (t_s - last[0])
            standing = list(speed < self.config.stance_speed_mps)
        for leg, foot in enumerate(self._feet):
            own = pose.joints[foot]
            anchor = self._anchor[leg]
            if not standing[leg]:
                self._anchor[leg] = None
                continue
            if anchor is None:  # the stance begins where the body puts the foot now
                self._anchor[leg] = np.array([own[0], own[1], own[2], 1.0])
                continue
            anchor[2:] += (own[2], 1.0)
            target = np.array([anchor[0], anchor[1], anchor[2] / anchor[3]])
            held = None
            if np.linalg.norm(target - own) <= self.config.release_m:
                held = leg_reaching(pose, self.skeleton, leg, pose.joints[self._ankles[leg]] + target - own)
            if held is None:  # let go: the stance begins again where the body's own foot is
                self.released += 1
                self._anchor[leg] = np.array([own[0], own[1], own[2], 1.0])
            else:
                pose = held
        return pose


def locked_bodies(skeleton: Skeleton, t_s: np.ndarray, bodies: BodyPose, suit_feet: np.ndarray,
                  config: FootLockConfig | None = None) -> BodyPose:
    """:meth:`FootLock.step` over a capture's frames in turn: times (N,), bodies (arrays (N, 24, ...)), the suit's
    own feet (N, 2, 3); the bodies with their standing feet held."""
    lock = FootLock(skeleton, config)
    out = [lock.step(float(t), BodyPose(bodies.local_rot[k], bodies.glob_rot[k], bodies.joints[k]), suit_feet[k])
           for k, t in enumerate(t_s)]
    return BodyPose(*(np.stack([getattr(p, f) for p in out]) for f in ("local_rot", "glob_rot", "joints")))
