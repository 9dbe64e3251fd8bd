"""The static scene around a capture: flat ground plus random clutter, and its ray casting.

The scene lives in the scene frame S (z up). For the LIP rig S is the LiDAR
frame L itself and the ground is the plane ``z = -h`` (``h`` the LiDAR
height). Clutter (boxes such as crates or cars, vertical cylinders such as poles
and tree trunks, optionally the walls of a room) stands on the ground outside a
keep-out rectangle, the performer's capture area, and by default also out of
the sensor's line of sight to it. Nothing moves, so a capture ray-casts the
scene once (``lip_ros.rig.lidar.OusterModel.static_image``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["KeepOut", "Boxes", "Cylinders", "Scene"]

#: Clear distance kept between clutter and the keep-out area (metres).
CLEARANCE = 0.5
#: Clear distance kept between clutter and the sensor (metres).
SENSOR_CLEARANCE = 2.0


@dataclass(frozen=True)
class KeepOut:
    """An axis-aligned rectangle of the ground plane (x, y in S) that clutter must not touch."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float

    def distance(self, xy: np.ndarray) -> np.ndarray:
        """(N,) distance of ground points (N, 2) to the rectangle, 0 inside."""
        xy = np.asarray(xy, dtype=np.float64)
        dx = np.maximum(np.maximum(self.x_min - xy[:, 0], xy[:, 0] - self.x_max), 0.0)
        dy = np.maximum(np.maximum(self.y_min - xy[:, 1], xy[:, 1] - self.y_max), 0.0)
        return np.hypot(dx, dy)

    def corners(self) -> np.ndarray:
        """(4, 2) corners of the rectangle."""
        x0, x1, y0, y1 = self.x_min, self.x_max, self.y_min, self.y_max
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])

    def shadows(self, viewer: np.ndarray, xy: np.ndarray, radius: np.ndarray) -> np.ndarray:
        """(N,) whether discs (centres (N, 2), radii (N,)) may hide part of the rectangle from ``viewer`` (2,)."""
        viewer = np.asarray(viewer, dtype=np.float64)
        if self.distance(viewer[None])[0] == 0.0:
            return np.zeros(len(xy), dtype=bool)
        corners = self.corners() - viewer
        mid = corners.mean(axis=0)
        ref = np.arctan2(mid[1], mid[0])
        corner_az = np.angle(np.exp(1j * (np.arctan2(corners[:, 1], corners[:, 0]) - ref)))
        rel = np.asarray(xy, dtype=np.float64) - viewer
        dist = np.linalg.norm(rel, axis=1)
        az = np.angle(np.exp(1j * (np.arctan2(rel[:, 1], rel[:, 0]) - ref)))
        half = np.arcsin(np.clip(radius / np.maximum(dist, 1e-9), 0.0, 1.0))
        in_sector = (az + half >= corner_az.min()) & (az - half <= corner_az.max())
        return in_sector & (dist - radius < np.linalg.norm(corners, axis=1).max())


def _empty(*shape: int) -> np.ndarray:
    return np.zeros((0,) + shape)


@dataclass(frozen=True)
class Boxes:
    """B boxes rotated by ``yaw`` about z: centres (B, 3), half sizes (B, 3), yaw (B,), reflectivity (B,)."""

    centre: np.ndarray = field(default_factory=lambda: _empty(3))
    half: np.ndarray = field(default_factory=lambda: _empty(3))
    yaw: np.ndarray = field(default_factory=lambda: _empty())
    reflectivity: np.ndarray = field(default_factory=lambda: _empty())

    def __len__(self) -> int:
        return len(self.yaw)

    def spheres(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding spheres: centres (B, 3), radii (B,)."""
        return self.centre, np.linalg.norm(self.half, axis=1)

    def intersect(self, i: int, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Entry distance (inf if none) and incidence cosine of unit rays (origin o (3,), d (N, 3)) into box i."""
        c, s = np.cos(self.yaw[i]), np.sin(self.yaw[i])
        rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # S -> box frame
        ob = rot @ (o - self.centre[i])
        db = d @ rot.T
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-self.half[i] - ob) / db
            t2 = (self.half[i] - ob) / db
        enter = np.minimum(t1, t2)
        t_near = enter.max(axis=1)
        t_far = np.maximum(t1, t2).min(axis=1)
        hit = (t_near <= t_far) & (t_near > 0.0)
        face = enter.argmax(axis=1)
        cos = np.abs(np.take_along_axis(db, face[:, None], axis=1)[:, 0])
        return np.where(hit, t_near, np.inf), cos


