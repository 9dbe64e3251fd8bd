"""Scenes with height, for a performer who walks through them carrying the sensors (the HSC4D rig).

A :class:`Terrain` is a set of solid oriented boxes (:class:`Blocks`) in the
world frame W (z up, the open ground at z = 0): walkable ones (the ground,
stair steps, ramps, a raised terrace) and obstacles (walls with openings,
pillars, crates, a roofed room). Walkable blocks stand on the ground (the
steps and the terrace solid down to it, the ramp a slab leaning on the
terrace, open underneath towards its high end), so the scene surface under a
point is the highest walkable top face there (:meth:`Terrain.surface_height`,
the ground truth of foot contact).
:meth:`Terrain.random` lays out a site of 60 x 40 m from a seed: a terrace
reached by a stair flight of 10-16 risers and by a ramp of 5-12 deg, a
roofed room with a door, walls with doorways, pillars and crates, building
facades along the edges (with gaps), a kiosk and lamp posts on the terrace,
each dimension drawn from the seed. Ray casting: :mod:`lip_ros.rig.mesh_raycast`
on :meth:`Terrain.triangles`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lip_ros.core.rotations import rot_y, rot_z

__all__ = ["Blocks", "Terrain", "SITE_HALF_M", "ROUTE_RADIUS_M", "SCENES"]

#: Half the extent of a random site along x and y (metres): 60 x 40 m.
SITE_HALF_M = (30.0, 20.0)
#: What a site holds besides the ground, the terrace, its stair flight and its ramp (the walk's route): "site" all of
#: the module docstring's; rig variants with less for the LiDAR odometry to register on: "sparse" only the facades
#: along the edges and the terrace's kiosk and lamp posts (no room, free walls, pillars or crates), "open" nothing else
#: (a field with a stand).
SCENES = ("site", "sparse", "open")
#: The highest a terrace can be (16 risers of 18 cm).
_TERRACE_MAX_M = 16 * 0.18
#: A ramp runs at most this far (m): steeper than drawn if the terrace is high (room for the route round it).
_MAX_RAMP_RUN_M = 25.0
#: The route's turning radius (m) and the straight it keeps before and after a stair flight or a ramp.
ROUTE_RADIUS_M = 1.2
_ROUTE_RUN_IN_M = 1.5
#: The ground slab's thickness below z = 0.
_GROUND_DEPTH_M = 1.0
# The 12 triangles of a box, as corner indices (corner k has sign bits x = k & 4, y = k & 2, z = k & 1).
_BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                       [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
_CORNER_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)


@dataclass(frozen=True)
class Blocks:
    """Solid boxes: centre (N, 3), half extents (N, 3) along their own axes, yaw about z, pitch (a ramp's rise
    along its own +x, rad), and whether their top face is walked on."""

    centre: np.ndarray
    half: np.ndarray
    yaw: np.ndarray
    pitch: np.ndarray
    walkable: np.ndarray

    def __len__(self) -> int:
        return len(self.centre)

    @property
    def rotation(self) -> np.ndarray:
        """(N, 3, 3) each box's axes in W: Rz(yaw) Ry(-pitch) (+x rises by the pitch)."""
        return rot_z(self.yaw) @ rot_y(-self.pitch)

    @classmethod
    def concatenate(cls, parts: list[Blocks]) -> Blocks:
        """All boxes of ``parts`` in order."""
        return cls(*(np.concatenate([getattr(p, k) for p in parts]) for k in
                     ("centre", "half", "yaw", "pitch", "walkable")))

    @classmethod
    def axis_aligned(cls, lo: np.ndarray, hi: np.ndarray, walkable: bool) -> Blocks:
        """Boxes from their lower and upper corners (N, 3)."""
        lo, hi = np.atleast_2d(lo).astype(np.float64), np.atleast_2d(hi).astype(np.float64)
        n = len(lo)
        return cls(0.5 * (lo + hi), 0.5 * (hi - lo), np.zeros(n), np.zeros(n), np.full(n, walkable))


