"""Posing the contract skeleton for procedural motion: posture channels, foot plans and leg IK.

A motion clip describes the body at T times as a :class:`Drive`: pelvis
position and heading in the ground frame (the LiDAR frame L shifted down to the
ground: x forward, y left, z up, ground at z = 0), a posture vector of angles,
and where each foot is (ankle target, yaw, pitch). :meth:`BodyRig.solve` turns
it into local joint rotations: the upper body from Euler angles, each leg by
analytic two-bone IK (the knee bends forward only; a foot in the air is kept
from snapping the leg straight). :meth:`BodyRig.reach_limit` tells how high
the pelvis may be for the planted feet to stay in reach.

Joint angles are stored in the *left-side convention*: a right-side joint holds
the angles of the mirrored left-side motion (so the same numbers pose both arms
symmetrically) and is mirrored when converted. Shoulder angles (x-z-x chain)
are (-forward flexion, elevation above horizontal, twist); the A-pose arm has
elevation -60 degrees, the T-pose 0.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from lip_ros.core.frames import R_L_M_FACING_X
from lip_ros.core.rotations import rot_x, rot_y, rot_z
from lip_ros.core.skeleton import NUM_JOINTS, Skeleton, forward_kinematics
from lip_ros.rig.motion.primitives import bump, euler_chain, smoothstep, soft_clamp, softplus, wrap_angle

__all__ = [
    "POSTURE_SIZE",
    "CHANNELS",
    "posture",
    "FootPlan",
    "Drive",
    "BodyRig",
    "sole_points",
]

#: Orientation in L of an upright body facing +x of L (model z -> x, y -> z, x -> y).

# Sole points of the reference body in bone frames, matching the foot capsules of
# lip_ros.core.body: heel under the ankle (ankle frame), ball and toe tip (foot frame).
_HEEL = np.array([0.0, -0.085, -0.045])
_BALL = np.array([0.0, -0.030, 0.0])
_TOE = np.array([0.0, -0.030, 0.05])
_LEGS = ((1, 4, 7, 10), (2, 5, 8, 11))  # hip, knee, ankle, foot joints of the left and right leg

# Posture vector layout.
U, V, Z, YAW, PITCH, TWIST, ROLL = range(7)
_JOINT0 = 7  # 24 x 3 joint angles in each joint's Euler chain (left-side convention)
_FOOT_OFF = _JOINT0 + 3 * NUM_JOINTS  # (2, 3) foot offsets in the heading frame: forward, left, up
_FOOT_PITCH = _FOOT_OFF + 6  # (2,) extra foot pitch (positive: toes down)
_KNEE_OUT = _FOOT_PITCH + 2  # (2,) hip external rotation (knees out)
POSTURE_SIZE = _KNEE_OUT + 2

_SEQUENCES = {
    "yxz": (3, 6, 9, 12, 15),  # spine, neck, head: twist (y), flexion (x), side bend (z)
    "yzx": (13, 14, 18, 19, 20, 21, 22, 23),  # collars, elbows, wrists, hands
    "xzx": (16, 17),  # shoulders: -flexion, elevation, twist
}
_MIRROR = {"x": 1.0, "y": -1.0, "z": -1.0}  # reflection x -> -x of a rotation about each axis


def _channel_table() -> dict[str, tuple[tuple[int, float], ...]]:
    def joint(j: int, k: int) -> int:
        return _JOINT0 + 3 * j + k

    spine, head = ((3, 0.35), (6, 0.3), (9, 0.35)), ((12, 0.4), (15, 0.6))
    table: dict[str, tuple[tuple[int, float], ...]] = {
        name: ((i, 1.0),) for i, name in enumerate(("u", "v", "z", "yaw", "pitch", "twist", "roll"))
    }
    for group, joints in (("spine", spine), ("head", head)):
        for k, what in enumerate(("twist", "flex", "lat")):
            table[f"{group}_{what}"] = tuple((joint(j, k), w) for j, w in joints)
    for side, (p, collar, shoulder, elbow, wrist) in enumerate((("l_", 13, 16, 18, 20), ("r_", 14, 17, 19, 21))):
        table[p + "collar"] = ((joint(collar, 1), 1.0),)  # elevation (shrug)
        table[p + "f"] = ((joint(shoulder, 0), -1.0),)  # forward flexion
        table[p + "e"] = ((joint(shoulder, 1), 1.0),)  # elevation above horizontal
        table[p + "tw"] = ((joint(shoulder, 2), 1.0),)  # twist (negative: forearm up when bent)
        table[p + "elbow"] = ((joint(elbow, 0), -1.0),)  # elbow flexion
        table[p + "pron"] = ((joint(elbow, 2), 1.0),)
        table[p + "wrist"] = ((joint(wrist, 1), 1.0),)
        for k, axis in enumerate("uvz"):
            table[f"{p}foot_{axis}"] = ((_FOOT_OFF + 3 * side + k, 1.0),)
        table[p + "foot_pitch"] = ((_FOOT_PITCH + side, 1.0),)
        table[p + "knee_out"] = ((_KNEE_OUT + side, 1.0),)
    return table


#: Semantic posture channels -> (index in the posture vector, weight) pairs.
CHANNELS = _channel_table()


def posture(channels: Mapping[str, np.ndarray | float], n: int, base: np.ndarray | None = None) -> np.ndarray:
    """(n, POSTURE_SIZE) posture vectors: ``base`` plus the named semantic channels (see ``CHANNELS``)."""
    out = np.zeros((n, POSTURE_SIZE)) if base is None else np.tile(base, (n, 1))
    for name, value in channels.items():
        for i, w in CHANNELS[name]:
            out[:, i] += w * np.asarray(value)
    return out


def _mirrored(names: tuple[str, ...]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    groups = {}
    for seq, joints in _SEQUENCES.items():
        signs = np.array([[_MIRROR[a] if names[j].startswith("right_") else 1.0 for a in seq] for j in joints])
        groups[seq] = (np.array(joints), signs)
    return groups


@dataclass
class FootPlan:
    """Where and when one foot is planted; between two plants it swings over.

    A footprint is the ground point under the ankle of the flat foot, with the
    foot's yaw. A swing rises in a bump of height ``lift`` (highest at ``peak``)
    on top of a plateau of height ``clearance`` (reached within the first and
    left within the last fifth of the swing: quick lift-off and touch-down, as
    in running). During a plant the foot may roll: from ``strike`` pitch at
    touch-down to flat within ``strike_time``, and to ``push`` pitch at lift-off
    within the last ``push_time`` (positive pitch = heel up, rolling over the
    ball; negative = toes up, on the heel). The first plant starts at -inf and
    the last ends at +inf. On terrain a footprint stands at its ``ground``
    height, pitched by its ``slope`` (the pitch of a ramp under the foot, signed
    as the roll's); a swing climbs to a higher footprint early and drops to a
    lower one late (clearing the step edges), turning to the next slope.
    """

    start: np.ndarray  # (N,)
    end: np.ndarray  # (N,)
    xy: np.ndarray  # (N, 2)
    yaw: np.ndarray  # (N,)
    lift: np.ndarray  # (N,) apex height of the swing after each plant
    strike: np.ndarray  # (N,)
    strike_time: np.ndarray  # (N,)
    push: np.ndarray  # (N,)
    push_time: np.ndarray  # (N,)
    clearance: np.ndarray  # (N,) plateau height of the swing after each plant
    peak: float = 0.5  # where in the swing the bump is highest (fraction)
    ground: np.ndarray | None = None  # (N,) height of each footprint's ground (None: all 0)
    slope: np.ndarray | None = None  # (N,) foot pitch the ground under each footprint asks for (None: all 0)

    def evaluate(
        self, t: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Footprint xy (T, 2), yaw (T,), swing height (T,), roll pitch (T,), airborne weight (T,) and the
        ground the foot is on or over (T, 2): its height under the ankle and its slope pitch, at times ``t``.

        The airborne weight is 0 while planted and rises to 1 within the first
        quarter of a swing (falling back within the last quarter); a swing that
        hardly lifts the foot (below 2 cm) stays (partly) grounded.
        """
        n = len(self.start)
        i = np.clip(np.searchsorted(self.start, t, side="right") - 1, 0, n - 1)
        j = np.minimum(i + 1, n - 1)
        planted = t <= self.end[i]
        gap = np.maximum(self.start[j] - self.end[i], 1e-9)
        sigma = np.where(planted, 0.0, (t - self.end[i]) / np.where(planted, 1.0, gap))
        w = smoothstep(sigma)
        xy = self.xy[i] + w[:, None] * (self.xy[j] - self.xy[i])
        yaw = self.yaw[i] + w * wrap_angle(self.yaw[j] - self.yaw[i])
        plateau = smoothstep(5.0 * sigma) * smoothstep(5.0 * (1.0 - sigma))
        height = self.lift[i] * bump(sigma, self.peak) + self.clearance[i] * plateau
        rolled = self.strike[i] * (1.0 - smoothstep((t - self.start[i]) / self.strike_time[i]))
        pushed = self.push[i] * smoothstep((t - self.end[i] + self.push_time[i]) / self.push_time[i])
        stance = rolled + pushed
        swing = self.push[i] + w * (self.strike[j] - self.push[i])
        lifted = smoothstep((self.lift[i] + self.clearance[i]) / 0.02)
        airborne = smoothstep(4.0 * sigma) * smoothstep(4.0 * (1.0 - sigma)) * lifted
        ground = np.zeros(n) if self.ground is None else self.ground
        slope = np.zeros(n) if self.slope is None else self.slope
        climb = np.where(ground[j] > ground[i], smoothstep(4.0 * sigma), smoothstep(4.0 * sigma - 3.0))
        base = ground[i] + climb * (ground[j] - ground[i])
        tilt = np.where(planted, slope[i], slope[i] + w * (slope[j] - slope[i]))
        return xy, yaw, height, np.where(planted, stance, swing), airborne, np.stack([base, tilt], -1)


@dataclass
class Drive:
    """What a clip asks of the body at T times (ground frame: L with z = 0 on the ground)."""

    pelvis_xy: np.ndarray  # (T, 2)
    pelvis_z: np.ndarray  # (T,) wished pelvis height; lowered where a planted foot needs it
    heading: np.ndarray  # (T,) facing direction, radians about z
    posture: np.ndarray  # (T, POSTURE_SIZE)
    ankle: np.ndarray  # (T, 2, 3) ankle targets, left and right
    foot_yaw: np.ndarray  # (T, 2)
    foot_pitch: np.ndarray  # (T, 2)
    toe: np.ndarray  # (T, 2) toe flexion (foot joint, about x)
    airborne: np.ndarray  # (T, 2) 0 for a foot on the ground, 1 for one in the air (the pelvis need not reach it)


def _shortest_rotation(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(T, 3, 3) shortest rotations turning directions ``v`` to ``t`` (both (T, 3))."""
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    t = t / np.linalg.norm(t, axis=-1, keepdims=True)
    k = np.cross(v, t)
    c = np.sum(v * t, axis=-1)
    kx = np.zeros(k.shape[:-1] + (3, 3))
    kx[..., 0, 1], kx[..., 0, 2], kx[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    kx[..., 1, 0], kx[..., 2, 0], kx[..., 2, 1] = k[..., 2], -k[..., 1], k[..., 0]
    return np.eye(3) + kx + (kx @ kx) / (1.0 + c)[..., None, None]


class BodyRig:
    """One performer's body geometry for posing: legs, feet, neutral stance; solves drives into poses."""

    KNEE_NEUTRAL = np.radians(5.0)  # knee flexion of the relaxed standing pose
    KNEE_CAP = KNEE_NEUTRAL  # planted legs are kept at least this bent (see reach_limit)
    KNEE_MIN = np.radians(0.75)  # the IK never straightens a knee further
    KNEE_SWING = np.radians(8.0)  # a foot in the air is kept within reach of this knee flexion ...
    _SWING_EASE = np.radians(30.0)  # ... easing in from this flexion on
    _PIVOT_BLEND = 0.08  # rad of pitch over which the foot's pivot moves from heel to ball

    def __init__(self, skeleton: Skeleton) -> None:
        self.skeleton = skeleton
        self.scale = skeleton.scale
        off = skeleton.offsets
        _, rest = forward_kinematics(skeleton, np.tile(np.eye(3), (NUM_JOINTS, 1, 1)))
        legs = np.array(_LEGS)
        self.hip_off = off[legs[:, 0]]
        self._thigh, self._shank = off[legs[:, 1]], off[legs[:, 2]]
        self.heel = np.tile(_HEEL * self.scale, (2, 1))  # pivots in the ankle frame: the heel's sole point and
        self.ball = off[legs[:, 3]]  # the toe joint (the toes stay flat on the ground when the heel rises)
        soles = np.stack(
            [self.heel[:, 1], (self.ball + _BALL * self.scale)[:, 1], (self.ball + _TOE * self.scale)[:, 1]]
        )
        self.ankle_height = -np.min(soles, axis=0)
        # |thigh + Rx(k) shank|^2 = c0 + 2 rho cos(k - phi) for knee flexion k
        a, b = self._thigh, self._shank
        self._c0 = np.sum(a * a, -1) + np.sum(b * b, -1) + 2.0 * a[:, 0] * b[:, 0]
        cos_c, sin_c = a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2], a[:, 2] * b[:, 1] - a[:, 1] * b[:, 2]
        self._rho, self._phi = np.hypot(cos_c, sin_c), np.arctan2(sin_c, cos_c)
        self._cap = self.reach(self.KNEE_CAP)
        self._dmax = self.reach(self.KNEE_MIN)
        self._dswing = self.reach(self.KNEE_SWING)
        self._swing_margin = self._dswing - self.reach(self._SWING_EASE)
        ankles = rest[legs[:, 2]]
        #: pelvis height of the zero pose standing with its lowest sole on the ground
        self.stand_height = float(np.max(self.ankle_height - ankles[:, 1]))
        #: flat-foot ankle positions (forward, left) relative to the pelvis when standing
        self.neutral_feet = ankles[:, [2, 0]].copy()
        self.neutral_height = self.pelvis_height_for(self.KNEE_NEUTRAL)
        self._groups = _mirrored(skeleton.names)

    def reach(self, knee: float) -> np.ndarray:
        """(2,) hip-to-ankle distance of the left and right leg at knee flexion ``knee`` (rad)."""
        return np.sqrt(self._c0 + 2.0 * self._rho * np.cos(knee - self._phi))

    def pelvis_height_for(self, knee: float, pitch: float = 0.0) -> float:
        """Upright pelvis height standing on the neutral footprints with knees bent ``knee`` (rad),
        feet pitched ``pitch`` (heels raised when positive).
        """
        heights = []
        for side in range(2):
            ankle = self.ankle_from_footprint(
                side, self.neutral_feet[side][None], np.zeros(1), np.zeros(1), np.full(1, pitch), planar=True
            )[0]
            horiz = np.hypot(self.hip_off[side, 2] - ankle[0], self.hip_off[side, 0] - ankle[1])
            vertical = np.sqrt(self.reach(knee)[side] ** 2 - horiz**2)
            heights.append(ankle[2] + vertical - self.hip_off[side, 1])
        return float(min(heights))

    def ankle_from_footprint(
        self,
        side: int,
        xy: np.ndarray,
        yaw: np.ndarray,
        height: np.ndarray,
        pitch: np.ndarray,
        planar: bool = False,
        ground: np.ndarray | None = None,
    ) -> np.ndarray:
        """(T, 3) ankle positions of a foot on footprints ``xy`` (T, 2) with ``yaw``, lifted ``height``,
        pitched ``pitch`` about its heel (pitch < 0) or ball (pitch > 0).

        With ``planar`` the result is (forward, left, up) in the footprint's own frame, yaw ignored. On
        terrain, ``ground`` (T, 2) is the height of the ground plane under the footprint and its slope (a
        pitch, toes down when positive): the foot lifts and rolls in the plane tilted by the slope.
        """
        w = smoothstep((pitch + self._PIVOT_BLEND) / (2.0 * self._PIVOT_BLEND))[:, None]
        pivot = (1.0 - w) * self.heel[side] + w * self.ball[side]
        disp = pivot - np.einsum("tab,tb->ta", rot_x(pitch), pivot)  # model frame M of the flat foot
        flat = np.column_stack([xy, self.ankle_height[side] + height])
        if planar:
            return flat + disp[:, [2, 0, 1]]
        if ground is None:
            return flat + np.einsum("tab,tb->ta", rot_z(yaw) @ R_L_M_FACING_X, disp)
        above = np.einsum("ab,tb->ta", R_L_M_FACING_X, disp)  # forward, left, up of the footprint's frame
        above[:, 2] += self.ankle_height[side] + height
        tilted = np.einsum("tab,tb->ta", rot_z(yaw) @ rot_y(ground[:, 1]), above)
        return np.column_stack([xy, ground[:, 0]]) + tilted

    def toe_flat(self, pitch: np.ndarray, rise: np.ndarray) -> np.ndarray:
        """Toe flexion keeping the toes flat on the ground when the heel is raised (fading as the foot rises)."""
        on_ball = smoothstep((pitch + self._PIVOT_BLEND) / (2.0 * self._PIVOT_BLEND))
        return -pitch * on_ball * np.exp(-np.maximum(rise, 0.0) / (0.06 * self.scale))

    def _pelvis_frame(self, drive: Drive) -> tuple[np.ndarray, np.ndarray]:
        """Pelvis rotations (T, 3, 3) and hip offsets in the world (T, 2, 3)."""
        tilt = euler_chain(drive.posture[:, [TWIST, PITCH, ROLL]], "yxz")
        r_pelvis = rot_z(drive.heading) @ R_L_M_FACING_X @ tilt
        return r_pelvis, np.einsum("tab,sb->tsa", r_pelvis, self.hip_off)

    def _caps(self, drive: Drive, hips: np.ndarray) -> np.ndarray:
        """(T, 2) highest pelvis z from which each ankle target is in reach (knees bent >= KNEE_CAP)."""
        caps = []
        for side in range(2):
            ankle = drive.ankle[:, side]
            horiz = drive.pelvis_xy + hips[:, side, :2] - ankle[:, :2]
            floor = (0.55 * self._cap[side]) ** 2  # an out-of-reach foot lowers the pelvis this far at most
            q = floor + softplus(self._cap[side] ** 2 - np.sum(horiz**2, axis=-1) - floor, 1e-3)
            caps.append(ankle[:, 2] + np.sqrt(q) - hips[:, side, 2])
        return np.stack(caps, 1)

    def reach_limit(self, drive: Drive) -> np.ndarray:
        """(T,) highest pelvis z keeping the feet that are on the ground (airborne < 0.5) in reach."""
        caps = self._caps(drive, self._pelvis_frame(drive)[1])
        return np.min(np.where(drive.airborne < 0.5, caps, np.inf), axis=1)

    def rotations(self, post: np.ndarray) -> np.ndarray:
        """(T, 24, 3, 3) local rotations of the upper body from posture vectors (T, POSTURE_SIZE);
        pelvis and legs identity.
        """
        n = len(post)
        local = np.tile(np.eye(3), (n, NUM_JOINTS, 1, 1))
        angles = post[:, _JOINT0:_FOOT_OFF].reshape(n, NUM_JOINTS, 3)
        for seq, (joints, signs) in self._groups.items():
            local[:, joints] = euler_chain(angles[:, joints] * signs, seq)
        return local

    def solve(self, drive: Drive) -> tuple[np.ndarray, np.ndarray]:
        """Pelvis positions (T, 3) in the ground frame and local rotations (T, 24, 3, 3) for a drive.

        The pelvis is put where the drive says: keeping planted feet in reach is
        the caller's business (see ``reach_limit``); a foot out of reach stops
        short of its target with the knee at ``KNEE_MIN``.
        """
        post = drive.posture
        r_pelvis, hips = self._pelvis_frame(drive)
        root = np.column_stack([drive.pelvis_xy, drive.pelvis_z])
        local = self.rotations(post)
        local[:, 0] = r_pelvis
        pelvis_yaw = drive.heading + post[:, TWIST]
        for side, (hip_j, knee_j, ankle_j, foot_j) in enumerate(_LEGS):
            vec = drive.ankle[:, side] - (root + hips[:, side])
            dist = np.linalg.norm(vec, axis=-1)
            swing = soft_clamp(dist, self._dswing[side], self._swing_margin[side])  # no snapping straight in the air
            dist = dist + drive.airborne[:, side] * (swing - dist)
            dist = soft_clamp(dist, self._dmax[side], 0.002 * self.scale)
            cos_k = (dist**2 - self._c0[side]) / (2.0 * self._rho[side])
            knee = self._phi[side] + np.arccos(np.clip(cos_k, -1.0, 1.0))
            r_knee = rot_x(knee)
            leg = self._thigh[side] + r_knee @ self._shank[side]
            knees_out = post[:, _KNEE_OUT + side] * (1.0 if side == 0 else -1.0)
            r_twist = rot_y(wrap_angle(drive.foot_yaw[:, side] - pelvis_yaw) + knees_out)
            target = np.einsum("tba,tb->ta", r_pelvis, vec)  # in the pelvis frame
            r_hip = _shortest_rotation(np.einsum("tab,tb->ta", r_twist, leg), target) @ r_twist
            pitch = drive.foot_pitch[:, side]
            r_foot = rot_z(drive.foot_yaw[:, side]) @ R_L_M_FACING_X @ rot_x(pitch)
            local[:, hip_j] = r_hip
            local[:, knee_j] = r_knee
            local[:, ankle_j] = np.swapaxes(r_pelvis @ r_hip @ r_knee, -1, -2) @ r_foot
            local[:, foot_j] = rot_x(drive.toe[:, side])
        return root, local


def sole_points(skeleton: Skeleton, glob_rot: np.ndarray, joint_pos: np.ndarray) -> np.ndarray:
    """(..., 6, 3) heel, ball and toe-tip points of the left and right sole (order: heels, balls, toes).

    ``glob_rot`` (..., 24, 3, 3) and ``joint_pos`` (..., 24, 3) as from forward kinematics.
    """
    s = skeleton.scale
    legs = np.array(_LEGS)
    pts = []
    for joints, local in ((legs[:, 2], _HEEL), (legs[:, 3], _BALL), (legs[:, 3], _TOE)):
        pts.append(joint_pos[..., joints, :] + np.einsum("...sab,b->...sa", glob_rot[..., joints, :, :], local * s))
    return np.concatenate(pts, axis=-2)
