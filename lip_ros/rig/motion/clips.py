"""Motion clips: what a clip is, and the choreography of in-place clips.

A clip is a stretch of motion in its own time ``tau`` in [0, duration] that
starts and ends in the performer's relaxed standing pose (so clips chain
smoothly) and returns a :class:`~lip_ros.rig.motion.posture.Drive` for any times.
In-place clips are choreographed with a :class:`Choreo`: eased keyframes and
oscillators on posture channels plus foot steps, built into a
:class:`PostureClip`. Walking and running are in :mod:`lip_ros.rig.motion.gait`,
the activities in :mod:`lip_ros.rig.motion.acts`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from lip_ros.rig.motion.posture import CHANNELS, YAW, BodyRig, Drive, FootPlan, U, V, Z, posture
from lip_ros.rig.motion.primitives import EasedKeys, Oscillator, rotate_2d, smoothstep, softplus

__all__ = ["Anchor", "Area", "Style", "Clip", "PostureClip", "Choreo", "plan_feet", "ENERGY_RANGE", "TEMPO_RANGE"]

#: The rig's performers' style: amplitude factor and duration factor (larger is slower), drawn uniformly.
ENERGY_RANGE = (0.8, 1.2)
TEMPO_RANGE = (0.85, 1.15)

_PLACEMENT = ("u", "v", "yaw")  # channels that may end away from zero (where the clip leaves the body)


@dataclass(frozen=True)
class Anchor:
    """Where a clip starts: pelvis ground position (2,) and heading (rad) in the ground frame."""

    xy: np.ndarray
    heading: float

    def to_world(self, uv: np.ndarray) -> np.ndarray:
        """(..., 2) points from the anchor's frame (forward, left) to the ground frame."""
        return self.xy + rotate_2d(uv, self.heading)


@dataclass(frozen=True)
class Area:
    """The capture area: a disc on the ground."""

    centre: np.ndarray  # (2,)
    radius: float

    def room(self, xy: np.ndarray) -> float:
        """How far ``xy`` (2,) is inside the area's rim."""
        return float(self.radius - np.linalg.norm(np.asarray(xy) - self.centre))


@dataclass(frozen=True)
class Style:
    """A performer's relaxed posture and how energetic and quick they move."""

    neutral: dict[str, float]  # absolute values of posture channels in the relaxed stance
    energy: float  # amplitude factor, about 1
    tempo: float  # duration factor, about 1 (larger is slower)

    @classmethod
    def draw(cls, rng: np.random.Generator, energy: tuple[float, float] = ENERGY_RANGE,
             tempo: tuple[float, float] = TEMPO_RANGE) -> Style:
        """A random style: relaxed posture, ``energy`` and ``tempo`` uniform in their ranges."""
        arm_e, arm_f, elbow = -rng.uniform(1.22, 1.38), rng.uniform(0.0, 0.12), rng.uniform(0.15, 0.35)
        neutral = {
            "l_e": arm_e,
            "r_e": arm_e + rng.normal(0.0, 0.03),
            "l_f": arm_f,
            "r_f": arm_f + rng.normal(0.0, 0.03),
            "l_elbow": elbow,
            "r_elbow": elbow + rng.normal(0.0, 0.04),
            "l_wrist": rng.uniform(-0.1, 0.15),
            "r_wrist": rng.uniform(-0.1, 0.15),
            "spine_flex": rng.uniform(-0.04, 0.1),
            "head_flex": rng.uniform(-0.08, 0.1),
        }
        return cls(neutral, float(rng.uniform(*energy)), float(rng.uniform(*tempo)))

    def rest(self, name: str) -> float:
        """Relaxed value of a posture channel."""
        return self.neutral.get(name, 0.0)

    def base(self) -> np.ndarray:
        """(POSTURE_SIZE,) posture vector of the relaxed stance."""
        return posture(self.neutral, 1)[0]


class Clip(Protocol):
    """A stretch of motion that starts and ends in the relaxed stance."""

    name: str
    duration: float
    end: Anchor  # where the body stands when the clip is over

    def drive(self, tau: np.ndarray) -> Drive:
        """The body at clip times ``tau`` (T,), in [0, duration]."""
        ...