@dataclass(frozen=True)
class Terrain:
    """A static scene of solid boxes, and what a random one was drawn with (``layout``: name -> value)."""

    blocks: Blocks
    layout: dict

    def triangles(self) -> np.ndarray:
        """(12 N, 3, 3) the boxes' faces, outward."""
        b = self.blocks
        corners = b.centre[:, None] + np.einsum("nij,nkj->nki", b.rotation, _CORNER_SIGNS * b.half[:, None])
        return corners[:, _BOX_FACES].reshape(-1, 3, 3)

    def route(self) -> tuple[np.ndarray, np.ndarray]:
        """A closed walk through a random site: start (2,) and corners (K, 2) of the polygon it rounds.

        From the start on open ground west of the stair flight: east up the
        stairs, north across the terrace, west down the ramp, a U-turn south
        into the lane between the ramp and the stairs, east along it and back to
        the start; straight for at least ``_ROUTE_RUN_IN_M`` before and after the
        stairs and the ramp, and turns of ``ROUTE_RADIUS_M`` elsewhere.
        """
        lay = self.layout
        tx, stair, ramp = lay["terrace_x_m"], np.mean(lay["stair_y_m"]), np.mean(lay["ramp_y_m"])
        stair_foot = tx - (lay["risers"] - 1) * lay["tread_m"]
        ramp_foot = tx - lay["ramp_run_m"]
        lane = 0.5 * (lay["ramp_y_m"][0] + lay["stair_y_m"][1])
        back = stair_foot - _ROUTE_RUN_IN_M - 2.0 * ROUTE_RADIUS_M
        turn = ramp_foot - _ROUTE_RUN_IN_M - ROUTE_RADIUS_M
        on_terrace = tx + _ROUTE_RUN_IN_M + ROUTE_RADIUS_M
        corners = np.array([[on_terrace, stair], [on_terrace, ramp], [turn, ramp], [turn, lane], [back, lane],
                            [back, stair]])
        return np.array([back + ROUTE_RADIUS_M + 0.5, stair]), corners

    def surface_height(self, xy: np.ndarray) -> np.ndarray:
        """(Q,) the height of the highest walkable top face under each point (Q, 2); NaN off the site."""
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        b = self.blocks
        walk = np.flatnonzero(b.walkable)
        rot = b.rotation[walk]
        normal = rot[:, :, 2]  # (M, 3) the top faces' normals (never horizontal: pitch < 90 deg)
        top = b.centre[walk] + b.half[walk, 2:3] * normal
        z = top[:, None, 2] - (normal[:, None, 0] * (xy[None, :, 0] - top[:, None, 0])
                               + normal[:, None, 1] * (xy[None, :, 1] - top[:, None, 1])) / normal[:, None, 2]
        points = np.concatenate([np.broadcast_to(xy, (len(walk), *xy.shape)), z[..., None]], axis=-1)
        local = np.einsum("mji,mqj->mqi", rot, points - b.centre[walk, None])
        inside = np.all(np.abs(local[..., :2]) <= b.half[walk, None, :2] + 1e-9, axis=-1)
        highest = np.where(inside, z, -np.inf).max(axis=0)
        return np.where(inside.any(axis=0), highest, np.nan)

    @classmethod
    def random(cls, seed: int, scene: str = "site") -> Terrain:
        """A site of 60 x 40 m drawn from ``seed`` (module docstring), holding what ``scene`` says (:data:`SCENES`;
        the same seed draws the same stairs, ramp and terrace, and the same objects of those it holds)."""
        if scene not in SCENES:
            raise ValueError(f"unknown scene {scene!r}: one of {SCENES}")
        rng = np.random.default_rng(seed)
        sx, sy = SITE_HALF_M
        parts = [Blocks.axis_aligned([-sx, -sy, -_GROUND_DEPTH_M], [sx, sy, 0.0], walkable=True)]
        risers = int(rng.integers(10, 17))
        riser = float(rng.uniform(0.15, 0.18))
        tread = float(rng.uniform(0.28, 0.32))
        height = risers * riser
        ramp_deg = max(float(rng.uniform(5.0, 12.0)), float(np.degrees(np.arctan(height / _MAX_RAMP_RUN_M))))
        terrace_x = float(rng.uniform(5.0, 10.0))  # its west face; it reaches the site's east edge
        terrace_y = (-sy, float(rng.uniform(-4.0, -1.0)))
        parts.append(Blocks.axis_aligned([terrace_x, terrace_y[0], 0.0], [sx, terrace_y[1], height], walkable=True))
        # the stair flight, down westwards from the terrace's west face
        stair_width = float(rng.uniform(1.5, 2.5))
        stair_y = float(rng.uniform(-18.0, -16.0))
        k = np.arange(1, risers)  # the last riser is the terrace's edge
        lo = np.stack([terrace_x - (risers - k) * tread, np.full(k.size, stair_y), np.zeros(k.size)], axis=1)
        hi = np.stack([lo[:, 0] + tread, np.full(k.size, stair_y + stair_width), k * riser], axis=1)
        parts.append(Blocks.axis_aligned(lo, hi, walkable=True))
        # the ramp, down westwards too, in its own band: a slab whose top face runs from the ground to the terrace
        ramp_width = float(rng.uniform(2.0, 3.0))
        ramp_y = float(rng.uniform(-10.0, -8.0))
        run = height / np.tan(np.radians(ramp_deg))
        length, thick = float(np.hypot(run, height)), 0.5
        pitch = float(np.radians(ramp_deg))
        mid_top = np.array([terrace_x - 0.5 * run, ramp_y + 0.5 * ramp_width, 0.5 * height])
        normal = np.array([-np.sin(pitch), 0.0, np.cos(pitch)])
        parts.append(Blocks(np.array([mid_top - thick * normal]), np.array([[0.5 * length, 0.5 * ramp_width, thick]]),
                            np.zeros(1), np.array([pitch]), np.ones(1, dtype=bool)))
        # every object drawn whatever the scene holds, so that a seed's are the same in each
        inner = [_room(rng, x=float(rng.uniform(-26.0, -14.0)), y=float(rng.uniform(6.0, 10.0))),
                 _walls_with_openings(rng), _clutter(rng)]
        edges = _surroundings(rng, terrace_x, terrace_y[1])
        parts += {"site": [*inner, edges], "sparse": [edges], "open": []}[scene]
        layout = {"risers": risers, "riser_m": riser, "tread_m": tread, "terrace_height_m": height,
                  "terrace_x_m": terrace_x, "terrace_y_m": terrace_y, "stair_y_m": (stair_y, stair_y + stair_width),
                  "ramp_deg": ramp_deg, "ramp_y_m": (ramp_y, ramp_y + ramp_width), "ramp_run_m": run, "scene": scene}
        return cls(Blocks.concatenate(parts), layout)


