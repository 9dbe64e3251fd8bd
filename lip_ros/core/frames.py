"""Physical constants and fixed frame relations shared by the core and the rig (see docs/conventions.md)."""

from __future__ import annotations

import numpy as np

from lip_ros.core.rotations import rot_z

#: Standard gravity (m/s^2), as the contract states (+9.81 up at rest).
GRAVITY = 9.81

#: Orientation in L of an upright body (frame M) facing +x of L: model z -> x, y -> z, x -> y.
#: A body with heading h (its forward direction's azimuth in L) has ``Rz(h) @ R_L_M_FACING_X``.
R_L_M_FACING_X = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

#: Up along the body in the model frame M (x left, y up, z forward): its y. Read-only.
UP_M = np.array([0.0, 1.0, 0.0])
UP_M.flags.writeable = False


def level_rotation(up: np.ndarray) -> np.ndarray:
    """R_L_P (3, 3): the level frame P of a sensor frame L whose gravity-up direction in L is ``up`` (3,): P's z
    is ``up``, and P is L turned by the smallest rotation that does it (so P keeps L's heading as far as a level
    frame can). The identity when ``up`` is L's z."""
    z = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    axis = np.cross([0.0, 0.0, 1.0], z)  # sin(angle) * unit axis
    c = float(z[2])
    if c <= -1.0 + 1e-12:
        raise ValueError(f"up {up} points down: no level frame")
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + k + k @ k / (1.0 + c)  # Rodrigues for the rotation taking z onto up


def hip_lidar_rotation(tilt_up_deg: float, spin_deg: float = 0.0) -> np.ndarray:
    """R_M_L (3, 3): a LiDAR worn on the hip, in the pelvis frame M (the HSC4D rig): its +x where the body faces,
    its z up the body, then tilted up by ``tilt_up_deg`` (about its own y axis: +x rises), then turned by
    ``spin_deg`` about its own z, the spin axis (where its +x, an Ouster's connector and column 0, points: a
    sensor worn with its connector down the leg or to the back is the same tilt with another spin)."""
    t = np.radians(tilt_up_deg)
    c, s = np.cos(t), np.sin(t)
    return R_L_M_FACING_X.T @ np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]]) @ rot_z(np.radians(spin_deg))
