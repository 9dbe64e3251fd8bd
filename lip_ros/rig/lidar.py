"""Ouster OS1 simulator: organized frames of the static scene and moving bodies.

Follows the Ouster scan model of docs/conventions.md: row i has elevation
``fov/2 - i * fov / (H - 1)`` (row 0 highest), column j is fired at
``j * T / W`` after the frame stamp with encoder azimuth
``column0 - 2 pi j / W`` in L (clockwise seen from above), and row i looks
``beam_offset[i]`` beside it (the beams' azimuth angles of a staggered cloud;
destaggering leaves a fraction of a column; zero by default): ray
direction ``[cos(phi) cos(theta), cos(phi) sin(theta), sin(phi)]``, all rays
from the origin of L. ``column0_azimuth_deg`` is 180 by default (column 0 looks
backwards, -x: the rig's own convention, which its bags and training data
use); 0 is ouster-ros's ``os_lidar`` (column 0 along +x), any other value a
mounting yaw.

The sensor has a fixed pose (``rotation`` R_S_L, ``position`` p_S_L) in the
scene frame S in which the scene and the actors live; for the LIP rig S = L and
the pose is the identity (the ground is at ``z = -h`` in the scene). Points are
reported in L. A moving sensor (the hip-worn HSC4D rig) is cast by
``scan_moving``: each column from the sensor's pose at that column's firing
time, against a triangle mesh (``lip_ros.rig.mesh_raycast``), the points in L
at that time, as the real sensor reports them (motion distortion included);
the sensor model is the same.

Per frame, the static scene comes from a range image cast once per capture
(``static_image``); each actor's pose is evaluated once, at the time the sweep
passes its root, and rays are cast against it only inside the angular box of
its bounding sphere. The nearest surface wins. Then the sensor model: a return
needs ``range >= min_range`` and ``range <= max_range * sqrt(rho cos(i) / 0.8)``
(``max_range`` is the range of an 80 % Lambertian target at normal incidence,
so dark or grazing surfaces vanish sooner), random dropouts, gaussian range
noise growing with range, ranges quantised to mm, xyz recomputed from the
quantised range along the beam; no return = NaN xyz and range 0.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Protocol

import numpy as np

from lip_msgs_py.ouster import OUSTER_ORIGINAL_DTYPE
from lip_ros.core.body import BodyModel
from lip_ros.rig.scene import Scene
from lip_ros.rig.trajectory import Trajectory

__all__ = ["Actor", "PoseFn", "SensorPoses", "SurfaceCaster", "StaticImage", "Frame", "OusterModel"]

#: A pose source: seconds since the capture start -> (glob_rot (24, 3, 3), joint_pos (24, 3)) in S.
PoseFn = Callable[[float], tuple[np.ndarray, np.ndarray]]

#: Reflectivity of the target that ``max_range`` is specified for.
_SPEC_REFLECTIVITY = 0.8
#: Ambient level of pixels looking at the sky, relative to a white surface.
_SKY_AMBIENT = 0.3
_U16_MAX = 65535


@dataclass
class Actor:
    """A moving body: its surface model and its motion (a Trajectory or a ``PoseFn``), in S."""

    body: BodyModel
    motion: Trajectory | PoseFn

    def pose_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations (24, 3, 3) and joint positions (24, 3) at ``t`` seconds since the capture start."""
        glob, pos = self.poses_at(np.array([t]))
        return glob[0], pos[0]

    def poses_at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations (T, 24, 3, 3) and joint positions (T, 24, 3) at the times ``t`` (T,) (a trajectory's
        in one vectorised sample)."""
        if callable(getattr(self.motion, "sample", None)):
            return self.motion.sample(np.asarray(t, dtype=np.float64)).global_pose(self.motion.skeleton)
        poses = [self.motion(float(x)) for x in t]
        return np.stack([g for g, _ in poses]), np.stack([p for _, p in poses])


#: ``poses(t_ns)``: the sensor's pose R_W_L (N, 3, 3), p_W_L (N, 3) in the scene at the times ``t_ns`` (N,).
SensorPoses = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


class SurfaceCaster(Protocol):
    """A static surface to cast rays on (``lip_ros.rig.mesh_raycast.MeshRaycaster``)."""

    normals: np.ndarray  # (T, 3) unit normal of each surface element

    def cast(self, origins: np.ndarray, dirs: np.ndarray, max_range: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Distance to the first hit along each ray (inf: none) and the element hit (-1: none)."""


