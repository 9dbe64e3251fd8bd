"""The surface fit's inner loop, compiled (numba): one Gauss-Newton step's normal equations over a frame's points.

:meth:`lip_ros.lip.surface_fit.SurfaceFitter.fit` spends its time here: for each performer point, given where its
ray first meets the posed capsule body (:func:`lip_ros.core.capsule_rays.first_hits`, called by the fit), the
capsule it meets or, for a ray that misses the body, the capsule nearest the point, the point's residual and its
row of the Jacobian, summed into ``H`` and ``rhs``. As NumPy array operations a step took about 0.6 ms for 200
points, most of it the cost of a hundred small array operations; compiled, a point at a time, about 0.2 ms,
without the GIL held (the graph's other threads go on). How it is compiled and cached:
:mod:`lip_ros.core.compiled`.
"""

from __future__ import annotations

from math import inf, sqrt

import numba
import numpy as np
from numba import types

from lip_ros.core.compiled import COMPILE, array_in

__all__ = ["normal_equations"]


@numba.njit(**COMPILE)
def _nearest_on_axis(p: np.ndarray, a: np.ndarray, ab: np.ndarray) -> tuple[float, float, float, float]:
    """Where on the segment ``a`` to ``a + ab`` the point ``p`` is nearest (the fraction s) and the point's offset
    from there."""
    abab = max(ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2], 1e-18)
    s = ((p[0] - a[0]) * ab[0] + (p[1] - a[1]) * ab[1] + (p[2] - a[2]) * ab[2]) / abab
    s = min(max(s, 0.0), 1.0)
    return s, p[0] - (a[0] + s * ab[0]), p[1] - (a[1] + s * ab[1]), p[2] - (a[2] + s * ab[2])


@numba.njit(types.Tuple((types.float64[:, :], types.float64[:], types.float64[:]))(
    array_in(2), array_in(2), array_in(1), array_in(1), array_in(2), array_in(2), array_in(1), array_in(1),
    array_in(1, types.int64), array_in(3), array_in(3), array_in(1), array_in(1, types.int64), types.float64,
    types.float64, types.float64, types.float64, types.int64), **COMPILE)
def normal_equations(points: np.ndarray, ray: np.ndarray, ranges: np.ndarray, t: np.ndarray, a: np.ndarray,
                     ab: np.ndarray, radius: np.ndarray, r0: np.ndarray, girth: np.ndarray, da: np.ndarray,
                     db: np.ndarray, hit_ranges: np.ndarray, met: np.ndarray, huber_m: float, noise_m: float,
                     miss_weight: float, min_cos: float, n_girths: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One Gauss-Newton step of the surface fit at the body's position ``t`` (3,): the weighted normal equations
    ``H`` (M, M) and ``rhs`` (M,) over the unknowns (the translation, ``n_girths`` girths, then the G bone-group
    lengths: M = 3 + n_girths + G), no priors added, and each point's residual (N,).

    ``points`` (N, 3) in the sensor's frame, their unit rays and ranges; the body's capsules root-relative: ends
    ``a`` and ``a + ab`` (K, 3), radii ``radius`` (K,), the contract body's radii ``r0`` (K,) and each capsule's
    girth group ``girth`` (K,), the ends' derivatives by each bone-group length ``da``, ``db`` (G, K, 3); where
    each ray first meets the body and the capsule it meets, ``hit_ranges`` and ``met`` (-1 where none:
    :func:`lip_ros.core.capsule_rays.first_hits` from the body's origin ``-t``). A point whose ray meets the
    body: the range error times the cosine of the incidence (at least ``min_cos``); one whose ray misses it: its
    distance to the nearest capsule's surface, weighted by ``miss_weight``; Huber weights beyond ``huber_m``, over
    ``noise_m`` squared."""
    n, k_count, g_count = points.shape[0], a.shape[0], da.shape[0]
    m = 3 + n_girths + g_count
    H = np.zeros((m, m))
    rhs = np.zeros(m)
    res_out = np.empty(n)
    jac = np.empty(m)
    p = np.empty(3)
    for i in range(n):
        d, hit_range, capsule = ray[i], hit_ranges[i], met[i]
        hit = capsule >= 0
        if hit:  # where the ray meets the body, root-relative
            for j in range(3):
                p[j] = d[j] * hit_range - t[j]
            k = capsule
        else:  # the point itself, and the capsule whose surface is nearest it
            for j in range(3):
                p[j] = points[i, j] - t[j]
            k, nearest = 0, inf
            for kk in range(k_count):
                _, q0, q1, q2 = _nearest_on_axis(p, a[kk], ab[kk])
                gap = sqrt(q0 * q0 + q1 * q1 + q2 * q2) - radius[kk]
                if gap < nearest:
                    nearest, k = gap, kk
        s, q0, q1, q2 = _nearest_on_axis(p, a[k], ab[k])
        dist = sqrt(q0 * q0 + q1 * q1 + q2 * q2)
        scale = max(dist, 1e-9)
        n0, n1, n2 = q0 / scale, q1 / scale, q2 / scale
        if hit:
            res = max(-(n0 * d[0] + n1 * d[1] + n2 * d[2]), min_cos) * (hit_range - ranges[i])
        else:
            res = dist - radius[k]
        w = min(1.0, huber_m / max(abs(res), 1e-12)) / (noise_m * noise_m)
        if not hit:
            w *= miss_weight
        res_out[i] = res
        jac[0], jac[1], jac[2] = -n0, -n1, -n2  # moving the body by dt moves the point by -dt relative to it
        for g in range(n_girths):
            jac[3 + g] = 0.0
        jac[3 + girth[k]] = -r0[k]
        for g in range(g_count):  # a longer bone group moves the axis point nearest the point by dq
            dq0 = da[g, k, 0] + s * (db[g, k, 0] - da[g, k, 0])
            dq1 = da[g, k, 1] + s * (db[g, k, 1] - da[g, k, 1])
            dq2 = da[g, k, 2] + s * (db[g, k, 2] - da[g, k, 2])
            jac[3 + n_girths + g] = -(dq0 * n0 + dq1 * n1 + dq2 * n2)
        for u in range(m):
            wu = w * jac[u]
            rhs[u] -= wu * res
            for v in range(u, m):
                H[u, v] += wu * jac[v]
    for u in range(m):
        for v in range(u):
            H[u, v] = H[v, u]
    return H, rhs, res_out
