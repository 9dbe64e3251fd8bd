"""Smooth building blocks of procedural body motion (numpy, vectorised over time).

Easing and bump curves, soft limits, eased keyframe channels, windowed
oscillators, Euler-angle chains, closed ground loops and routes through corners. Every curve is at least
C2 in time, so positions built from them can be differentiated twice (the IMU
simulation finite-differences them at about 1 kHz).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import gaussian_filter1d
from scipy.optimize import brentq

from lip_ros.core.rotations import rot_x, rot_y, rot_z

__all__ = [
    "smoothstep",
    "smoothstep_inverse",
    "bump",
    "softplus",
    "soft_clamp",
    "wrap_angle",
    "rotate_2d",
    "EasedKeys",
    "Oscillator",
    "euler_chain",
    "LoopPath",
    "RoutePath",
    "LOOP_SHAPES",
]

#: Standard gravity (m/s^2).
_AXES = {"x": rot_x, "y": rot_y, "z": rot_z}
_INV_GRID = np.linspace(0.0, 1.0, 2001)


def smoothstep(x: np.ndarray | float) -> np.ndarray:
    """Quintic ease 0 -> 1 on [0, 1] (zero slope and curvature at both ends), clamped outside."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (10.0 + x * (6.0 * x - 15.0))


def smoothstep_inverse(y: np.ndarray | float) -> np.ndarray:
    """The x in [0, 1] with ``smoothstep(x) == y`` (y clamped to [0, 1])."""
    return np.interp(np.clip(y, 0.0, 1.0), smoothstep(_INV_GRID), _INV_GRID)


def bump(x: np.ndarray | float, peak: float = 0.5) -> np.ndarray:
    """C2 bump on [0, 1] with maximum 1 at ``peak`` and zero (with two derivatives) at both ends."""
    a, b = (3.0, 3.0 * (1.0 - peak) / peak) if peak <= 0.5 else (3.0 * peak / (1.0 - peak), 3.0)
    x = np.clip(x, 0.0, 1.0)
    return (x**a * (1.0 - x) ** b) / (peak**a * (1.0 - peak) ** b)


def softplus(x: np.ndarray | float, width: float) -> np.ndarray:
    """Smooth ``max(x, 0)``: ``width * log(1 + exp(x / width))``."""
    return width * np.logaddexp(0.0, np.asarray(x) / width)


def soft_clamp(x: np.ndarray, limit: np.ndarray | float, margin: float) -> np.ndarray:
    """``x`` below ``limit - margin``; above, eased (C2, tanh) so that it never exceeds ``limit``."""
    knee = np.asarray(limit) - margin
    over = np.maximum(np.asarray(x) - knee, 0.0)
    return np.where(x > knee, knee + margin * np.tanh(over / margin), x)


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def rotate_2d(xy: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """(..., 2) vectors turned counter-clockwise by ``angle`` (scalar or (...,))."""
    xy = np.asarray(xy, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * xy[..., 0] - s * xy[..., 1], s * xy[..., 0] + c * xy[..., 1]], -1)


class EasedKeys:
    """A scalar channel through keyframes, eased (quintic) from key to key, held outside them.

    The channel comes to rest at every key (pose-to-pose animation); it is C2.
    """

    def __init__(self, times: np.ndarray, values: np.ndarray) -> None:
        order = np.argsort(times, kind="stable")
        self.times = np.asarray(times, dtype=np.float64)[order]
        self.values = np.asarray(values, dtype=np.float64)[order]
        if np.any(np.diff(self.times) <= 0.0):
            raise ValueError("keyframe times must be distinct")

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Channel values at times ``t``."""
        if len(self.times) == 1:
            return np.full(np.shape(t), self.values[0])
        i = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 2)
        t0, t1 = self.times[i], self.times[i + 1]
        w = smoothstep((t - t0) / (t1 - t0))
        return self.values[i] + w * (self.values[i + 1] - self.values[i])


@dataclass(frozen=True)
class Oscillator:
    """``amp * sin(2 pi freq (t - t_on) + phase)``, faded in and out over ``ramp`` s inside [t_on, t_off]."""

    amp: float
    freq: float
    t_on: float
    t_off: float
    ramp: float = 0.3
    phase: float = 0.0

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Oscillator values at times ``t`` (zero outside its window)."""
        window = smoothstep((t - self.t_on) / self.ramp) * smoothstep((self.t_off - t) / self.ramp)
        return self.amp * window * np.sin(2.0 * np.pi * self.freq * (t - self.t_on) + self.phase)


