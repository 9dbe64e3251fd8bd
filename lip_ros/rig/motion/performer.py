"""Procedural full-body motion of one performer: the synthetic rig's stand-in for mocap captures.

``make_motion`` builds a :class:`PerformerMotion` (a ``Trajectory``): a
continuous-time, deterministic, C1/C2-smooth pose of the contract skeleton in
the LiDAR frame L. Every capture starts with the contract's calibration: the
performer stands still at the area's centre facing the LiDAR, in A-pose, then
in T-pose, then eases into the scenario. Scenarios are single activities
(walk, run, jump, squat, arms, martial, dance) or a ``mixed`` chain of them;
all stay inside a disc of ``area_radius`` around the centre. The phase windows
(:class:`Phase`) tell tests and tools what was done when.

What the performer does comes from :mod:`lip_ros.rig.motion.gait` and
:mod:`lip_ros.rig.motion.acts` (on the clip framework of
:mod:`lip_ros.rig.motion.clips`), how the body is posed from
:mod:`lip_ros.rig.motion.posture`, the smooth curves from
:mod:`lip_ros.rig.motion.primitives`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import gaussian_filter1d, minimum_filter1d

from lip_ros.core.frames import R_L_M_FACING_X
from lip_ros.core.rotations import axis_angle_to_matrix, matrix_to_axis_angle, rot_z
from lip_ros.core.skeleton import Skeleton, load_skeleton
from lip_ros.rig.motion.acts import (
    build_arms,
    build_dance,
    build_jump,
    build_martial,
    build_squat,
    build_sync_jump,
    build_turn,
)
from lip_ros.rig.motion.clips import ENERGY_RANGE, TEMPO_RANGE, Anchor, Area, Clip, Style
from lip_ros.rig.motion.gait import GaitClip
from lip_ros.rig.motion.posture import BodyRig
from lip_ros.rig.motion.primitives import RoutePath, smoothstep, wrap_angle
from lip_ros.rig.terrain import ROUTE_RADIUS_M, Terrain
from lip_ros.rig.trajectory import BodyPose

__all__ = [
    "SCENARIOS",
    "ACTIVITIES",
    "MIN_DURATION",
    "Phase",
    "PerformerMotion",
    "make_motion",
    "random_scenario",
    "random_motion",
    "calibration_duration",
    "make_site_motion",
]

#: Single activities, each also a scenario.
ACTIVITIES = ("walk", "run", "jump", "squat", "arms", "martial", "dance")
#: Scenario names accepted by ``make_motion``.
SCENARIOS = ACTIVITIES + ("mixed",)
#: Shortest time (s) each activity needs after the calibration.
MIN_DURATION = {"walk": 5.0, "run": 6.0, "jump": 4.5, "squat": 7.0, "arms": 6.0, "martial": 6.0, "dance": 7.0}
MIN_DURATION["mixed"] = min(MIN_DURATION.values())

_BUILDERS: dict[str, Callable[[BodyRig, Style, np.random.Generator, Anchor, float, Area], Clip]] = {
    "walk": lambda *args: GaitClip(*args, run=False),
    "run": lambda *args: GaitClip(*args, run=True),
    "jump": build_jump,
    "squat": build_squat,
    "arms": build_arms,
    "martial": build_martial,
    "dance": build_dance,
}
_CALIBRATION = (("a_pose", 2.3, 3.0), ("a_to_t", 0.8, 1.2), ("t_pose", 2.3, 3.0), ("to_motion", 0.6, 1.0))
_GAP = (0.3, 0.6)  # s between clips of a mixed scenario
_SCENARIO_WEIGHTS = {"mixed": 0.3} | {a: 0.1 for a in ACTIVITIES}


@dataclass(frozen=True)
class Phase:
    """A named window of the capture: [t_start, t_end] seconds."""

    name: str
    t_start: float
    t_end: float


class _Piece(Protocol):
    duration: float

    def pose(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pelvis positions (T, 3) in the ground frame and local rotations (T, 24, 3, 3)."""
        ...


