"""Forward kinematics' joint chain, compiled (numba): :func:`lip_ros.core.skeleton.forward_kinematics`'s loop.

Twenty-three joints, each its parent's rotation times its own and its parent's position plus the rotated offset:
as NumPy operations on (..., 3, 3) arrays this took about 0.27 ms a pose, most of it the cost of 46 small array
operations, and a LIP frame runs it four times; compiled, about 4 us (0.02 ms with
:func:`~lip_ros.core.skeleton.forward_kinematics`'s array handling around it). How it is compiled and cached:
:mod:`lip_ros.core.compiled`.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types

from lip_ros.core.compiled import COMPILE, array_in

__all__ = ["chain"]


@numba.njit(types.Tuple((types.float64[:, :, :, ::1], types.float64[:, :, ::1]))(
    array_in(4), array_in(3), array_in(2), array_in(1, types.int64)), **COMPILE)
def chain(local_rot: np.ndarray, offsets: np.ndarray, root_pos: np.ndarray, parents: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations (B, J, 3, 3) and positions (B, J, 3) of B poses: local rotations (B, J, 3, 3) (``[:, 0]``
    the root's in the world), rest offsets (B, J, 3), root positions (B, 3), each joint's parent (J,) (-1 for the
    root, parents before their children)."""
    count, joints = local_rot.shape[0], local_rot.shape[1]
    glob = np.empty((count, joints, 3, 3))
    pos = np.empty((count, joints, 3))
    for i in range(count):
        glob[i, 0] = local_rot[i, 0]
        pos[i, 0] = root_pos[i]
        for j in range(1, joints):
            g, local, off = glob[i, parents[j]], local_rot[i, j], offsets[i, j]
            for r in range(3):
                for c in range(3):
                    glob[i, j, r, c] = g[r, 0] * local[0, c] + g[r, 1] * local[1, c] + g[r, 2] * local[2, c]
                pos[i, j, r] = pos[i, parents[j], r] + (g[r, 0] * off[0] + g[r, 1] * off[1] + g[r, 2] * off[2])
    return glob, pos
