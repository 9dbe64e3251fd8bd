"""Walking and running on closed loops through the capture area, with start, stop and turns, or along a route
over terrain (stairs, ramps)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import gaussian_filter1d, minimum_filter1d

from lip_ros.core.frames import GRAVITY
from lip_ros.rig.motion.clips import Anchor, Area, Style, plan_feet
from lip_ros.rig.motion.posture import BodyRig, Drive, FootPlan, posture
from lip_ros.rig.motion.primitives import LoopPath, RoutePath, rotate_2d, smoothstep

__all__ = ["GaitClip"]


@dataclass(frozen=True)
class _Gait:
    """Parameters of one walk or run."""

    speed: float
    cadence: float  # strides per second
    stance: float  # fraction of the stride a foot is planted
    lift: float
    clearance: float
    peak: float
    strike: float
    push: float
    lateral_accel: float
    ramp: float
    width: float  # half the step width
    drop: float  # pelvis lowering
    bob: float  # pelvis bobbing amplitude (running)
    lean: float
    arm_swing: float
    arm_e: float
    elbow: float
    elbow_swing: float
    arm_twist: float
    pelvis_yaw: float
    pelvis_roll: float
    sway: float
    thorax: float

    @classmethod
    def draw(cls, rng: np.random.Generator, style: Style, scale: float, run: bool) -> _Gait:
        u, e = rng.uniform, style.energy
        if run:
            return cls(
                speed=u(2.3, 3.3) * np.sqrt(scale),
                cadence=u(1.3, 1.5) / np.sqrt(scale),
                stance=u(0.33, 0.4),
                lift=u(0.15, 0.25) * scale,
                clearance=u(0.05, 0.08) * scale,
                peak=0.4,
                strike=-u(0.0, 0.15),
                push=u(0.5, 0.8),
                lateral_accel=u(4.0, 6.0),
                ramp=u(1.3, 1.8),
                width=u(0.02, 0.04) * scale,
                drop=u(0.04, 0.06) * scale,
                bob=u(0.02, 0.035) * scale,
                lean=u(0.08, 0.2),
                arm_swing=u(0.3, 0.55) * e,
                arm_e=-u(1.1, 1.3),
                elbow=u(1.35, 1.7),
                elbow_swing=u(0.1, 0.35),
                arm_twist=-u(0.0, 0.3),
                pelvis_yaw=u(0.08, 0.16) * e,
                pelvis_roll=u(0.03, 0.07),
                sway=u(0.005, 0.015) * scale,
                thorax=u(0.1, 0.2) * e,
            )
        speed = u(1.0, 1.6) * np.sqrt(scale)
        step = u(0.7, 0.8) * 0.86 * scale * (speed / (1.3 * np.sqrt(scale))) ** 0.6  # step length from leg length
        return cls(
            speed=speed,
            cadence=speed / (2.0 * step),
            stance=u(0.58, 0.62),
            lift=u(0.04, 0.08) * scale,
            clearance=u(0.015, 0.03) * scale,
            peak=0.5,
            strike=-u(0.2, 0.35),
            push=u(0.8, 1.0),
            lateral_accel=u(1.2, 2.0),
            ramp=u(0.9, 1.3),
            width=u(0.05, 0.075) * scale,
            drop=u(0.005, 0.015) * scale,
            bob=0.0,
            lean=u(0.0, 0.06),
            arm_swing=u(0.2, 0.45) * e,
            arm_e=-u(1.25, 1.38),
            elbow=u(0.2, 0.45),
            elbow_swing=u(0.1, 0.3),
            arm_twist=0.0,
            pelvis_yaw=u(0.05, 0.1) * e,
            pelvis_roll=u(0.03, 0.06),
            sway=u(0.015, 0.03) * scale,
            thorax=u(0.05, 0.12) * e,
        )


class GaitClip:
    """Walking or running round and round a closed loop through the start, with start and stop.

    The body follows the loop at a speed limited by the loop's curvature; a
    smooth envelope ramps the gait in and out. Feet are planted on footprints
    laid along the loop (no sliding), roll heel to toe, and swing over; the
    pelvis sways, rotates and bobs, the arms swing against the legs, the body
    leans into turns.

    Given a ``route`` (a :class:`~lip_ros.rig.motion.primitives.RoutePath`
    starting at the anchor) and the ``surface`` height under ground points, the
    loop is the route and the walk follows the terrain: each footprint moves
    along the foot (at most ``_FOOTHOLD_SHIFT``) to the nearest foothold where
    the sole rests on one plane (a tread, the ground, a ramp), stands at its
    height and takes its slope; the pelvis rides the ground along the route,
    smoothed; on a stair flight (steps in the route's profile closer than
    ``_FLIGHT_GAP`` apart) the body slows to one tread per step.
    """

    _DT = 0.01  # s, step of the speed integration
    _PROFILE_STEP = 0.02  # m, sampling of the ground along the route
    _STEP_EDGE = 0.03  # m, a rise of the route's ground profile this sharp is a step edge
    _FLIGHT_GAP = 0.6  # m, step edges closer than this belong to one stair flight
    _PELVIS_SMOOTH = 0.3  # m, sigma of the ground under the pelvis along the route
    _FOOTHOLD_SHIFT = 0.15  # m, furthest a footprint moves to find a foothold
    _MAX_SLOPE = np.radians(15.0)  # a sole tilted more than this is not a foothold

    def __init__(
        self,
        rig: BodyRig,
        style: Style,
        rng: np.random.Generator,
        anchor: Anchor,
        duration: float,
        area: Area | None,
        run: bool,
        route: RoutePath | None = None,
        surface: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        self.name, self.duration, self.rig, self.style = ("run" if run else "walk"), float(duration), rig, style
        self.run = run
        self.p = p = _Gait.draw(rng, style, rig.scale, run)
        # the gait runs between a stride after the start and a stride before the end, so that the first
        # and the last steps have zero amplitude and the clip is at rest at both ends
        self._start = min(1.0 / p.cadence, 0.25 * duration)
        self._stop = duration - self._start
        self._ramp = min(p.ramp, (self._stop - self._start) / 3.0)
        self.surface = surface
        self._ground, self._speed_cap = self._profile(route, surface)
        if route is None:
            if area is None:
                raise ValueError("a gait needs an area to loop in, or a route")
            self.path, self._s = self._plan_path(rng, anchor, area)
        else:
            self.path = route
            self._s = CubicSpline(*self._integrate(route), bc_type="clamped")
        end_xy, end_heading, _ = self.path.at(self._s(np.array([duration])))
        self.end = Anchor(end_xy[0], float(end_heading[0]))
        self._plans = [self._footprints(side) for side in range(2)]
        self._base = style.base()

    def envelope(self, tau: np.ndarray) -> np.ndarray:
        """Gait amplitude 0..1 (ramped in at the start, out before the end)."""
        return smoothstep((tau - self._start) / self._ramp) * smoothstep((self._stop - tau) / self._ramp)

    def _plan_path(self, rng: np.random.Generator, anchor: Anchor, area: Area) -> tuple[LoopPath, CubicSpline]:
        """The largest loop through the anchor inside the area, and the distance walked along it over time."""
        # keep clear of the rim (room for the limbs), unless the body already stands closer to it
        limit = min(area.radius, max(area.radius - 0.45 * self.rig.scale, area.radius - area.room(anchor.xy) + 0.05))
        central = area.room(anchor.xy) > 0.7 * area.radius  # a figure eight fits round the centre only
        shape = "eight" if central and not self.run and rng.random() < 0.4 else "oval"
        harmonics = (
            (rng.uniform(-0.2, 0.1), rng.uniform(-0.05, 0.05)) if shape == "oval" else (rng.uniform(-0.35, -0.1), 0.0)
        )
        normal = np.array([-np.sin(anchor.heading), np.cos(anchor.heading)])
        inward = float(np.dot(area.centre - anchor.xy, normal))  # an oval bulges towards the area's centre
        side = np.sign(inward) if abs(inward) > 1e-6 else (1.0 if rng.random() < 0.5 else -1.0)
        unit = LoopPath(shape, 1.0, anchor.xy, anchor.heading, side, harmonics)
        lo, hi = 0.05, 100.0  # longest loop inside the area (bisection)
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if unit.with_length(mid).max_distance(area.centre) <= limit else (lo, mid)
        path = unit.with_length(lo)
        return path, CubicSpline(*self._integrate(path), bc_type="clamped")  # at rest at both ends

    def _profile(self, route: RoutePath | None, surface: Callable[[np.ndarray], np.ndarray] | None
                 ) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]:
        """The ground under the pelvis (smoothed) and the speed limit of stair flights, along the route's arc
        length (any laps); zero and none without a route on a surface."""
        if route is None or surface is None:
            return (lambda s: np.zeros(np.shape(s))), (lambda s: np.full(np.shape(s), np.inf))
        n = int(np.ceil(route.length / self._PROFILE_STEP))
        grid = np.arange(n) * (route.length / n)
        z = surface(route.at(grid)[0])
        step = grid[1] - grid[0]
        under = gaussian_filter1d(z, self._PELVIS_SMOOTH / step, mode="wrap")
        edges = grid[np.flatnonzero(np.abs(np.diff(z, append=z[:1])) > self._STEP_EDGE)]
        cap = np.full(n, np.inf)
        gaps = np.diff(edges)
        for k in np.flatnonzero(gaps < self._FLIGHT_GAP):  # between two edges of a flight: one tread per step
            cap[(grid >= edges[k] - 0.5 * gaps[k]) & (grid <= edges[k + 1] + 0.5 * gaps[k])] = 2.0 * gaps[k]
        speed = np.minimum(cap * self.p.cadence, self.p.speed)  # stride times cadence
        widen = int(round(1.0 / step)) | 1  # slow down a metre ahead, smoothly
        speed = gaussian_filter1d(minimum_filter1d(speed, widen, mode="wrap"), 0.3 / step, mode="wrap")

        def lap(values: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
            return lambda s: np.interp(np.mod(s, route.length), grid, values, period=route.length)

        return lap(under), lap(speed)

    def _integrate(self, path: LoopPath | RoutePath) -> tuple[np.ndarray, np.ndarray]:
        """Arc length over time at the enveloped, curvature-limited speed."""
        p = self.p
        grid = np.linspace(0.0, path.length, 1024)
        kappa = np.abs(path.at(grid)[2])
        turning = np.sqrt(p.lateral_accel / np.maximum(kappa, 1e-6))  # fastest speed for the curve
        cruise = np.minimum(p.speed, self._speed_cap(grid))
        limit = (cruise**-4 + turning**-4) ** -0.25  # smooth minimum of cruise and turning speed
        t = np.arange(0.0, self.duration + self._DT, self._DT)
        env = self.envelope(t)
        env_mid = self.envelope(t + 0.5 * self._DT)
        dist = np.zeros_like(t)
        length = path.length
        for k in range(len(t) - 1):
            v0 = env[k] * np.interp(dist[k] % length, grid, limit)
            v1 = env_mid[k] * np.interp((dist[k] + 0.5 * self._DT * v0) % length, grid, limit)
            dist[k + 1] = dist[k] + self._DT * v1
        return t, dist

    def _footprints(self, side: int) -> FootPlan:
        p, rig = self.p, self.rig
        offset = 0.5 * side  # the right foot is half a stride behind
        k = np.arange(int(np.floor(-offset)) - 1, int(np.ceil(self.duration * p.cadence)) + 2)
        start = (k + offset) / p.cadence
        end = start + p.stance / p.cadence
        mid = np.clip(start + 0.5 * p.stance / p.cadence, 0.0, self.duration)
        xy, heading, _ = self.path.at(self._s(mid))
        env = self.envelope(mid)
        lateral = (1.0 if side == 0 else -1.0) * (env * p.width + (1.0 - env) * abs(rig.neutral_feet[side, 1]))
        forward = rig.neutral_feet[side, 0]
        xy = xy + rotate_2d(np.stack([np.full_like(lateral, forward), lateral], -1), heading)
        swing_mid = np.clip(0.5 * (end + start + 1.0 / p.cadence), 0.0, self.duration)
        stance_time = p.stance / p.cadence
        start[0], end[-1] = -np.inf, np.inf
        ground = slope = None
        if self.surface is not None:
            xy, ground, slope = self._foothold(side, xy, heading)
        return FootPlan(
            start=start,
            end=end,
            xy=xy,
            yaw=heading,
            lift=p.lift * self.envelope(swing_mid),
            clearance=p.clearance * self.envelope(swing_mid),
            strike=p.strike * self.envelope(np.clip(start, 0.0, None)),
            strike_time=np.full(len(k), (0.15 if self.run else 0.2) * stance_time),
            push=p.push * self.envelope(np.clip(end, None, self.duration)),
            push_time=np.full(len(k), 0.5 * stance_time),
            peak=p.peak,
            ground=ground,
            slope=slope,
        )

    def _foothold(self, side: int, xy: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Footprints (N, 2) moved along the foot to the nearest place where heel, middle and toe tip stand on
        one plane no steeper than ``_MAX_SLOPE`` (kept where there is none), the height of that plane under
        the footprint and its slope pitch (N,)."""
        rig = self.rig
        heel, toe = rig.heel[side, 2], rig.ball[side, 2] + 0.05 * rig.scale  # along the foot, from the ankle
        shifts = np.linspace(-self._FOOTHOLD_SHIFT, self._FOOTHOLD_SHIFT, 31)
        shifts = shifts[np.argsort(np.abs(shifts), kind="stable")]
        along = np.stack([np.cos(yaw), np.sin(yaw)], -1)  # (N, 2)
        at = np.array([heel, 0.5 * (heel + toe), toe])
        points = xy[:, None, None] + along[:, None, None] * (shifts[None, :, None, None] + at[None, None, :, None])
        z = self.surface(points.reshape(-1, 2)).reshape(len(xy), len(shifts), 3)
        rise = z[..., 2] - z[..., 0]
        flat = (np.abs(z[..., 1] - 0.5 * (z[..., 0] + z[..., 2])) < 0.005) & (
            np.abs(rise) <= np.tan(self._MAX_SLOPE) * (toe - heel))
        best = np.where(flat.any(axis=1), np.argmax(flat, axis=1), 0)
        rows = np.arange(len(xy))
        moved = xy + along * shifts[best][:, None]
        rise = rise[rows, best]
        slope = -np.arctan(rise / (toe - heel))  # toes up (negative pitch) uphill
        under = z[rows, best, 0] - heel / (toe - heel) * rise  # the plane at the ankle (heel < 0 < toe)
        return moved, np.nan_to_num(under), slope

    def drive(self, tau: np.ndarray) -> Drive:
        """The body at clip times ``tau``."""
        p, rig, n = self.p, self.rig, len(tau)
        dist = self._s(tau)
        speed = self._s(tau, 1)
        xy, heading, kappa = self.path.at(dist)
        env = self.envelope(tau)
        phase = p.cadence * tau
        stride = np.cos(2.0 * np.pi * phase)  # +1 at left heel strike
        stance = np.cos(2.0 * np.pi * (phase - 0.5 * p.stance))  # +1 at left mid-stance
        normal = np.stack([-np.sin(heading), np.cos(heading)], -1)
        pelvis_xy = xy + (env * p.sway * stance)[:, None] * normal
        pelvis_z = (rig.neutral_height + self._ground(dist)
                    - env * (p.drop + p.bob * np.cos(4.0 * np.pi * (phase - 0.5 * p.stance))))
        rest = self.style.rest
        roll = env * p.pelvis_roll * stance
        channels = {
            "pitch": env * p.lean,
            "twist": -env * p.pelvis_yaw * stride,
            "roll": roll - np.arctan(speed**2 * kappa / GRAVITY),
            "spine_twist": env * (p.pelvis_yaw + p.thorax) * stride,
            "spine_lat": -0.7 * roll,
            "head_twist": -env * p.thorax * stride,
            "head_flex": -0.7 * env * p.lean,
            "l_f": env * (0.1 - p.arm_swing * stride),
            "r_f": env * (0.1 + p.arm_swing * stride),
            "l_e": env * (p.arm_e - rest("l_e")),
            "r_e": env * (p.arm_e - rest("r_e")),
            "l_tw": env * p.arm_twist,
            "r_tw": env * p.arm_twist,
            "l_elbow": env * (p.elbow - rest("l_elbow") + p.elbow_swing * 0.5 * (1.0 - stride)),
            "r_elbow": env * (p.elbow - rest("r_elbow") + p.elbow_swing * 0.5 * (1.0 + stride)),
        }
        post = posture(channels, n, self._base)
        fxy, fyaw, height, roll, airborne, ground = plan_feet(Anchor(np.zeros(2), 0.0), self._plans, tau)
        ankle = np.stack([
            rig.ankle_from_footprint(i, fxy[i], fyaw[:, i], height[:, i], roll[:, i], ground=ground[:, i])
            for i in range(2)], 1)
        pitch = roll + ground[..., 1]
        return Drive(pelvis_xy, pelvis_z, heading, post, ankle, fyaw, pitch, rig.toe_flat(roll, height), airborne)