def plan_feet(
    anchor: Anchor, plans: list[FootPlan], tau: np.ndarray
) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Footprint xy (world), yaw, swing height, roll pitch, airborne weight and ground (height, slope) of both
    feet, (T, 2[, 2])."""
    xy, yaw, height, pitch, airborne, ground = zip(*(plan.evaluate(tau) for plan in plans), strict=False)
    stack = [np.stack(a, 1) for a in (yaw, height, pitch, airborne, ground)]
    return [anchor.to_world(p) for p in xy], stack[0] + anchor.heading, stack[1], stack[2], stack[3], stack[4]


@dataclass
class _Plant:
    """A foot on a footprint (forward, left, yaw) from ``start`` to ``end``, then a swing ``lift`` high."""

    start: float
    end: float
    uv: np.ndarray
    yaw: float
    lift: float = 0.0


@dataclass
class PostureClip:
    """An in-place clip: posture channels from eased keys plus oscillators, feet from plans."""

    name: str
    duration: float
    rig: BodyRig
    anchor: Anchor
    base: np.ndarray  # (POSTURE_SIZE,) relaxed posture
    keys: dict[str, EasedKeys]  # offsets from the relaxed value
    oscillators: list[tuple[str, Callable[[np.ndarray], np.ndarray]]]  # added to the channels
    plans: list[FootPlan]
    follow: float | None = None  # feet leave the ground when the pelvis rises above this (jumps)
    end: Anchor = field(init=False)

    def __post_init__(self) -> None:
        t = np.array([self.duration])
        uv = np.array([[self.keys[c](t)[0] if c in self.keys else 0.0 for c in ("u", "v")]])
        yaw = self.keys["yaw"](t)[0] if "yaw" in self.keys else 0.0
        self.end = Anchor(self.anchor.to_world(uv)[0], self.anchor.heading + yaw)

    def drive(self, tau: np.ndarray) -> Drive:
        """The body at clip times ``tau``."""
        rig, n = self.rig, len(tau)
        channels: dict[str, np.ndarray] = {name: k(tau) for name, k in self.keys.items()}
        for name, osc in self.oscillators:
            channels[name] = channels.get(name, 0.0) + osc(tau)
        post = posture(channels, n, self.base)
        heading = self.anchor.heading + post[:, YAW]
        pelvis_xy = self.anchor.to_world(post[:, [U, V]])
        pelvis_z = rig.neutral_height + post[:, Z]
        fxy, fyaw, height, pitch, airborne, _ = plan_feet(self.anchor, self.plans, tau)  # on the flat ground
        ankles, toes = [], []
        for side, prefix in enumerate(("l_", "r_")):
            du, dv, dz = (post[:, CHANNELS[f"{prefix}foot_{a}"][0][0]] for a in "uvz")
            pitch[:, side] += post[:, CHANNELS[prefix + "foot_pitch"][0][0]]
            rise = height[:, side] + dz
            if self.follow is not None:  # airborne once the pelvis is higher than the legs reach
                tiptoe = rig.ankle_from_footprint(
                    side, np.zeros((n, 2)), np.zeros(n), np.zeros(n), pitch[:, side], True
                )
                rise = rise + softplus(
                    pelvis_z - self.follow - tiptoe[:, 2] + rig.ankle_height[side], 0.015 * rig.scale
                )
            xy = fxy[side] + rotate_2d(np.stack([du, dv], -1), heading)
            ankles.append(rig.ankle_from_footprint(side, xy, fyaw[:, side], rise, pitch[:, side]))
            toes.append(rig.toe_flat(pitch[:, side], rise))
            lifted = smoothstep((rise - height[:, side]) / (0.15 * rig.scale))  # kicks, knee raises, jumps
            airborne[:, side] = 1.0 - (1.0 - airborne[:, side]) * (1.0 - lifted)
        return Drive(pelvis_xy, pelvis_z, heading, post, np.stack(ankles, 1), fyaw, pitch, np.stack(toes, 1), airborne)


class Choreo:
    """Builder of a :class:`PostureClip`: absolute key values per channel, oscillators, foot steps.

    Channels (see ``lip_ros.rig.motion.posture.CHANNELS``) start at their relaxed
    value at time 0; each is eased from key to key independently. Placement
    (u, v forward/left of the anchor, yaw) may end anywhere, every other channel
    must end relaxed, and the feet must end in stance under the pelvis.
    """

    def __init__(self, name: str, rig: BodyRig, style: Style, anchor: Anchor, duration: float) -> None:
        self.name, self.rig, self.style, self.anchor, self.duration = name, rig, style, anchor, float(duration)
        self._keys: dict[str, dict[float, float]] = {}
        self._oscillators: list[tuple[str, Callable[[np.ndarray], np.ndarray]]] = []
        self._plants = [[_Plant(-np.inf, np.inf, rig.neutral_feet[side].copy(), 0.0)] for side in range(2)]
        self.follow: float | None = None

    def rest(self, name: str) -> float:
        """Relaxed value of a channel."""
        return self.style.rest(name)

    def value(self, name: str, t: float) -> float:
        """The channel's value at ``t`` from the keys so far (its last key at or before ``t``)."""
        keys = self._keys.get(name, {})
        earlier = [k for k in keys if k <= t]
        return keys[max(earlier)] if earlier else self.rest(name)

    def key(self, t: float, **values: float) -> None:
        """Key channels at time ``t`` (within the clip) to absolute ``values``."""
        if not -1e-9 <= t <= self.duration + 1e-9:
            raise ValueError(f"{self.name}: key at {t:.3f} s outside the clip (0 .. {self.duration:.3f} s)")
        t = min(max(round(t, 6), 0.0), self.duration)
        for name, v in values.items():
            if name not in CHANNELS:
                raise KeyError(f"unknown posture channel {name!r}")
            self._keys.setdefault(name, {})[round(t, 6)] = float(v)

    def hold(self, t: float, *names: str) -> None:
        """Key channels at ``t`` to the values they already have there (a hold before a move)."""
        self.key(t, **{name: self.value(name, t) for name in names})

    def relax(self, t: float, *names: str) -> None:
        """Key channels at ``t`` back to their relaxed values."""
        self.key(t, **{name: self.rest(name) for name in names})

    def osc(
        self, amps: dict[str, float], freq: float, t_on: float, t_off: float, ramp: float = 0.3, phase: float = 0.0
    ) -> None:
        """Add oscillations ``amp * sin(...)`` to channels over [t_on, t_off] (faded over ``ramp``)."""
        for name, amp in amps.items():
            self._oscillators.append((name, Oscillator(amp, freq, t_on, t_off, ramp, phase)))

    def add(self, name: str, curve: Callable[[np.ndarray], np.ndarray]) -> None:
        """Add ``curve(t)`` (zero outside the clip's own window, smooth) to a channel."""
        if name not in CHANNELS:
            raise KeyError(f"unknown posture channel {name!r}")
        self._oscillators.append((name, curve))

    def stance_foot(self, side: int, uv: np.ndarray, yaw: float) -> np.ndarray:
        """Footprint (forward, left) of a foot in stance under a pelvis at ``uv`` facing ``yaw``."""
        return np.asarray(uv, dtype=np.float64) + rotate_2d(self.rig.neutral_feet[side], yaw)

    def foot(self, side: int) -> tuple[np.ndarray, float]:
        """Footprint (forward, left) and yaw of a foot's last plant."""
        last = self._plants[side][-1]
        return last.uv, last.yaw

    def step(
        self,
        side: int,
        t_lift: float,
        t_land: float,
        uv: np.ndarray,
        yaw: float,
        lift: float = 0.06,
    ) -> None:
        """Lift a foot at ``t_lift`` and plant it flat at ``t_land`` on footprint ``uv`` (forward, left) with
        ``yaw``; it swings ``lift`` (times the body scale) high.
        """
        last = self._plants[side][-1]
        if not last.start < t_lift < t_land:
            raise ValueError("steps of a foot must follow each other")
        last.end, last.lift = t_lift, lift * self.rig.scale
        self._plants[side].append(_Plant(t_land, np.inf, np.asarray(uv, dtype=np.float64), yaw))

    def build(self) -> PostureClip:
        """The finished clip (checks that it ends relaxed, feet under the pelvis)."""
        keys = {}
        for name, by_time in self._keys.items():
            by_time = {0.0: self.rest(name), **by_time}
            t = np.array(sorted(by_time))
            values = np.array([by_time[k] for k in t]) - self.rest(name)
            if name not in _PLACEMENT and abs(values[-1]) > 1e-9:
                raise ValueError(f"{self.name}: channel {name} does not end relaxed")
            keys[name] = EasedKeys(t, values)
        if any(isinstance(osc, Oscillator) and osc.t_off > self.duration for _, osc in self._oscillators):
            raise ValueError(f"{self.name}: an oscillation outlasts the clip")
        end = np.array([self.value(c, self.duration) for c in ("u", "v")])
        end_yaw = self.value("yaw", self.duration)
        for side in range(2):
            uv, yaw = self.foot(side)
            if not np.allclose(uv, self.stance_foot(side, end, end_yaw), atol=1e-6):
                raise ValueError(f"{self.name}: feet do not end in stance")
        plans = [self._plan(side) for side in range(2)]
        return PostureClip(
            self.name,
            self.duration,
            self.rig,
            self.anchor,
            self.style.base(),
            keys,
            self._oscillators,
            plans,
            self.follow,
        )

    def _plan(self, side: int) -> FootPlan:
        plants = self._plants[side]

        def col(attr: str) -> np.ndarray:
            return np.array([getattr(p, attr) for p in plants], dtype=np.float64)

        flat, ones = np.zeros(len(plants)), np.ones(len(plants))  # feet roll with the pitch channels instead
        uv, lift = np.array([p.uv for p in plants]), col("lift")
        return FootPlan(col("start"), col("end"), uv, col("yaw"), lift, flat, ones, flat, ones, clearance=flat)