def _room(rng: np.random.Generator, x: float, y: float) -> Blocks:
    """A roofed room with its south-west corner at (x, y): four walls, a door in the south wall, a roof."""
    w, d, h, t = float(rng.uniform(6.0, 9.0)), float(rng.uniform(5.0, 8.0)), float(rng.uniform(2.6, 3.2)), 0.2
    door = float(rng.uniform(1.0, w - 2.0))
    lo = [[x, y, 0.0], [x + door + 1.0, y, 0.0], [x, y + d - t, 0.0], [x, y, 0.0], [x + w - t, y, 0.0]]
    hi = [[x + door, y + t, h], [x + w, y + t, h], [x + w, y + d, h], [x + t, y + d, h], [x + w, y + d, h]]
    walls = Blocks.axis_aligned(np.array(lo), np.array(hi), walkable=False)
    roof = Blocks.axis_aligned([x, y, h], [x + w, y + d, h + t], walkable=False)
    return Blocks.concatenate([walls, roof])


def _walls_with_openings(rng: np.random.Generator) -> Blocks:
    """Two free-standing walls in the north-east, each with a doorway."""
    parts = []
    for x0 in (0.0, 12.0):
        y, length, h = float(rng.uniform(8.0, 14.0)), float(rng.uniform(8.0, 12.0)), float(rng.uniform(2.0, 3.0))
        gap = float(rng.uniform(2.0, length - 3.0))
        parts.append(Blocks.axis_aligned(np.array([[x0, y, 0.0], [x0 + gap + 1.2, y, 0.0]]),
                                         np.array([[x0 + gap, y + 0.25, h], [x0 + length, y + 0.25, h]]),
                                         walkable=False))
    return Blocks.concatenate(parts)


