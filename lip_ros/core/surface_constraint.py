"""How well a point cloud's surfaces pin down a registration's motion, from the points alone (ROS-free).

A registration slides freely along a motion no surface resists: on an open
field the ground pins down the height, the tilt and nothing else; in a corridor
nothing pins the shift along it. :func:`registration_constraint` takes each
point's local plane (the normal of its ``neighbours`` nearest points, where they
are flat) and returns the eigen-decomposition of the point-to-plane information
of a small motion of the sensor (a turn, scaled by the points' RMS range, and a
shift), per point of the cloud: the degeneracy measure of Zhang and Singh ("On
degeneracy of optimization-based state estimation problems", ICRA 2016) per
point rather than summed, so that it does not grow with a sensor's point count.
A direction with a small eigenvalue is one the cloud hardly pins down.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["registration_constraint"]

#: a neighbourhood is flat when its smallest spread is under this share of its middle one
_FLAT = 0.1


def registration_constraint(points: np.ndarray, neighbours: int = 10) -> tuple[np.ndarray, np.ndarray, float]:
    """For ``points`` (N, 3) seen from the origin: the eigenvalues (6,), ascending, and eigenvectors (6, 6, columns)
    of the point-to-plane information of a small motion (rotation vector times ``scale``, translation), per point,
    and ``scale``, the points' RMS distance from the origin (so that a turn and a shift are measured alike: a turn
    of 1 / scale rad moves the points as far as a shift of 1 m on the mean). Up to ``neighbours`` points: zeros,
    the identity, 1."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) <= neighbours:
        return np.zeros(6), np.eye(6), 1.0
    _, index = cKDTree(points).query(points, neighbours)
    near = points[index] - points[index].mean(axis=1, keepdims=True)
    spread, axes = np.linalg.eigh(np.einsum("nki,nkj->nij", near, near))
    flat = spread[:, 0] < _FLAT * spread[:, 1]
    normals = axes[flat, :, 0]
    scale = float(np.sqrt(np.mean(np.einsum("na,na->n", points, points)))) or 1.0
    rows = np.concatenate([np.cross(points[flat], normals) / scale, normals], axis=1)
    values, vectors = np.linalg.eigh(rows.T @ rows / len(points))
    return np.clip(values, 0.0, None), vectors, scale