@dataclass
class _Hold:
    """One pose, held."""

    duration: float
    root: np.ndarray  # (3,)
    local: np.ndarray  # (24, 3, 3)

    def pose(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(tau)
        return np.tile(self.root, (n, 1)), np.tile(self.local, (n, 1, 1, 1))

    def first(self) -> tuple[np.ndarray, np.ndarray]:
        """The pose at the start."""
        return self.root, self.local

    last = first


class _SwayingHold(_Hold):
    """One pose, held by a wearer who sways: the body turned about the world's x, y and z through ``pivot`` (3,),
    a point on the ground between the feet (so that the feet stay put and the pelvis moves, as a sway about the
    ankles), by ``amplitude_rad`` (3,) times a sine of ``freq_hz`` (3,) from ``phase`` (3,). The sway fades in
    over the first ``_EASE_S`` (it begins as the pose, at rest) and slows to rest over the last ``_EASE_S`` where
    it has got to (:meth:`last`), not turned back, so that the rates are continuous into what follows."""

    _EASE_S = 0.5

    def __init__(self, duration: float, root: np.ndarray, local: np.ndarray, pivot: np.ndarray,
                 amplitude_rad: np.ndarray, freq_hz: np.ndarray, phase: np.ndarray) -> None:
        super().__init__(duration, root, local)
        self.pivot, self.amplitude_rad, self.freq_hz, self.phase = pivot, amplitude_rad, freq_hz, phase

    def pose(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        root, local = super().pose(tau)
        ease = self._EASE_S
        fade = smoothstep(tau / ease)[:, None]
        # the sway's own clock, slowing to a stop at the end: d(clock)/d(tau) = 1 - smoothstep over the last ease
        u = np.clip((tau - (self.duration - ease)) / ease, 0.0, 1.0)
        clock = np.minimum(tau, self.duration - ease) + ease * (u - 2.5 * u**4 + 3.0 * u**5 - u**6)
        angles = self.amplitude_rad * np.sin(2.0 * np.pi * self.freq_hz * clock[:, None] + self.phase) * fade
        turn = axis_angle_to_matrix(angles)
        local[:, 0] = turn @ local[:, 0]
        root = self.pivot + np.einsum("nab,nb->na", turn, root - self.pivot)
        return root, local

    def last(self) -> tuple[np.ndarray, np.ndarray]:
        """The pose at the end."""
        root, local = self.pose(np.array([self.duration]))
        return root[0], local[0]


@dataclass
class _Gap:
    """A transition still to be made: a blend from the pose before it to the pose after it."""

    duration: float


class _Blend:
    """Eased (quintic) transition between two poses: pelvis interpolated, joints slerped."""

    def __init__(
        self, duration: float, start: tuple[np.ndarray, np.ndarray], end: tuple[np.ndarray, np.ndarray]
    ) -> None:
        self.duration = duration
        self._root0, self._local0 = start
        self._droot = end[0] - start[0]
        self._rotvec = matrix_to_axis_angle(np.swapaxes(start[1], -1, -2) @ end[1])  # (24, 3)

    def pose(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = smoothstep(tau / self.duration)
        return self._root0 + w[:, None] * self._droot, self._local0 @ axis_angle_to_matrix(
            w[:, None, None] * self._rotvec
        )


class _Play:
    """A clip, posed by the body rig.

    Where a planted foot would be out of reach the pelvis must come down; that
    lowering is planned ahead over the whole clip (the reach deficit on a grid,
    widened and smoothed, as a spline) so that the pelvis eases down in time
    instead of being pulled at the last moment.
    """

    _GRID = 0.01  # s
    _WIDEN = 0.2  # s, window of the minimum filter
    _SMOOTH = 0.05  # s, sigma of the Gaussian

    def __init__(self, clip: Clip, rig: BodyRig) -> None:
        self.clip, self.rig, self.duration = clip, rig, clip.duration
        t = np.linspace(0.0, clip.duration, int(np.ceil(clip.duration / self._GRID)) + 1)
        drive = clip.drive(t)
        deficit = np.minimum(rig.reach_limit(drive) - drive.pelvis_z, 0.0)
        step = t[1] - t[0]
        deficit = minimum_filter1d(deficit, int(round(self._WIDEN / step)) | 1, mode="nearest")
        self._lower = CubicSpline(t, gaussian_filter1d(deficit, self._SMOOTH / step, mode="nearest"), bc_type="clamped")

    def pose(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tau = np.clip(tau, 0.0, self.duration)
        drive = self.clip.drive(tau)
        drive.pelvis_z = drive.pelvis_z + self._lower(tau)
        return self.rig.solve(drive)

    def first(self) -> tuple[np.ndarray, np.ndarray]:
        """The pose at the start."""
        root, local = self.pose(np.zeros(1))
        return root[0], local[0]

    def last(self) -> tuple[np.ndarray, np.ndarray]:
        """The pose at the end."""
        root, local = self.pose(np.array([self.duration]))
        return root[0], local[0]


class PerformerMotion:
    """A performer's motion over a capture (implements ``lip_ros.rig.trajectory.Trajectory``).

    ``sample(t)`` is continuous in time, vectorised and deterministic; times
    outside [0, duration] hold the first or last pose.
    """

    def __init__(
        self,
        skeleton: Skeleton,
        scenario: str,
        pieces: list[tuple[str, _Piece]],
        lidar_height: float,
        centre: np.ndarray,
        area_radius: float,
    ) -> None:
        self.skeleton = skeleton
        self.scenario = scenario
        self.lidar_height = float(lidar_height)
        self.centre = np.asarray(centre, dtype=np.float64)
        self.area_radius = float(area_radius)
        self._pieces = [p for _, p in pieces]
        ends = np.cumsum([p.duration for p in self._pieces])
        self._starts = np.concatenate([[0.0], ends[:-1]])
        self.duration = float(ends[-1])
        #: the capture's phase windows, in order (calibration, transitions, activities)
        self.phases = [
            Phase(name, float(a), float(b)) for (name, _), a, b in zip(pieces, self._starts, ends, strict=False)
        ]

    def phase(self, name: str) -> Phase:
        """The first phase called ``name``."""
        for p in self.phases:
            if p.name == name:
                return p
        raise KeyError(f"no phase {name!r} in this motion")

    def sample(self, t: np.ndarray) -> BodyPose:
        """Poses at times ``t`` (T,) seconds since the capture started: pelvis in L, local rotations."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=np.float64)), 0.0, self.duration)
        which = np.clip(np.searchsorted(self._starts, t, side="right") - 1, 0, len(self._pieces) - 1)
        root = np.empty((len(t), 3))
        local = np.empty((len(t), 24, 3, 3))
        for i in np.unique(which):
            m = which == i
            root[m], local[m] = self._pieces[i].pose(t[m] - self._starts[i])
        root[:, 2] -= self.lidar_height
        return BodyPose(root, local)


def calibration_duration(seed: int) -> float:
    """How long the calibration (A-pose, T-pose, transition) of ``make_motion(seed=seed)`` lasts."""
    rng = np.random.default_rng([seed, 1])
    return float(sum(rng.uniform(lo, hi) for _, lo, hi in _CALIBRATION))


def _calibration(rig: BodyRig, seed: int, anchor: Anchor) -> list[tuple[str, _Hold | _Blend | _Gap]]:
    rng = np.random.default_rng([seed, 1])
    (a_name, *a), (at_name, *at), (t_name, *tt), (to_name, *to) = _CALIBRATION
    root = np.array([anchor.xy[0], anchor.xy[1], rig.stand_height])
    a_pose, t_pose = rig.skeleton.pose_local_rotations("a_pose"), rig.skeleton.pose_local_rotations("t_pose")
    a_pose[0] = t_pose[0] = rot_z(anchor.heading) @ R_L_M_FACING_X
    return [
        (a_name, _Hold(rng.uniform(*a), root, a_pose)),
        (at_name, _Blend(rng.uniform(*at), (root, a_pose), (root, t_pose))),
        (t_name, _Hold(rng.uniform(*tt), root, t_pose)),
        (to_name, _Gap(rng.uniform(*to))),
    ]


def _plan_activities(scenario: str, budget: float, rng: np.random.Generator,
                     activities: tuple[str, ...] = ACTIVITIES) -> list[tuple[str, float]]:
    """Activities and their durations filling ``budget`` seconds (gaps between them excluded); a ``mixed``
    scenario chains some of ``activities``."""
    if scenario != "mixed":
        return [(scenario, budget)]
    fitting = [a for a in activities if MIN_DURATION[a] <= budget]
    if not fitting:
        raise ValueError(f"none of {activities} fits in {budget:.1f} s")
    count = int(np.clip(budget // 10.0, 1, 6))
    while True:
        names: list[str] = []
        while len(names) < count:
            name = fitting[rng.integers(len(fitting))]
            if not names or name != names[-1]:
                names.append(name)
        gaps = rng.uniform(*_GAP, size=count - 1)
        free = budget - gaps.sum() - sum(MIN_DURATION[n] for n in names)
        if free >= 0.0 or count == 1:
            break
        count -= 1
    weights = np.array([1.8 if n in ("walk", "run") else 1.0 for n in names]) * rng.uniform(0.7, 1.3, size=count)
    durations = [MIN_DURATION[n] + max(free, 0.0) * w / weights.sum() for n, w in zip(names, weights, strict=False)]
    plan: list[tuple[str, float]] = []
    for k, (name, d) in enumerate(zip(names, durations, strict=False)):
        plan.append((name, d))
        if k < count - 1:
            plan.append(("transition", float(gaps[k])))
    return plan


def make_motion(
    scenario: str,
    duration_s: float,
    seed: int,
    centre: np.ndarray,
    lidar_height: float,
    area_radius: float = 3.0,
    body_scale: float | None = None,
    calibration: bool = True,
    skeleton: Skeleton | None = None,
    facing_deg: float = 0.0,
    activities: tuple[str, ...] = ACTIVITIES,
    energy: tuple[float, float] = ENERGY_RANGE,
    tempo: tuple[float, float] = TEMPO_RANGE,
) -> PerformerMotion:
    """A performer's motion: calibration (optional) then ``scenario`` for ``duration_s`` seconds in all.

    ``centre`` (3,) (or (2,)) is the middle of the capture area in L (its z is
    ignored: the performer stands on the ground at z = -lidar_height);
    ``body_scale`` multiplies ``skeleton`` (default: the contract's; random in [0.9, 1.1] if
    None); the performer starts (and calibrates) facing the LiDAR turned by
    ``facing_deg`` (counter-clockwise seen from above); a ``mixed`` scenario chains some of ``activities``;
    the style's ``energy`` (amplitude factor) and ``tempo`` (duration factor) are drawn from their ranges.
    Same arguments, same motion.
    """
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; choose from {SCENARIOS}")
    rng = np.random.default_rng([seed, 0])
    scale = float(rng.uniform(0.9, 1.1)) if body_scale is None else float(body_scale)
    rig = BodyRig((skeleton or load_skeleton()).scaled(scale))
    style = Style.draw(np.random.default_rng([seed, 2]), energy, tempo)
    centre_xy = np.asarray(centre, dtype=np.float64)[:2]
    area = Area(centre_xy, float(area_radius))
    if area.radius < 0.8 * scale:
        raise ValueError("area_radius is too small for a performer")
    anchor = Anchor(centre_xy, float(np.arctan2(-centre_xy[1], -centre_xy[0]) + np.radians(facing_deg)))
    plan = _calibration(rig, seed, anchor) if calibration else []
    budget = duration_s - sum(p.duration for _, p in plan)
    if budget < MIN_DURATION[scenario]:
        raise ValueError(
            f"{scenario} needs duration_s >= {np.ceil(10 * (MIN_DURATION[scenario] + duration_s - budget)) / 10:.1f} s"
        )
    for k, (name, d) in enumerate(_plan_activities(scenario, budget, np.random.default_rng([seed, 3]), activities)):
        if name == "transition":
            plan.append((name, _Gap(d)))
            continue
        rng = np.random.default_rng([seed, 10 + k])
        heading = _loop_heading(anchor, area) if name in ("walk", "run") else None
        if heading is not None:  # turn first: no room for a loop ahead
            turn = build_turn(rig, style, rng, anchor, heading)
            plan.append(("turn", _Play(turn, rig)))
            anchor, d = turn.end, d - turn.duration
        clip = _BUILDERS[name](rig, style, rng, anchor, d, area)
        plan.append((name, _Play(clip, rig)))
        anchor = clip.end
    pieces = [
        (name, _Blend(p.duration, plan[k - 1][1].last(), plan[k + 1][1].first()) if isinstance(p, _Gap) else p)
        for k, (name, p) in enumerate(plan)
    ]
    return PerformerMotion(rig.skeleton, scenario, pieces, lidar_height, centre_xy, area.radius)


def _a_pose_hold(duration: float, root: np.ndarray, local: np.ndarray, ground: float, sway_deg: float,
                 rng: np.random.Generator) -> _Hold:
    """The A-pose held perfectly still, or swaying by up to ``sway_deg`` about each axis through the ground at
    ``ground`` under the pelvis (:class:`_SwayingHold`)."""
    if sway_deg <= 0.0:
        return _Hold(duration, root, local)
    pivot = np.array([root[0], root[1], ground])
    return _SwayingHold(duration, root, local, pivot, np.deg2rad(sway_deg) * rng.uniform(0.5, 1.0, 3),
                        rng.uniform(0.2, 0.5, 3), rng.uniform(0.0, 2.0 * np.pi, 3))


def make_site_motion(
    terrain: Terrain, duration_s: float, seed: int, body_scale: float | None = None, skeleton: Skeleton | None = None,
    sway_deg: float = 0.0,
) -> PerformerMotion:
    """A performer who carries the sensors through a site (the HSC4D capture), in the world frame W of
    ``terrain``: standing still in A-pose at the start of the site's route, one vertical jump in place with a
    ballistic flight (the sync event), then walking the route over the terrain (stairs, ramp) for the rest
    of ``duration_s``. Phases: ``a_pose``, ``jump``, ``walk`` (and the transitions between them). ``sway_deg``
    > 0: a wearer who sways in the A-pose instead of standing perfectly still, the body turning about each world
    axis through the ground between the feet by up to that much at 0.2-0.5 Hz (a variant; the seed's other draws
    are unchanged)."""
    rng = np.random.default_rng([seed, 0])
    scale = float(rng.uniform(0.9, 1.1)) if body_scale is None else float(body_scale)
    rig = BodyRig((skeleton or load_skeleton()).scaled(scale))
    style = Style.draw(np.random.default_rng([seed, 2]))
    start, corners = terrain.route()
    route = RoutePath(start, corners, ROUTE_RADIUS_M)
    anchor = Anchor(start, float(route.at(np.zeros(1))[1][0]))
    rng = np.random.default_rng([seed, 1])
    a_pose = rig.skeleton.pose_local_rotations("a_pose")
    a_pose[0] = rot_z(anchor.heading) @ R_L_M_FACING_X
    ground = float(terrain.surface_height(start[None])[0])
    plan: list[tuple[str, _Piece | _Gap]] = [
        ("a_pose", _a_pose_hold(rng.uniform(2.3, 3.0), np.array([*start, rig.stand_height + ground]), a_pose,
                                ground, sway_deg, np.random.default_rng([seed, 3]))),
        ("to_jump", _Gap(rng.uniform(0.6, 1.0))),
        ("jump", _Play(build_sync_jump(rig, style, rng, anchor), rig)),
        ("to_walk", _Gap(rng.uniform(0.3, 0.6))),
    ]
    budget = duration_s - sum(p.duration for _, p in plan)
    if budget < MIN_DURATION["walk"]:
        raise ValueError(f"a site capture needs duration_s >= {duration_s - budget + MIN_DURATION['walk']:.1f} s")
    walk = GaitClip(rig, style, np.random.default_rng([seed, 10]), anchor, budget, None, run=False, route=route,
                    surface=terrain.surface_height)
    plan.append(("walk", _Play(walk, rig)))
    pieces = [
        (name, _Blend(p.duration, plan[k - 1][1].last(), plan[k + 1][1].first()) if isinstance(p, _Gap) else p)
        for k, (name, p) in enumerate(plan)
    ]
    return PerformerMotion(rig.skeleton, "site_walk", pieces, 0.0, start, float(np.inf))


def _loop_heading(anchor: Anchor, area: Area) -> float | None:
    """The heading to turn to before walking a loop from the anchor, or None if the body may start as it faces.

    Well off the centre a loop fits only heading roughly along the rim, not outwards: then the
    body turns to the nearer direction along the rim.
    """
    offset = anchor.xy - area.centre
    distance = np.linalg.norm(offset)
    outward = np.arctan2(offset[1], offset[0])
    if distance < 0.3 * area.radius or abs(wrap_angle(anchor.heading - outward)) > np.radians(70.0):
        return None
    return float(outward + np.copysign(0.5 * np.pi, wrap_angle(anchor.heading - outward)))


def random_scenario(rng: np.random.Generator, activities: tuple[str, ...] = ACTIVITIES) -> str:
    """A scenario drawn for training data: ``mixed`` most often, else one of ``activities``."""
    names = [n for n in _SCENARIO_WEIGHTS if n == "mixed" or n in activities]
    w = np.array([_SCENARIO_WEIGHTS[n] for n in names])
    return names[rng.choice(len(names), p=w / w.sum())]


def random_motion(
    seed: int,
    duration_s: float,
    centre: np.ndarray,
    lidar_height: float,
    area_radius: float = 3.0,
    calibration: bool = True,
    body_scale: float | None = None,
    skeleton: Skeleton | None = None,
    activities: tuple[str, ...] = ACTIVITIES,
    energy: tuple[float, float] = ENERGY_RANGE,
    tempo: tuple[float, float] = TEMPO_RANGE,
) -> PerformerMotion:
    """``make_motion`` with a scenario drawn from ``seed`` among ``activities`` (and ``mixed`` of them), and the
    body scale unless given (training data)."""
    scenario = random_scenario(np.random.default_rng([seed, 4]), activities)
    budget = duration_s - (calibration_duration(seed) if calibration else 0.0)
    if budget < MIN_DURATION[scenario]:
        scenario = "mixed"
    return make_motion(scenario, duration_s, seed, centre, lidar_height, area_radius, body_scale, calibration,
                       skeleton, activities=activities, energy=energy, tempo=tempo)
