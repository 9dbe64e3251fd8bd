"""Ray casting on a static triangle mesh with Intel Embree (``embreex``): the one module that imports it.

Used by the HSC4D rig, whose LiDAR moves through a scene of thousands of
triangles (:class:`lip_ros.rig.terrain.Terrain`): a 64 x 1024 sweep is cast in
milliseconds, each ray from its own origin (the sensor's pose at its column's
time).
"""

from __future__ import annotations

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

__all__ = ["MeshRaycaster"]


class MeshRaycaster:
    """The first hit of rays on the triangles (T, 3, 3) given at construction (any winding)."""

    def __init__(self, triangles: np.ndarray) -> None:
        triangles = np.asarray(triangles, dtype=np.float32)
        if triangles.ndim != 3 or triangles.shape[1:] != (3, 3) or not len(triangles):
            raise ValueError(f"triangles must be (T, 3, 3) with T > 0, not {triangles.shape}")
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self._scene, triangles)
        cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]).astype(np.float64)
        #: (T, 3) each triangle's unit normal (by its winding)
        self.normals = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-12)

    def cast(self, origins: np.ndarray, dirs: np.ndarray, max_range: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Distance (N,) along the unit ``dirs`` from ``origins`` to the first triangle (inf: none within
        ``max_range``), and the hit triangle's index (N,) (-1: none); ``origins`` and ``dirs`` (N, 3) or (3,)."""
        origins, dirs = np.broadcast_arrays(np.atleast_2d(origins), np.atleast_2d(dirs))
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        dirs = np.ascontiguousarray(dirs, dtype=np.float32)
        if not len(dirs):
            return np.zeros(0), np.zeros(0, dtype=np.int64)
        hit = self._scene.run(origins, dirs, output=1)
        index = hit["primID"].astype(np.int64)
        found = (hit["geomID"] >= 0) & (hit["tfar"] <= max_range)
        return np.where(found, hit["tfar"].astype(np.float64), np.inf), np.where(found, index, -1)

    def surface_distance(self, points: np.ndarray, max_range: float = 5.0, subdivisions: int = 3) -> np.ndarray:
        """(N,) how far each point (N, 3) is from the mesh: the shortest of rays cast from it along directions
        spread over the sphere (a ``subdivisions`` x ``subdivisions`` grid on each face of a cube, 6 s^2 of them),
        inf if none hits within ``max_range``. An upper bound of the true distance: with 3 subdivisions (54
        directions) at most 7.2 % above it (measured against planes of 200 random orientations)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        grid = (np.arange(subdivisions) + 0.5) / subdivisions * 2.0 - 1.0
        u, v = (a.ravel() for a in np.meshgrid(grid, grid))
        faces = []
        for axis in range(3):
            for sign in (-1.0, 1.0):
                d = np.empty((u.size, 3))
                d[:, axis], d[:, (axis + 1) % 3], d[:, (axis + 2) % 3] = sign, u, v
                faces.append(d)
        dirs = np.concatenate(faces)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        out = np.full(len(points), np.inf)
        for d in dirs:
            out = np.minimum(out, self.cast(points, np.broadcast_to(d, points.shape), max_range)[0])
        return out