@dataclass(frozen=True)
class StaticImage:
    """The static scene as seen by every beam: (H, W) arrays, noise-free."""

    range: np.ndarray  # metres along the beam, inf where the beam escapes
    cos_incidence: np.ndarray  # cosine of the angle between the beam and the surface normal
    reflectivity: np.ndarray  # Lambertian reflectivity of the surface hit, 0..1


@dataclass
class Frame:
    """One simulated organized frame."""

    points: np.ndarray  # (H, W) OUSTER_ORIGINAL_DTYPE, xyz in L, NaN and range 0 where no return
    labels: np.ndarray  # (H, W) int16: index of the actor a return comes from, -1 otherwise
    stamp_ns: int  # header.stamp: firing time of column 0
    actor_stamps_ns: np.ndarray  # (A,) int64: when the sweep passed each actor's root, its pose's time (same clock)
    actor_poses: list[tuple[np.ndarray, np.ndarray]]  # (glob_rot, joint_pos) in S of each actor at that time


@dataclass(frozen=True, eq=False)
class OusterModel:
    """An Ouster OS1 LiDAR at a fixed pose in the scene frame S (see the module docstring).

    ``azimuth_window_deg`` = (start, end) keeps returns only from columns whose
    encoder angle ``360 j / W`` (degrees from column 0, in sweep direction, as the
    sensor's ``azimuth_window`` setting) lies in [start, end), wrapping if
    start > end; +x of L is at 180.
    """

    beams: int = 128
    columns: int = 1024
    rate_hz: float = 10.0
    vertical_fov_deg: float = 45.0
    max_range: float = 120.0  # range of an 80 % Lambertian target at normal incidence (m)
    min_range: float = 0.5
    range_noise_std: float = 0.012  # range noise sigma at 0 m ...
    range_noise_per_m: float = 0.0003  # ... growing by this much per metre of range
    dropout_prob: float = 0.001
    azimuth_window_deg: tuple[float, float] | None = None
    column0_azimuth_deg: float = 180.0  # where column 0 looks in L (0: ouster-ros os_lidar, 180: the rig's default)
    beam_azimuth_deg: tuple[float, ...] = ()  # per-row azimuth offsets, cycled over the rows (() = none)
    signal_scale: float = 1.0e5  # intensity of a white target at normal incidence at 1 m
    ambient_level: float = 300.0  # ambient of a white surface
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # R_S_L
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))  # p_S_L

    def __post_init__(self) -> None:
        object.__setattr__(self, "rotation", np.asarray(self.rotation, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "position", np.asarray(self.position, dtype=np.float64).reshape(3))
        if self.beams < 2 or self.columns < 1 or self.rate_hz <= 0.0:
            raise ValueError("need beams >= 2, columns >= 1 and a positive rate")

    @classmethod
    def os1_128(cls, columns: int = 1024, rate_hz: float = 10.0, **kwargs) -> OusterModel:
        """OS1-128, the static sensor of the LIP branch."""
        return cls(beams=128, columns=columns, rate_hz=rate_hz, **kwargs)

    @classmethod
    def os1_64(cls, columns: int = 1024, rate_hz: float = 20.0, **kwargs) -> OusterModel:
        """OS1-64, the hip-worn sensor of the HSC4D branch."""
        return cls(beams=64, columns=columns, rate_hz=rate_hz, **kwargs)

    @classmethod
    def os0_128(cls, columns: int = 1024, rate_hz: float = 10.0, **kwargs) -> OusterModel:
        """OS0-128: 90 deg vertical field of view, shorter range."""
        return cls(beams=128, columns=columns, rate_hz=rate_hz, vertical_fov_deg=90.0, max_range=50.0, **kwargs)

    @classmethod
    def os2_128(cls, columns: int = 1024, rate_hz: float = 10.0, **kwargs) -> OusterModel:
        """OS2-128: 22.5 deg vertical field of view, longer range."""
        return cls(beams=128, columns=columns, rate_hz=rate_hz, vertical_fov_deg=22.5, max_range=240.0, **kwargs)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of a frame."""
        return self.beams, self.columns

    @property
    def period_ns(self) -> int:
        """Duration T of one sweep in ns."""
        return int(round(1e9 / self.rate_hz))

    @cached_property
    def elevation(self) -> np.ndarray:
        """(H,) beam elevations in radians, row 0 highest."""
        fov = self.vertical_fov_deg
        return np.deg2rad(fov / 2.0 - np.arange(self.beams) * fov / (self.beams - 1))

    @cached_property
    def azimuth(self) -> np.ndarray:
        """(W,) column (encoder) azimuths in L, radians: column0 - 2 pi j / W."""
        return np.deg2rad(self.column0_azimuth_deg) - 2.0 * np.pi * np.arange(self.columns) / self.columns

    @cached_property
    def beam_offset(self) -> np.ndarray:
        """(H,) each row's azimuth offset from its column's, radians."""
        if not self.beam_azimuth_deg:
            return np.zeros(self.beams)
        return np.deg2rad(np.resize(np.asarray(self.beam_azimuth_deg, dtype=np.float64), self.beams))

    def _column_of_azimuth(self, theta: float) -> float:
        """The fractional column whose encoder azimuth is ``theta`` (rad)."""
        return (np.deg2rad(self.column0_azimuth_deg) - theta) * self.columns / (2.0 * np.pi)

    @cached_property
    def column_t_ns(self) -> np.ndarray:
        """(W,) firing time of each column after the frame stamp, ns."""
        return np.rint(np.arange(self.columns) * (1e9 / self.rate_hz) / self.columns).astype(np.int64)

    @cached_property
    def column_valid(self) -> np.ndarray:
        """(W,) whether a column lies in the azimuth window (all if none)."""
        if self.azimuth_window_deg is None:
            return np.ones(self.columns, dtype=bool)
        start, end = self.azimuth_window_deg
        enc = 360.0 * np.arange(self.columns) / self.columns
        return (enc >= start) & (enc < end) if start <= end else (enc >= start) | (enc < end)

    @cached_property
    def directions(self) -> np.ndarray:
        """(H, W, 3) unit beam directions in L."""
        cp, sp = np.cos(self.elevation)[:, None], np.sin(self.elevation)[:, None]
        theta = self.azimuth[None, :] + self.beam_offset[:, None]
        ct, st = np.cos(theta), np.sin(theta)
        return np.stack(np.broadcast_arrays(cp * ct, cp * st, sp), axis=-1)

    @cached_property
    def _rays_s(self) -> np.ndarray:
        """(H, W, 3) beam directions in S (all from ``position``)."""
        return self.directions @ self.rotation.T

    def range_sigma(self, range_m: np.ndarray) -> np.ndarray:
        """Range noise standard deviation (m) at a range (m)."""
        return self.range_noise_std + self.range_noise_per_m * np.asarray(range_m)

    def column_of(self, point_s: np.ndarray) -> int:
        """The column whose azimuth passes nearest to a point (3,) of S."""
        p = self.rotation.T @ (np.asarray(point_s) - self.position)
        theta = np.arctan2(p[1], p[0])
        return int(np.rint(self._column_of_azimuth(theta))) % self.columns

    def static_image(self, scene: Scene) -> StaticImage:
        """Cast every beam against the static scene (once per capture)."""
        return StaticImage(*scene.raycast(self.position, self._rays_s))

    def _footprint(self, centre_s: np.ndarray, radius: float) -> tuple[slice, np.ndarray]:
        """Rows (a slice) and columns (indices) of all beams that may meet a sphere of S."""
        c = self.rotation.T @ (centre_s - self.position)
        dist = float(np.linalg.norm(c))
        if dist <= radius:
            return slice(0, self.beams), np.flatnonzero(self.column_valid)
        alpha = np.arcsin(radius / dist)
        phi = np.arcsin(c[2] / dist)
        rows = np.flatnonzero(np.abs(self.elevation - phi) <= alpha)
        row_slice = slice(rows[0], rows[-1] + 1) if rows.size else slice(0, 0)
        if np.cos(phi) <= np.sin(alpha):
            cols = np.arange(self.columns)
        else:
            spread = np.abs(self.beam_offset).max()
            half = (np.arcsin(np.sin(alpha) / np.cos(phi)) + spread) * self.columns / (2.0 * np.pi)
            jc = self._column_of_azimuth(np.arctan2(c[1], c[0]))
            lo, hi = int(np.floor(jc - half)), int(np.ceil(jc + half))
            cols = np.arange(self.columns) if hi - lo + 1 >= self.columns else np.arange(lo, hi + 1) % self.columns
        return row_slice, cols[self.column_valid[cols]]

    def _actor_pose(self, actor: Actor, stamp_ns: int, start_ns: int) -> tuple[int, np.ndarray, np.ndarray]:
        """Time (ns) the sweep passes the actor's root, and the actor's pose then.

        Fixed-point iteration from mid-sweep: pose -> column of the root -> its time.
        """
        t_ns = stamp_ns + self.period_ns // 2
        glob, pos = actor.pose_at((t_ns - start_ns) * 1e-9)
        for _ in range(3):
            t_next = stamp_ns + int(self.column_t_ns[self.column_of(pos[0])])
            if t_next == t_ns:
                break
            t_ns = t_next
            glob, pos = actor.pose_at((t_ns - start_ns) * 1e-9)
        return t_ns, glob, pos

    def scan(
        self,
        stamp_ns: int,
        static: StaticImage | None,
        actors: Sequence[Actor],
        rng: np.random.Generator,
        start_ns: int = 0,
    ) -> Frame:
        """Simulate the frame whose column 0 fires at ``stamp_ns``.

        ``static`` is this sensor's ``static_image`` of the scene (None: empty
        space); actor poses are asked for at ``(t_ns - start_ns) * 1e-9`` seconds,
        ``start_ns`` being the capture start on the stamp clock.
        """
        if static is None:
            best = np.full(self.shape, np.inf)
            cos, refl = np.zeros(self.shape), np.zeros(self.shape)
        else:
            if static.range.shape != self.shape:
                raise ValueError(f"static image is {static.range.shape}, the sensor {self.shape}")
            best, cos, refl = static.range.copy(), static.cos_incidence.copy(), static.reflectivity.copy()
        labels = np.full(self.shape, -1, dtype=np.int16)
        stamps, poses = [], []
        for k, actor in enumerate(actors):
            t_ns, glob, pos = self._actor_pose(actor, stamp_ns, start_ns)
            stamps.append(t_ns)
            poses.append((glob, pos))
            rows, cols = self._footprint(*actor.body.bounding_sphere(glob, pos))
            dirs = self._rays_s[rows, cols]
            if dirs.size == 0:
                continue
            hits = actor.body.raycast(self.position, dirs.reshape(-1, 3), glob, pos)
            r, c, rho = (x.reshape(dirs.shape[:2]) for x in hits)
            nearer = r < best[rows, cols]
            for image, value in ((best, r), (cos, c), (refl, rho), (labels, k)):
                image[rows, cols] = np.where(nearer, value, image[rows, cols])
        points = self._measure(best, cos, refl, labels, rng)
        return Frame(points, labels, int(stamp_ns), np.array(stamps, dtype=np.int64), poses)

    def scan_moving(
        self,
        stamp_ns: int,
        surface: SurfaceCaster,
        poses: SensorPoses,
        rng: np.random.Generator,
        actors: Sequence[Actor] = (),
        start_ns: int = 0,
        reflectivity: float = 0.5,
        block: int = 32,
    ) -> Frame:
        """Simulate the frame whose column 0 fires at ``stamp_ns`` from a moving sensor: column j cast from
        ``poses(stamp_ns + column_t_ns[j])`` against ``surface`` (of uniform ``reflectivity``) and the
        ``actors`` (the performer who carries the sensor among them: their body blocks and returns rays), its
        points in L at that pose (the sensor's own ``rotation`` and ``position`` are not used). An actor is
        posed once per ``block`` columns, at the block's middle, and cast from the sensor's position then
        (32 columns of a 10 Hz sweep: 3 ms)."""
        rot, pos = poses(stamp_ns + self.column_t_ns)
        dirs = np.einsum("wab,hwb->hwa", rot, self.directions)  # (H, W, 3) in the scene
        origins = np.broadcast_to(pos[None], dirs.shape)
        dist, element = surface.cast(origins.reshape(-1, 3), dirs.reshape(-1, 3), self.max_range)
        hit = element >= 0
        cos = np.zeros(dist.shape)
        cos[hit] = np.abs(np.einsum("na,na->n", surface.normals[element[hit]], dirs.reshape(-1, 3)[hit]))
        best, cos = dist.reshape(self.shape), cos.reshape(self.shape)
        refl = np.where(hit, reflectivity, 0.0).reshape(self.shape)
        labels = np.full(self.shape, -1, dtype=np.int16)
        stamps, actor_poses = [], []
        blocks = [np.arange(lo, min(lo + block, self.columns)) for lo in range(0, self.columns, block)]
        mids = np.array([cols[len(cols) // 2] for cols in blocks])
        t_ns = stamp_ns + self.column_t_ns[mids].astype(np.int64)
        for k, actor in enumerate(actors):
            globs, joints = actor.poses_at((t_ns - start_ns) * 1e-9)  # one sample for the sweep's blocks
            stamps.append(int(t_ns[0]))
            actor_poses.append((globs[0], joints[0]))
            for cols, mid, glob, joint in zip(blocks, mids, globs, joints, strict=True):
                r, c, rho = (x.reshape(self.beams, len(cols)) for x in
                             actor.body.raycast(pos[mid], dirs[:, cols].reshape(-1, 3), glob, joint))
                nearer = r < best[:, cols]
                for image, value in ((best, r), (cos, c), (refl, rho), (labels, k)):
                    image[:, cols] = np.where(nearer, value, image[:, cols])
        points = self._measure(best, cos, refl, labels, rng)
        return Frame(points, labels, int(stamp_ns), np.array(stamps, dtype=np.int64), actor_poses)

    def _measure(
        self, true_range: np.ndarray, cos: np.ndarray, refl: np.ndarray, labels: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """Sensor model: detection, noise, quantisation and the point fields; clears ``labels`` of non-returns."""
        strength = refl * cos
        detect = (
            (true_range >= self.min_range)
            & (true_range <= self.max_range * np.sqrt(np.minimum(strength / _SPEC_REFLECTIVITY, 1.0)))
            & self.column_valid[None, :]
            & (rng.random(self.shape) >= self.dropout_prob)
        )
        labels[~detect] = -1
        i = np.flatnonzero(detect)
        r = true_range.ravel()[i]
        noise = rng.standard_normal((2, i.size))
        range_mm = np.rint((r + self.range_sigma(r) * noise[0]) * 1000.0)
        falloff = self.signal_scale / np.maximum(r, 1.0) ** 2
        signal = strength.ravel()[i] * falloff
        signal = np.maximum(signal + np.sqrt(signal) * noise[1], 0.0)
        ambient = self.ambient_level * np.where(np.isfinite(true_range), refl, _SKY_AMBIENT)
        ambient = np.clip(ambient + np.sqrt(ambient) * rng.standard_normal(self.shape), 0.0, _U16_MAX)

        out = np.zeros(self.shape, dtype=OUSTER_ORIGINAL_DTYPE)  # zeroed padding: frames are byte-for-byte reproducible
        out["t"] = self.column_t_ns[None, :]
        out["ring"] = np.arange(self.beams)[:, None]
        out["ambient"] = np.rint(ambient * self.column_valid[None, :])
        flat = out.reshape(-1)
        xyz = (range_mm * 1e-3)[:, None] * self.directions.reshape(-1, 3)[i]
        for axis, name in enumerate("xyz"):
            out[name] = np.nan
            flat[name][i] = xyz[:, axis]
        flat["range"][i] = range_mm
        flat["intensity"][i] = np.rint(np.minimum(signal, _U16_MAX))  # photon counts, as the driver reports them
        flat["reflectivity"][i] = np.clip(np.rint(100.0 * signal / falloff), 0, 255)
        return out