def euler_chain(angles: np.ndarray, seq: str) -> np.ndarray:
    """(..., 3) angles to (..., 3, 3) rotations ``R_seq[0](a0) @ R_seq[1](a1) @ R_seq[2](a2)``."""
    angles = np.asarray(angles, dtype=np.float64)
    return _AXES[seq[0]](angles[..., 0]) @ _AXES[seq[1]](angles[..., 1]) @ _AXES[seq[2]](angles[..., 2])


LOOP_SHAPES = ("oval", "eight")


class LoopPath:
    """A closed, smooth loop on the ground plane, given by its heading as a function of arc length.

    With ``u = 2 pi s / length`` the heading relative to the start is
    ``u + b sin 2u + d sin 4u`` for an 'oval' (one turn, convex for small b, d)
    and ``a sin u + b sin 3u`` for an 'eight' (``a`` solved so that it closes),
    times ``side`` (+1: the first turn is to the left). The loop starts at
    ``anchor`` heading along ``heading`` (radians in the world xy plane) and is
    back there, with the same heading, after every ``length`` metres;
    curvature is ``dheading/ds``, bounded and smooth.
    """

    def __init__(
        self,
        shape: str,
        length: float,
        anchor: np.ndarray,
        heading: float,
        side: float = 1.0,
        harmonics: tuple[float, float] = (0.0, 0.0),
        samples: int = 4097,
    ) -> None:
        if shape not in LOOP_SHAPES:
            raise ValueError(f"unknown loop shape {shape!r}")
        b, d = harmonics
        if shape == "oval":
            self._turns, self._waves = 1.0, ((2, b), (4, d))
        else:
            self._turns = 0.0
            u = np.linspace(0.0, 2.0 * np.pi, samples)

            def gap(a: float) -> float:
                return float(np.trapezoid(np.cos(a * np.sin(u) + b * np.sin(3 * u)), u))

            self._waves = ((1, brentq(gap, 1.6, 3.4)), (3, b))
        self.length, self.side, self.heading = float(length), float(side), float(heading)
        self.anchor = np.asarray(anchor, dtype=np.float64)
        u = np.linspace(0.0, 2.0 * np.pi, samples)
        psi = self._psi(u)
        c, s = np.cos(self.heading), np.sin(self.heading)
        step = np.stack([np.cos(psi), np.sin(psi)], -1) @ np.array([[c, s], [-s, c]])
        unit = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (step[1:] + step[:-1]), axis=0) * (u[1] / (2.0 * np.pi))])
        unit -= np.outer(u / (2.0 * np.pi), unit[-1])  # remove the (tiny) closure error of the quadrature
        self._unit = CubicSpline(u / (2.0 * np.pi), unit, bc_type="periodic")
        self._points = unit

    def _psi(self, u: np.ndarray, derivative: bool = False) -> np.ndarray:
        """Heading relative to the start (or its derivative in u), side applied."""
        if derivative:
            out = self._turns + sum(k * a * np.cos(k * u) for k, a in self._waves)
        else:
            out = self._turns * u + sum(a * np.sin(k * u) for k, a in self._waves)
        return self.side * out

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World xy (..., 2), heading (...,) and signed curvature (...,) at arc lengths ``s`` (any laps)."""
        s = np.asarray(s, dtype=np.float64)
        u = 2.0 * np.pi * s / self.length
        xy = self.anchor + self.length * self._unit(np.mod(s / self.length, 1.0))
        return xy, self.heading + self._psi(u), self._psi(u, derivative=True) * 2.0 * np.pi / self.length

    def max_distance(self, centre: np.ndarray) -> float:
        """Largest distance of the loop from ``centre``."""
        return float(np.max(np.linalg.norm(self.anchor + self.length * self._points - centre, axis=-1)))

    def with_length(self, length: float) -> LoopPath:
        """The same loop scaled to ``length`` metres."""
        out = copy.copy(self)
        out.length = float(length)
        return out


class RoutePath:
    """A closed route on the ground through the corners of a polygon, turning on arcs of ``radius``.

    The route starts at ``start`` (on the polygon's last edge, heading to its
    first corner), runs straight along the edges and round each corner on a
    circular arc tangent to both edges; the curvature is then smoothed over
    ``smooth`` metres (a Gaussian in arc length) so that the heading is C2 (each
    smoothed turn moves the straight after it sideways by a few mm), and the
    closure error this leaves is spread along the loop. Same interface
    as :class:`LoopPath` (``length``, :meth:`at` for any laps).
    """

    def __init__(self, start: np.ndarray, corners: np.ndarray, radius: float, smooth: float = 0.1,
                 step: float = 0.01) -> None:
        start = np.asarray(start, dtype=np.float64)
        corners = np.asarray(corners, dtype=np.float64)
        ring = np.concatenate([[start], corners, [start]])
        edges = np.diff(ring, axis=0)
        heading = np.arctan2(edges[:, 1], edges[:, 0])
        turns = wrap_angle(np.diff(heading))  # at each corner
        cut = radius * np.tan(0.5 * np.abs(turns))  # edge length taken by the arcs at each end
        straight = np.linalg.norm(edges, axis=1) - np.concatenate([[0.0], cut]) - np.concatenate([cut, [0.0]])
        if np.any(straight < 0.0):
            raise ValueError("route corners are too close for the turning radius")
        pieces = []  # (length, curvature) along the route
        for k, turn in enumerate(turns):
            pieces += [(straight[k], 0.0), (radius * abs(turn), np.sign(turn) / radius)]
        pieces.append((straight[-1], 0.0))
        ends = np.cumsum([length for length, _ in pieces])
        self.length = float(ends[-1])
        s = np.linspace(0.0, self.length, int(np.ceil(self.length / step)) + 1)
        which = np.minimum(np.searchsorted(ends, s, side="right"), len(pieces) - 1)
        kappa = np.array([c for _, c in pieces])
        starts = ends - np.array([length for length, _ in pieces])
        psi_start = heading[0] + np.concatenate([[0.0], np.cumsum(kappa * (ends - starts))[:-1]])
        psi = psi_start[which] + kappa[which] * (s - starts[which])  # exact on the grid
        ds = s[1] - s[0]
        trend = (psi[-1] - psi[0]) * s / self.length
        wave = gaussian_filter1d((psi - trend)[:-1], smooth / ds, mode="wrap")  # one period (s = L is s = 0)
        psi = trend + np.append(wave, wave[0])  # = the curvature smoothed
        unit = np.stack([np.cos(psi), np.sin(psi)], -1)
        xy = start + np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (unit[1:] + unit[:-1]) * ds, axis=0)])
        xy -= np.outer(s / self.length, xy[-1] - start)  # close the loop exactly
        self._lap_turn = float(psi[-1] - psi[0])  # 2 pi times the winding number
        # splines (C2: the IMU simulation differentiates positions twice) of xy and of the heading less its lap trend
        self._xy = CubicSpline(s / self.length, xy, bc_type="periodic")
        self._psi = CubicSpline(s / self.length, psi - self._lap_turn * s / self.length, bc_type="periodic")

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World xy (..., 2), heading (...,) and signed curvature (...,) at arc lengths ``s`` (any laps)."""
        u = np.asarray(s, dtype=np.float64) / self.length
        r = np.mod(u, 1.0)
        heading = self._psi(r) + self._lap_turn * u
        return self._xy(r), heading, (self._psi(r, 1) + self._lap_turn) / self.length