def _surroundings(rng: np.random.Generator, terrace_x: float, terrace_north: float) -> Blocks:
    """What bounds a real site: building facades along its four edges (segments 4-9 m high with gaps), and on
    the terrace a kiosk and a row of lamp posts east of the route."""
    sx, sy = SITE_HALF_M
    parts = []
    for axis, fixed in ((0, -sy + 0.5), (0, sy - 0.5), (1, -sx + 0.5), (1, sx - 0.5)):
        half = sx if axis == 0 else sy
        edges = np.sort(rng.uniform(-half + 2.0, half - 2.0, 5))
        ends = np.concatenate([[-half + 0.5], edges, [half - 0.5]])
        for a, b in zip(ends[:-1], ends[1:], strict=True):
            if rng.random() < 0.2 or b - a < 1.5:  # a gap between buildings
                continue
            lo, hi = [0.0, 0.0, 0.0], [0.0, 0.0, float(rng.uniform(4.0, 9.0))]
            lo[axis], hi[axis] = a + 0.3, b - 0.3
            lo[1 - axis], hi[1 - axis] = (fixed - 0.4, fixed) if fixed > 0 else (fixed, fixed + 0.4)
            parts.append(Blocks.axis_aligned(np.array(lo), np.array(hi), walkable=False))
    kx, ky = float(rng.uniform(terrace_x + 8.0, 22.0)), float(rng.uniform(-16.0, -10.0))
    parts.append(Blocks.axis_aligned([kx, ky, 0.0], [kx + rng.uniform(3.0, 5.0), ky + rng.uniform(3.0, 5.0),
                                                     _TERRACE_MAX_M + rng.uniform(2.5, 3.5)], walkable=False))
    n = 4
    lx = np.full(n, terrace_x + 5.5)
    ly = np.linspace(-18.0, terrace_north - 1.0, n)
    parts.append(Blocks.axis_aligned(np.stack([lx - 0.1, ly - 0.1, np.zeros(n)], 1),
                                     np.stack([lx + 0.1, ly + 0.1, np.full(n, _TERRACE_MAX_M + 4.0)], 1),
                                     walkable=False))
    return Blocks.concatenate(parts)


def _clutter(rng: np.random.Generator) -> Blocks:
    """Square pillars in a row south of the room, and crates in the south-west, west of the stair flight and south
    of the ramp, each in a slot of its own."""
    n = 6
    px = np.linspace(-26.0, -8.0, n) + rng.uniform(-0.5, 0.5, n)
    py = rng.uniform(1.0, 3.0, n)
    pr = rng.uniform(0.2, 0.4, n)
    ph = rng.uniform(3.0, 6.0, n)
    pillars = Blocks.axis_aligned(np.stack([px - pr, py - pr, np.zeros(n)], 1), np.stack([px + pr, py + pr, ph], 1),
                                  walkable=False)
    m = 8
    cx = np.linspace(-27.0, -10.0, m) + rng.uniform(-0.5, 0.5, m)
    cy = rng.uniform(-19.0, -15.0, m)
    half = rng.uniform(0.3, 0.8, (m, 3))
    crates = Blocks(np.stack([cx, cy, half[:, 2]], 1), half, rng.uniform(0.0, np.pi, m), np.zeros(m),
                    np.zeros(m, dtype=bool))
    return Blocks.concatenate([pillars, crates])