@dataclass(frozen=True)
class Cylinders:
    """C vertical cylinders: axis (C, 2) in x, y, radius (C,), z_min, z_max (C,), reflectivity (C,)."""

    axis: np.ndarray = field(default_factory=lambda: _empty(2))
    radius: np.ndarray = field(default_factory=lambda: _empty())
    z_min: np.ndarray = field(default_factory=lambda: _empty())
    z_max: np.ndarray = field(default_factory=lambda: _empty())
    reflectivity: np.ndarray = field(default_factory=lambda: _empty())

    def __len__(self) -> int:
        return len(self.radius)

    def spheres(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding spheres: centres (C, 3), radii (C,)."""
        centre = np.column_stack([self.axis, 0.5 * (self.z_min + self.z_max)])
        return centre, np.hypot(self.radius, 0.5 * (self.z_max - self.z_min))

    def intersect(self, i: int, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Entry distance (inf if none) and incidence cosine of unit rays into the closed cylinder i."""
        radius, z_min, z_max = self.radius[i], self.z_min[i], self.z_max[i]
        ox, oy = o[0] - self.axis[i, 0], o[1] - self.axis[i, 1]
        dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
        qa = dx * dx + dy * dy
        qb = ox * dx + oy * dy
        h = qb * qb - qa * (ox * ox + oy * oy - radius * radius)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_side = (-qb - np.sqrt(h)) / qa
            z = o[2] + t_side * dz
            side = (h >= 0.0) & (qa > 0.0) & (t_side > 0.0) & (z >= z_min) & (z <= z_max)
            cos_side = -(dx * (ox + t_side * dx) + dy * (oy + t_side * dy)) / radius
            t_cap = (np.where(dz < 0.0, z_max, z_min) - o[2]) / dz
        cap = (t_cap > 0.0) & ((ox + t_cap * dx) ** 2 + (oy + t_cap * dy) ** 2 <= radius * radius)
        t = np.where(side, t_side, np.where(cap, t_cap, np.inf))
        return t, np.where(side, cos_side, np.abs(dz))


@dataclass(frozen=True)
class Scene:
    """Ground plane ``z = ground_z`` of S plus static boxes and vertical cylinders."""

    ground_z: float
    ground_reflectivity: float = 0.2
    boxes: Boxes = field(default_factory=Boxes)
    cylinders: Cylinders = field(default_factory=Cylinders)

    def raycast(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hits of unit rays from ``origin`` (3,) along ``dirs`` (..., 3), all in S.

        Returns range (...) (inf where the ray escapes), the cosine of the
        incidence angle (...) and the surface reflectivity (...) (0 where none).
        """
        o = np.asarray(origin, dtype=np.float64)
        shape = np.shape(dirs)[:-1]
        d = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        with np.errstate(divide="ignore"):
            t_ground = (self.ground_z - o[2]) / d[:, 2]
        best = np.where(t_ground > 0.0, t_ground, np.inf)
        cos = np.abs(d[:, 2])  # the ground's incidence cosine
        refl = np.where(np.isfinite(best), self.ground_reflectivity, 0.0)
        for group in (self.boxes, self.cylinders):
            centres, reach = group.spheres()
            for i, w in enumerate(centres - o):  # only rays passing a primitive's bounding sphere are tested
                along = d @ w
                near = np.flatnonzero((w @ w - along * along <= reach[i] ** 2) & (along > -reach[i]))
                t, c = group.intersect(i, o, d[near])
                nearer = t < best[near]
                idx = near[nearer]
                best[idx], cos[idx], refl[idx] = t[nearer], c[nearer], group.reflectivity[i]
        return best.reshape(shape), np.clip(cos, 0.0, 1.0).reshape(shape), refl.reshape(shape)

    def with_box(self, centre: np.ndarray, half: np.ndarray, yaw: float, reflectivity: float = 0.3) -> Scene:
        """This scene with one more box: centre (3,), half sizes (3,), yaw (rad) about z."""
        b = self.boxes
        boxes = Boxes(np.vstack([b.centre, centre]), np.vstack([b.half, half]), np.append(b.yaw, yaw),
                      np.append(b.reflectivity, reflectivity))
        return replace(self, boxes=boxes)

    @classmethod
    def random(
        cls,
        seed: int | np.random.Generator,
        keep_out: KeepOut,
        ground_z: float,
        n_boxes: int = 8,
        n_cylinders: int = 12,
        extent: float = 30.0,
        room: float | None = None,
        sensor_xy: tuple[float, float] = (0.0, 0.0),
        clear_view: bool = True,
        ground_reflectivity: float = 0.2,
    ) -> Scene:
        """A random cluttered scene, reproducible from ``seed``.

        Clutter stands in the square of half-size ``extent`` around ``sensor_xy``,
        at least ``CLEARANCE`` from ``keep_out`` and ``SENSOR_CLEARANCE`` from the
        sensor; with ``clear_view`` none of it stands between the sensor and the
        keep-out area. ``room`` (half-size, metres) adds the four walls of a square
        room around the sensor. Fewer objects than asked are placed if no free
        spot is found.
        """
        rng = np.random.default_rng(seed)
        sensor = np.asarray(sensor_xy, dtype=np.float64)
        if room is not None:
            lo, hi = sensor - room + CLEARANCE, sensor + room - CLEARANCE
            if keep_out.x_min < lo[0] or keep_out.y_min < lo[1] or keep_out.x_max > hi[0] or keep_out.y_max > hi[1]:
                raise ValueError("the keep-out area must lie inside the room")
            extent = min(extent, room - 1.0)
        pool = 64 * max(n_boxes, n_cylinders, 1)

        def free(xy: np.ndarray, radius: np.ndarray, n: int) -> np.ndarray:
            """Indices of the first ``n`` candidate footprints (centres, radii) that are allowed."""
            ok = keep_out.distance(xy) > radius + CLEARANCE
            ok &= np.linalg.norm(xy - sensor, axis=1) > radius + SENSOR_CLEARANCE
            if clear_view:
                ok &= ~keep_out.shadows(sensor, xy, radius)
            return np.flatnonzero(ok)[:n]

        xy = sensor + rng.uniform(-extent, extent, (pool, 2))
        half = rng.uniform([0.2, 0.2, 0.2], [1.5, 1.0, 1.25], (pool, 3))
        yaw = rng.uniform(0.0, np.pi, pool)
        rho = rng.uniform(0.08, 0.7, pool)
        i = free(xy, np.hypot(half[:, 0], half[:, 1]), n_boxes)
        boxes = [(np.column_stack([xy[i], ground_z + half[i, 2]]), half[i], yaw[i], rho[i])]
        if room is not None:
            th, hz = 0.1, 2.0
            centre = sensor + np.array([[room, 0.0], [-room, 0.0], [0.0, room], [0.0, -room]])
            half = np.array([[th, room + th, hz], [th, room + th, hz], [room + th, th, hz], [room + th, th, hz]])
            centre = np.column_stack([centre, np.full(4, ground_z + hz)])
            boxes.append((centre, half, np.zeros(4), rng.uniform(0.3, 0.7, 4)))

        xy = sensor + rng.uniform(-extent, extent, (pool, 2))
        tree = rng.random(pool) < 0.5  # tree trunks, else poles
        radius = np.where(tree, rng.uniform(0.12, 0.4, pool), rng.uniform(0.04, 0.12, pool))
        height = np.where(tree, rng.uniform(3.0, 6.0, pool), rng.uniform(2.5, 8.0, pool))
        rho = np.where(tree, rng.uniform(0.1, 0.35, pool), rng.uniform(0.3, 0.8, pool))
        i = free(xy, radius, n_cylinders)
        return cls(
            ground_z=float(ground_z),
            ground_reflectivity=ground_reflectivity,
            boxes=Boxes(*(np.concatenate(parts) for parts in zip(*boxes))),
            cylinders=Cylinders(xy[i], radius[i], np.full(len(i), float(ground_z)), ground_z + height[i], rho[i]),
        )
