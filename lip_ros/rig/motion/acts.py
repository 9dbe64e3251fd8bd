"""In-place activities, choreographed: squats, jumps, arm gestures, martial arts, dance.

Each ``build_*`` function has the signature ``(rig, style, rng, anchor,
duration, area) -> PostureClip`` and fills ``duration`` with randomised
repetitions of its moves, starting and ending relaxed. Angles are radians in
the channel conventions of :mod:`lip_ros.rig.motion.posture` (shoulder ``f``
forward flexion, ``e`` elevation above horizontal, ``tw`` twist; positive
``pitch`` leans forward; feet offsets forward/left/up).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lip_ros.core.frames import GRAVITY
from lip_ros.rig.motion.clips import Anchor, Area, Choreo, PostureClip, Style
from lip_ros.rig.motion.posture import BodyRig
from lip_ros.rig.motion.primitives import EasedKeys, rotate_2d, smoothstep_inverse, wrap_angle

__all__ = ["build_squat", "build_jump", "build_sync_jump", "build_arms", "build_martial", "build_dance", "build_turn"]


def build_squat(
    rig: BodyRig, style: Style, rng: np.random.Generator, anchor: Anchor, duration: float, area: Area
) -> PostureClip:
    """Step out to a wider stance, squat repeatedly (hips back, torso forward, arms up), step back in."""
    c, s, tp, u = Choreo("squat", rig, style, anchor, duration), rig.scale, style.tempo, rng.uniform
    width, toe_out = u(0.03, 0.12) * s, u(0.05, 0.3)
    arms = rng.choice(["forward", "chest", "low"])
    t = u(0.3, 0.6)
    _shuffle_stance(c, t, width, toe_out)
    t += 1.9
    end = duration - 2.1
    while True:
        down, bottom, up, top = u(0.9, 1.4) * tp, u(0.0, 0.3), u(0.7, 1.1) * tp, u(0.2, 0.6)
        if t + down + bottom + up > end:
            break
        depth = u(0.22, 0.42) * s * style.energy
        tilt = u(0.25, 0.45) * depth / (0.32 * s)
        low = {
            "z": -depth,
            "u": -u(0.3, 0.45) * depth,
            "pitch": tilt,
            "spine_flex": c.rest("spine_flex") + u(0.0, 0.25),
            "head_flex": -0.5 * tilt,
            "l_knee_out": u(0.05, 0.2),
            "r_knee_out": u(0.05, 0.2),
        }
        if arms == "forward":
            low |= {"l_f": u(1.3, 1.6), "r_f": u(1.3, 1.6), "l_e": -1.5, "r_e": -1.5, "l_elbow": 0.1, "r_elbow": 0.1}
        elif arms == "chest":
            low |= {"l_f": 0.6, "r_f": 0.6, "l_e": -1.15, "r_e": -1.15, "l_elbow": 2.1, "r_elbow": 2.1}
        else:
            low |= {"l_f": 0.35, "r_f": 0.35}
        c.relax(t, *low)
        c.key(t + down, **low)
        if bottom > 0.05:
            c.key(t + down + bottom, **low)
        c.relax(t + down + bottom + up, *low)
        t += down + bottom + up + top
    _shuffle_stance(c, min(max(t, end), duration - 1.7), 0.0, 0.0)
    return c.build()


def _shuffle_stance(c: Choreo, t: float, width: float, toe_out: float) -> None:
    """Step the left then the right foot sideways to a stance ``width`` wider per foot, toes out."""
    w = 0.03 * c.rig.scale
    for k, side in enumerate((0, 1)):
        sign = 1.0 if side == 0 else -1.0
        t0 = t + 0.8 * k
        c.key(t0, v=-sign * w)  # weight onto the other foot
        uv = c.stance_foot(side, np.zeros(2), 0.0) + np.array([0.0, sign * width])
        c.step(side, t0 + 0.3, t0 + 0.7, uv, sign * toe_out, lift=0.05)
        c.key(t0 + 0.8, v=0.0)


def build_jump(
    rig: BodyRig, style: Style, rng: np.random.Generator, anchor: Anchor, duration: float, area: Area
) -> PostureClip:
    """Jumps in place, forward, with quarter or half turns, or tucked: crouch, arm swing, flight, landing."""
    c, s, tp, u = Choreo("jump", rig, style, anchor, duration), rig.scale, style.tempo, rng.uniform
    c.follow = rig.pelvis_height_for(np.radians(8.0))
    t, uv, yaw = u(0.3, 0.6), np.zeros(2), 0.0
    while True:
        kind = rng.choice(["vertical", "forward", "turn", "tuck"], p=[0.25, 0.4, 0.2, 0.15])
        rise = (u(0.2, 0.32) if kind == "tuck" else u(0.1, 0.28)) * s * style.energy
        crouch, absorb = u(0.12, 0.28) * s, u(0.08, 0.2) * s
        dist = u(0.3, 0.8) * s if kind == "forward" else 0.0
        turn = rng.choice([-np.pi, -np.pi / 2, np.pi / 2, np.pi]) if kind == "turn" else 0.0
        land = uv + rotate_2d(np.array([dist, 0.0]), yaw)
        if area.room(anchor.to_world(land)) < 0.6 * s:
            land, turn = uv, np.pi
        flight = 2.0 * np.sqrt(2.0 * rise / GRAVITY)
        p_off, p_air, p_land = u(0.5, 0.7), u(0.3, 0.6), u(0.15, 0.3)
        z_ext = rig.pelvis_height_for(np.radians(8.0), p_off) - rig.neutral_height  # feet leave the ground here
        z_top = z_ext + rise
        up = smoothstep_inverse((z_ext + crouch) / (z_top + crouch))
        down = smoothstep_inverse(rise / (z_top + absorb))
        t1 = t + u(0.45, 0.7) * tp  # bottom of the crouch
        t_apex = t1 + 0.5 * flight / (1.0 - up)
        t_off, t_land = t1 + up * (t_apex - t1), t_apex + 0.5 * flight
        t_low = t_apex + 0.5 * flight / down  # bottom of the landing
        t_end = t_low + u(0.4, 0.7) * tp
        if t_end + 0.3 > duration:
            break
        new_yaw = yaw + turn
        arms = ("l_f", "r_f", "l_elbow", "r_elbow")
        c.hold(t, "u", "v", "yaw")
        c.relax(t, "z", "pitch", "spine_flex", "head_flex", *arms)
        f_back, f_up = -u(0.3, 0.6), u(1.2, 2.0)
        c.key(
            t1,
            z=-crouch,
            pitch=u(0.25, 0.45),
            spine_flex=0.25,
            head_flex=-0.25,
            l_f=f_back,
            r_f=f_back,
            l_elbow=0.3,
            r_elbow=0.3,
        )
        c.key(
            t_apex, z=z_top, pitch=0.0, spine_flex=-0.05, head_flex=0.05, l_f=f_up, r_f=f_up, l_elbow=0.4, r_elbow=0.4
        )
        c.key(
            t_low,
            z=-absorb,
            pitch=u(0.2, 0.4),
            spine_flex=0.2,
            head_flex=-0.15,
            l_f=u(0.4, 0.8),
            r_f=u(0.4, 0.8),
            l_elbow=0.5,
            r_elbow=0.5,
        )
        c.relax(t_end, "z", "pitch", "spine_flex", "head_flex", *arms)
        for name in ("l_foot_pitch", "r_foot_pitch"):
            c.key(t1, **{name: 0.0})
            c.key(t_off, **{name: p_off})
            c.key(t_apex, **{name: p_air})
            c.key(t_land, **{name: p_land})
            c.key(t_low, **{name: 0.0})
        if kind == "tuck":
            tuck = u(0.12, 0.25) * s
            c.key(t_off, l_foot_z=0.0, r_foot_z=0.0, l_foot_u=0.0, r_foot_u=0.0)
            c.key(t_apex, l_foot_z=tuck, r_foot_z=tuck, l_foot_u=0.1 * s, r_foot_u=0.1 * s)
            c.key(t_land, l_foot_z=0.0, r_foot_z=0.0, l_foot_u=0.0, r_foot_u=0.0)
        lean = rotate_2d(np.array([-0.04 * s, 0.0]), yaw)
        c.key(t1, u=uv[0] + lean[0], v=uv[1] + lean[1])
        ahead = rotate_2d(np.array([0.04 * s, 0.0]), new_yaw) if dist > 0 else np.zeros(2)
        c.key(t_low, u=land[0] + ahead[0], v=land[1] + ahead[1])
        c.key(t_end, u=land[0], v=land[1])
        if turn:
            c.key(t_off, yaw=yaw)
            c.key(t_land, yaw=new_yaw)
        if dist > 0 or turn:
            for side in range(2):
                c.step(side, t_off, t_land, c.stance_foot(side, land, new_yaw), new_yaw, lift=0.0)
        uv, yaw = land, new_yaw
        t = t_end + u(0.3, 0.9) * tp
    return c.build()


def build_sync_jump(rig: BodyRig, style: Style, rng: np.random.Generator, anchor: Anchor) -> PostureClip:
    """One vertical jump in place whose flight is ballistic (the HSC4D capture's sync event): a crouch, a push
    of constant upward acceleration to take-off, free fall of the pelvis (a parabola of gravity's curvature)
    rising 12-30 cm, a landing braked at constant deceleration, back to standing; the clip lasts as long as it
    needs (about 3 s)."""
    s, tp, u = rig.scale, style.tempo, rng.uniform
    rise, crouch, absorb = u(0.12, 0.3) * s, u(0.15, 0.25) * s, u(0.1, 0.18) * s
    p_off, p_land = u(0.5, 0.7), u(0.15, 0.3)
    z_ext = rig.pelvis_height_for(np.radians(8.0), p_off) - rig.neutral_height  # feet leave the ground here
    v0 = float(np.sqrt(2.0 * GRAVITY * rise))
    t1 = u(0.4, 0.6)  # bottom of the crouch, reached eased from standing
    t_off = t1 + 2.0 * (z_ext + crouch) / v0  # pushed at constant acceleration up to take-off
    t_land = t_off + 2.0 * v0 / GRAVITY
    t_low = t_land + 2.0 * (z_ext + absorb) / v0  # braked at constant deceleration to the bottom
    t_end = t_low + u(0.5, 0.7) * tp
    c = Choreo("sync_jump", rig, style, anchor, t_end + u(0.4, 0.6))
    c.follow = rig.pelvis_height_for(np.radians(8.0))
    arms = ("l_f", "r_f", "l_elbow", "r_elbow")
    c.key(t1, z=-crouch, pitch=u(0.25, 0.4), spine_flex=0.2, head_flex=-0.2, l_f=-0.4, r_f=-0.4, l_elbow=0.3,
          r_elbow=0.3)
    c.key(t_land, pitch=0.05, spine_flex=0.0, head_flex=0.05, l_f=u(0.8, 1.2), r_f=u(0.8, 1.2), l_elbow=0.4,
          r_elbow=0.4)
    c.key(t_low, z=-absorb, pitch=u(0.2, 0.35), spine_flex=0.15, head_flex=-0.1, l_f=0.5, r_f=0.5, l_elbow=0.5,
          r_elbow=0.5)
    c.relax(t_end, "z", "pitch", "spine_flex", "head_flex", *arms)
    for name in ("l_foot_pitch", "r_foot_pitch"):
        c.key(t1, **{name: 0.0})
        c.key(t_off, **{name: p_off})
        c.key(t_land, **{name: p_land})
        c.key(t_low, **{name: 0.0})
    eased = EasedKeys(np.array([t1, t_low]), np.array([-crouch, -absorb]))  # what the z keys give in between

    def flight(t: np.ndarray) -> np.ndarray:
        """The pelvis height in [t1, t_low] less the eased keys' (zero outside): piecewise parabolic, C1."""
        push = -crouch + (z_ext + crouch) * ((t - t1) / (t_off - t1)) ** 2
        air = z_ext + v0 * (t - t_off) - 0.5 * GRAVITY * (t - t_off) ** 2
        brake = -absorb + (z_ext + absorb) * ((t_low - t) / (t_low - t_land)) ** 2
        z = np.where(t < t_off, push, np.where(t <= t_land, air, brake))
        return np.where((t > t1) & (t < t_low), z - eased(t), 0.0)

    c.add("z", flight)
    return c.build()


def build_arms(
    rig: BodyRig, style: Style, rng: np.random.Generator, anchor: Anchor, duration: float, area: Area
) -> PostureClip:
    """Standing arm gestures: side and front raises, waves, overhead sways, circles, reaches, stretches."""
    c, u, tp = Choreo("arms", rig, style, anchor, duration), rng.uniform, style.tempo
    t = u(0.3, 0.7)
    while True:
        fits = [g for g, (slow, fixed) in _GESTURES.items() if t + slow * tp + fixed < duration - 0.3]
        if not fits:
            break
        t = fits[rng.integers(len(fits))](c, t, rng) + u(0.2, 0.8)
    sway_end = duration - 0.2
    c.osc({"v": 0.01 * rig.scale, "roll": 0.015}, u(0.15, 0.3), 0.2, sway_end, ramp=1.0, phase=u(0, 2 * np.pi))
    return c.build()


def _sides(rng: np.random.Generator) -> tuple[str, ...]:
    return (("l_", "r_"), ("l_",), ("r_",))[rng.choice(3, p=[0.5, 0.25, 0.25])]


def _arm_move(c: Choreo, t0: float, poses: list[tuple[float, dict[str, float]]]) -> float:
    """Relax the posed channels at ``t0`` and key ``poses`` one after the other (dt, values); returns the last time."""
    names = tuple(sorted({n for _, pose in poses for n in pose}))
    c.relax(t0, *names)
    t = t0
    for dt, pose in poses:
        t += dt
        c.key(t, **pose)
    return t


def _relax_after(c: Choreo, t: float, dt: float, names: tuple[str, ...]) -> float:
    c.relax(t + dt, *names)
    return t + dt


def _lateral_raise(c: Choreo, t: float, rng: np.random.Generator) -> float:
    u, tp = rng.uniform, c.style.tempo
    sides = _sides(rng)
    for _ in range(rng.integers(1, 3)):
        e = u(-0.1, 1.35)
        up = (
            {p + "e": e for p in sides}
            | {p + "elbow": 0.1 for p in sides}
            | {p + "collar": 0.12 * max(e, 0.0) for p in sides}
        )
        t = _arm_move(c, t, [(u(0.7, 1.2) * tp, up), (u(0.1, 0.5), up)])
        t = _relax_after(c, t, u(0.7, 1.1) * tp, tuple(up))
    return t


def _front_raise(c: Choreo, t: float, rng: np.random.Generator) -> float:
    u, tp = rng.uniform, c.style.tempo
    sides = _sides(rng)
    f = u(1.3, 2.9)
    up = {p + "f": f for p in sides} | {p + "e": -1.5 for p in sides} | {p + "elbow": 0.1 for p in sides}
    up["spine_flex"] = -0.06 * f
    t = _arm_move(c, t, [(u(0.8, 1.3) * tp, up), (u(0.2, 0.6), up)])
    return _relax_after(c, t, u(0.8, 1.2) * tp, tuple(up))


def _wave(c: Choreo, t: float, rng: np.random.Generator) -> float:
    u, tp = rng.uniform, c.style.tempo
    p = "l_" if rng.random() < 0.5 else "r_"
    lean = 0.08 if p == "r_" else -0.08
    up = {
        p + "f": u(0.0, 0.4),
        p + "e": u(-0.1, 0.5),
        p + "tw": -u(1.2, 1.6),
        p + "elbow": u(1.3, 1.8),
        "spine_lat": lean,
        "head_lat": lean,
    }
    t_up = _arm_move(c, t, [(u(0.5, 0.8) * tp, up)])
    hold = u(1.5, 3.0)
    c.key(t_up + hold, **up)
    c.osc({p + "elbow": u(0.25, 0.45)}, u(1.5, 2.5), t_up - 0.1, t_up + hold, ramp=0.25)
    return _relax_after(c, t_up + hold, u(0.6, 0.9) * tp, tuple(up))


def _overhead_wave(c: Choreo, t: float, rng: np.random.Generator) -> float:
    u, tp = rng.uniform, c.style.tempo
    e = u(1.0, 1.4)
    up = {"l_e": e, "r_e": e, "l_elbow": 0.3, "r_elbow": 0.3, "l_collar": 0.15, "r_collar": 0.15}
    t_up = _arm_move(c, t, [(u(0.8, 1.1) * tp, up)])
    hold, freq = u(2.0, 3.5), u(0.6, 1.0)
    c.key(t_up + hold, **up)
    c.osc({"spine_lat": u(0.06, 0.12), "l_e": -0.25, "r_e": 0.25}, freq, t_up - 0.2, t_up + hold, ramp=0.5)
    return _relax_after(c, t_up + hold, u(0.8, 1.1) * tp, tuple(up))


def _arm_circles(c: Choreo, t: float, rng: np.random.Generator) -> float:
    u, tp = rng.uniform, c.style.tempo
    e = u(-0.2, 0.1)
    out = {"l_e": e, "r_e": e, "l_elbow": 0.05, "r_elbow": 0.05}
    t_out = _arm_move(c, t, [(u(0.7, 1.0) * tp, out)])
    hold, amp, freq, turn = u(2.0, 3.5), u(0.25, 0.45), u(0.8, 1.3), rng.choice([-0.5, 0.5]) * np.pi
    c.key(t_out + hold, **out)
    c.osc({"l_f": amp, "r_f": amp}, freq, t_out - 0.1, t_out + hold, ramp=0.4)
    c.osc({"l_e": amp, "r_e": amp}, freq, t_out - 0.1, t_out + hold, ramp=0.4, phase=turn)
    return _relax_after(c, t_out + hold, u(0.7, 1.0) * tp, tuple(out))


def _reach(c: Choreo, t: float, rng: np.random.Generator) -> float:
    u, tp = rng.uniform, c.style.tempo
    p = "l_" if rng.random() < 0.5 else "r_"
    sign = 1.0 if p == "l_" else -1.0
    out = {
        p + "f": u(1.8, 2.6),
        p + "e": -1.0,
        p + "elbow": 0.15,
        "spine_twist": -sign * u(0.15, 0.35),
        "spine_lat": sign * u(0.05, 0.15),
        "v": -sign * 0.03 * c.rig.scale,
    }
    t = _arm_move(c, t, [(u(0.8, 1.2) * tp, out), (u(0.3, 0.8), out)])
    return _relax_after(c, t, u(0.8, 1.1) * tp, tuple(out))


def _stretch(c: Choreo, t: float, rng: np.random.Generator) -> float:
    u, tp = rng.uniform, c.style.tempo
    up = {"l_f": 2.9, "r_f": 2.9, "l_e": -1.45, "r_e": -1.45, "l_elbow": 0.1, "r_elbow": 0.1, "spine_flex": -0.08}
    bend = u(0.15, 0.3)
    poses = [
        (u(0.8, 1.2) * tp, up),
        (u(0.8, 1.2) * tp, up | {"spine_lat": bend}),
        (u(1.0, 1.4) * tp, up | {"spine_lat": -bend}),
        (u(0.8, 1.1) * tp, up | {"spine_lat": 0.0}),
    ]
    t = _arm_move(c, t, poses)
    return _relax_after(c, t, u(0.8, 1.1) * tp, tuple(poses[1][1]))


#: Arm gestures with their longest duration: (seconds times the style's tempo, fixed seconds).
_GESTURES: dict[Callable[[Choreo, float, np.random.Generator], float], tuple[float, float]] = {
    _lateral_raise: (4.6, 1.0),
    _front_raise: (2.5, 0.6),
    _wave: (1.7, 3.0),
    _overhead_wave: (2.2, 3.5),
    _arm_circles: (2.0, 3.5),
    _reach: (2.3, 0.8),
    _stretch: (6.0, 0.0),
}


def build_martial(
    rig: BodyRig, style: Style, rng: np.random.Generator, anchor: Anchor, duration: float, area: Area
) -> PostureClip:
    """Step into a fighting stance with a guard; jabs, crosses, hooks, uppercuts, front kicks, knees; step out."""
    c, s, tp, u = Choreo("martial", rig, style, anchor, duration), rig.scale, style.tempo, rng.uniform
    lead = 0 if rng.random() < 0.7 else 1
    rear, sign = 1 - lead, (1.0 if lead == 0 else -1.0)  # sign: +1 when the left side leads
    lp, rp = ("l_", "r_")[lead], ("l_", "r_")[rear]
    back, blade = u(0.3, 0.45) * s, u(0.35, 0.6)
    t0 = u(0.3, 0.6)
    feet = {
        lead: c.stance_foot(lead, np.zeros(2), 0.0) + np.array([0.05 * s, 0.0]),
        rear: c.stance_foot(rear, np.zeros(2), 0.0) + np.array([-back, -sign * 0.03 * s]),
    }
    c.step(rear, t0 + 0.1, t0 + 0.5, feet[rear], -sign * u(0.4, 0.7), lift=0.05)
    c.step(lead, t0 + 0.6, t0 + 0.8, feet[lead], -sign * u(0.1, 0.3), lift=0.02)
    guard = {
        "u": -0.45 * back,
        "z": -u(0.04, 0.09) * s,
        "twist": -sign * blade,
        "spine_twist": sign * 0.6 * blade,
        "head_twist": sign * 0.4 * blade,
        "head_flex": 0.12,
        "spine_flex": c.rest("spine_flex") + 0.05,
        lp + "f": u(0.7, 0.9),
        rp + "f": u(0.5, 0.7),
        lp + "e": -u(1.1, 1.3),
        rp + "e": -u(1.15, 1.35),
        lp + "elbow": u(1.8, 2.1),
        rp + "elbow": u(2.1, 2.4),
        lp + "tw": -0.3,
        rp + "tw": -0.3,
    }
    legs = tuple(f"{p}foot_{a}" for p in ("l_", "r_") for a in ("u", "v", "z", "pitch"))
    names = tuple(guard) + ("v", "pitch") + legs
    c.relax(t0, *names)
    c.key(t0 + 0.9, **guard)
    t = t0 + 0.9 + u(0.3, 0.6)
    fight_end = duration - 1.0  # then 0.9 s to step out
    punches = {"jab": _jab, "cross": _cross, "hook": _hook, "uppercut": _uppercut}
    while True:
        kind = rng.choice(["jab", "cross", "hook", "uppercut", "kick", "knee"], p=[0.28, 0.24, 0.12, 0.1, 0.16, 0.1])
        if t + _MARTIAL_TIME[kind] * tp > fight_end:
            break
        if kind in punches:
            strike, out = punches[kind](lp, rp, sign, blade, guard, s), 0.4 * _MARTIAL_TIME[kind] * tp
            c.hold(t, *strike)
            c.key(t + out, **strike)
            c.key(t + _MARTIAL_TIME[kind] * tp, **{n: guard.get(n, c.rest(n)) for n in strike})
        else:
            _kick(c, t, kind, rear if rng.random() < 0.6 else lead, feet, guard, rng)
        t = min(t + _MARTIAL_TIME[kind] * tp + u(0.2, 0.7) * tp, fight_end)
    c.osc({"z": u(0.01, 0.025) * s}, u(1.6, 2.4), t0 + 0.9, t, ramp=0.4)
    t = max(t, t0 + 1.2)
    c.hold(t, *names)
    c.relax(t + 0.9, *names)
    c.step(lead, t + 0.1, t + 0.3, c.stance_foot(lead, np.zeros(2), 0.0), 0.0, lift=0.02)
    c.step(rear, t + 0.4, t + 0.8, c.stance_foot(rear, np.zeros(2), 0.0), 0.0, lift=0.05)
    return c.build()


#: Duration (s, at tempo 1) of each martial-arts move; a punch strikes in its first 40 %.
_MARTIAL_TIME = {"jab": 0.4, "cross": 0.55, "hook": 0.55, "uppercut": 0.55, "kick": 1.2, "knee": 1.1}


def _jab(lp: str, rp: str, sign: float, blade: float, guard: dict[str, float], s: float) -> dict[str, float]:
    return {lp + "f": 1.5, lp + "e": -1.5, lp + "elbow": 0.08, lp + "tw": 0.2, "spine_twist": sign * 0.35 * blade}


def _cross(lp: str, rp: str, sign: float, blade: float, guard: dict[str, float], s: float) -> dict[str, float]:
    return {
        rp + "f": 1.5,
        rp + "e": -1.5,
        rp + "elbow": 0.08,
        rp + "tw": 0.2,
        "twist": sign * 0.05,
        "spine_twist": -sign * 0.1,
        "head_twist": 0.0,
        rp + "foot_pitch": 0.5,
    }


def _hook(lp: str, rp: str, sign: float, blade: float, guard: dict[str, float], s: float) -> dict[str, float]:
    return {lp + "f": 1.3, lp + "e": -0.35, lp + "elbow": 1.6, lp + "tw": -0.2, "spine_twist": -sign * 0.25}


def _uppercut(lp: str, rp: str, sign: float, blade: float, guard: dict[str, float], s: float) -> dict[str, float]:
    return {
        rp + "f": 1.7,
        rp + "e": -1.2,
        rp + "elbow": 1.7,
        "z": guard["z"] - 0.03 * s,
        "spine_twist": -sign * 0.1,
        "twist": -sign * 0.5 * blade,
    }


def _kick(
    c: Choreo,
    t: float,
    kind: str,
    side: int,
    feet: dict[int, np.ndarray],
    guard: dict[str, float],
    rng: np.random.Generator,
) -> None:
    """A front kick or a knee strike of leg ``side``: weight onto the other foot, chamber, strike, back down.

    Foot targets are placed relative to the kicking hip within the leg's reach.
    """
    rig, s, tp = c.rig, c.rig.scale, c.style.tempo
    p = ("l_", "r_")[side]
    pelvis = np.array([guard["u"], 0.0])
    pelvis = pelvis + 0.5 * (feet[1 - side] - pelvis)  # weight over the supporting foot
    hip = pelvis + np.array([0.0, (0.07 if side == 0 else -0.07) * s])
    hip_z = rig.neutral_height + guard["z"] - 0.09 * s
    reach = 0.9 * rig.reach(BodyRig.KNEE_SWING)[side]

    def ankle_at(forward: float, height: float) -> dict[str, float]:
        """Foot offsets putting the ankle ``forward`` of the hip, ``height`` above the ground."""
        return {
            p + "foot_u": hip[0] + forward - feet[side][0],
            p + "foot_v": hip[1] - feet[side][1],
            p + "foot_z": height - rig.ankle_height[side],
        }

    shift = {"u": pelvis[0], "v": pelvis[1], "pitch": -0.1}
    chamber = ankle_at(0.2 * s, hip_z - 0.42 * s) | {p + "foot_pitch": 0.3}
    c.hold(t, *shift, *chamber)
    c.key(t + 0.3 * tp, **shift)
    c.key(t + 0.55 * tp, **chamber)
    if kind == "kick":
        height = min(rng.uniform(0.45, 0.9) * s * c.style.energy, hip_z + 0.25 * s)
        forward = np.sqrt(max(reach**2 - (hip_z - height) ** 2, (0.2 * s) ** 2))
        c.key(t + 0.75 * tp, **ankle_at(forward, height), **{p + "foot_pitch": 0.6, "pitch": -0.25})
    else:
        c.key(t + 0.7 * tp, **ankle_at(0.12 * s, hip_z - 0.3 * s), **{"l_f": 1.0, "r_f": 1.0})
    c.key(t + 0.95 * tp, **chamber, pitch=-0.1, **{n: guard[n] for n in ("l_f", "r_f")})
    c.key(
        t + _MARTIAL_TIME[kind] * tp, **{n: c.rest(n) for n in chamber}, **{n: guard.get(n, c.rest(n)) for n in shift}
    )


def build_dance(
    rig: BodyRig, style: Style, rng: np.random.Generator, anchor: Anchor, duration: float, area: Area
) -> PostureClip:
    """Dance to a beat: step-touch, the twist, arm pumps, side sways, stepping turns, with a bounce."""
    c, s, u = Choreo("dance", rig, style, anchor, duration), rig.scale, rng.uniform
    beat = 60.0 / u(95.0, 128.0)
    t_start = u(0.4, 0.8)
    moves: dict[str, Callable[[Choreo, float, float, np.random.Generator], float]] = {
        "step_touch": _step_touch,
        "twist": _twist,
        "pump": _pump,
        "sway": _sway,
        "turn": _turn,
    }
    t = t_start
    while t + 9 * beat < duration - 0.5:
        t = moves[rng.choice(list(moves))](c, t, beat, rng)
    bounce = u(0.02, 0.04) * s  # the knees give on every beat: the pelvis bobs below its relaxed height
    c.key(t_start, z=0.0)
    c.key(t_start + beat, z=-bounce)
    c.key(max(t - beat, t_start + beat + 0.01), z=-bounce)
    c.key(t + 0.5 * beat, z=0.0)
    c.osc({"z": 0.5 * bounce}, 1.0 / beat, t_start, t, ramp=beat, phase=-0.5 * np.pi)
    return c.build()


def _step_touch(c: Choreo, t: float, beat: float, rng: np.random.Generator) -> float:
    w = rng.uniform(0.2, 0.4) * c.rig.scale
    clap = rng.random() < 0.5
    arm_names = ("l_f", "r_f", "l_e", "r_e", "l_elbow", "r_elbow")
    c.relax(t, "v", "twist", *arm_names)
    direction = 1.0 if rng.random() < 0.5 else -1.0
    for bar in range(2):
        for k, (side, target) in enumerate(((0, w), (1, w), (1, 0.0), (0, 0.0))):
            side = side if direction > 0 else 1 - side
            tb = t + (4 * bar + k) * beat
            uv = c.stance_foot(side, np.array([0.0, direction * target]), 0.0)
            c.step(side, tb + 0.05 * beat, tb + 0.6 * beat, uv, 0.0, lift=0.05)
            c.key(tb + 0.7 * beat, v=direction * w * (0.5, 1.0, 0.5, 0.0)[k], twist=direction * 0.12 * (1, 0, -1, 0)[k])
            if bar == 0 and k == 0:
                continue  # the arms join in from the second beat
            if clap:
                touch = k in (1, 3)
                c.key(
                    tb + 0.5 * beat,
                    **{n: (1.2 if touch else 0.5) for n in ("l_f", "r_f")},
                    l_e=-1.35,
                    r_e=-1.35,
                    l_elbow=1.3 if touch else 1.6,
                    r_elbow=1.3 if touch else 1.6,
                )
            else:
                up = k % 2 == 0
                c.key(
                    tb + 0.5 * beat,
                    l_f=1.2 if up else 0.2,
                    r_f=0.2 if up else 1.2,
                    l_e=-1.2,
                    r_e=-1.2,
                    l_elbow=1.7,
                    r_elbow=1.7,
                )
    t_end = t + 8 * beat
    c.relax(t_end, "v", "twist", *arm_names)
    return t_end


def _twist(c: Choreo, t: float, beat: float, rng: np.random.Generator) -> float:
    u = rng.uniform
    amp = u(0.25, 0.45) * c.style.energy
    pose = {"l_f": 0.6, "r_f": 0.6, "l_e": -1.1, "r_e": -1.1, "l_elbow": 1.6, "r_elbow": 1.6}
    c.relax(t, *pose)
    c.key(t + beat, **pose)
    c.key(t + 7 * beat, **pose)
    c.relax(t + 8 * beat, *pose)
    c.osc(
        {
            "twist": amp,
            "spine_twist": -0.8 * amp,
            "l_knee_out": 0.5 * amp,
            "r_knee_out": -0.5 * amp,
            "l_f": 0.3,
            "r_f": -0.3,
        },
        0.5 / beat,
        t + 0.5 * beat,
        t + 7.5 * beat,
        ramp=beat,
    )
    return t + 8 * beat


def _pump(c: Choreo, t: float, beat: float, rng: np.random.Generator) -> float:
    high, low = rng.uniform(2.5, 2.9), rng.uniform(1.7, 2.1)
    names = ("l_f", "r_f", "l_e", "r_e", "l_elbow", "r_elbow")
    c.relax(t, *names)
    for k in range(1, 8):
        left_up = k % 2 == 0
        c.key(
            t + (k + 0.5) * beat,
            l_f=high if left_up else low,
            r_f=low if left_up else high,
            l_e=-1.45,
            r_e=-1.45,
            l_elbow=0.3,
            r_elbow=0.3,
        )
    c.relax(t + 8.5 * beat, *names)
    c.osc({"head_flex": 0.1}, 1.0 / beat, t, t + 8 * beat, ramp=beat)
    return t + 8.5 * beat


def _sway(c: Choreo, t: float, beat: float, rng: np.random.Generator) -> float:
    u = rng.uniform
    pose = {"l_e": u(-0.9, -0.5), "r_e": u(-0.9, -0.5), "l_elbow": 0.5, "r_elbow": 0.5, "l_f": 0.3, "r_f": 0.3}
    c.relax(t, *pose)
    c.key(t + beat, **pose)
    c.key(t + 7 * beat, **pose)
    c.relax(t + 8 * beat, *pose)
    c.osc(
        {"v": u(0.03, 0.06) * c.rig.scale, "roll": -0.08, "spine_lat": 0.12, "l_e": 0.3, "r_e": -0.3},
        0.5 / beat,
        t + 0.5 * beat,
        t + 7.5 * beat,
        ramp=beat,
    )
    return t + 8 * beat


def _turn(c: Choreo, t: float, beat: float, rng: np.random.Generator) -> float:
    arms = {"l_e": -0.6, "r_e": -0.6, "l_elbow": 1.2, "r_elbow": 1.2, "l_f": 0.5, "r_f": 0.5}
    c.relax(t, *arms)
    c.key(t + beat, **arms)
    _stepping_turn(c, t, (1.0 if rng.random() < 0.5 else -1.0) * 2.0 * np.pi, 4, beat)
    c.relax(t + 4.5 * beat, *arms)
    return t + 4.5 * beat


def _stepping_turn(c: Choreo, t: float, angle: float, steps: int, step_time: float) -> float:
    """Turn on the spot by ``angle`` in ``steps`` equal steps of ``step_time`` each (both feet); returns the end."""
    uv = np.array([c.value("u", t), c.value("v", t)])
    yaw0 = c.value("yaw", t)
    c.hold(t, "yaw")
    first = 0 if angle > 0 else 1  # the foot on the inside of the turn leads
    for k in range(steps):
        yaw = yaw0 + angle * (k + 1) / steps
        tk = t + k * step_time
        c.key(tk + step_time, yaw=yaw)
        for j, side in enumerate((first, 1 - first)):
            lift, land = tk + (0.05 + 0.45 * j) * step_time, tk + (0.45 + 0.45 * j) * step_time
            c.step(side, lift, land, c.stance_foot(side, uv, yaw), yaw, lift=0.04)
    return t + steps * step_time


def build_turn(rig: BodyRig, style: Style, rng: np.random.Generator, anchor: Anchor, heading: float) -> PostureClip:
    """Turn on the spot, in steps of at most 60 degrees, to face ``heading`` (its duration follows)."""
    angle = float(wrap_angle(heading - anchor.heading))
    steps = int(np.ceil(abs(angle) / np.radians(60.0)))
    step_time = rng.uniform(0.5, 0.7) * style.tempo
    c = Choreo("turn", rig, style, anchor, steps * step_time + 0.4)
    _stepping_turn(c, 0.2, angle, steps, step_time)
    return c.build()
