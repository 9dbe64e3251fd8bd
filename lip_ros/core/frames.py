"""Physical constants and fixed frame relations shared by the core and the rig (see docs/conventions.md)."""

from __future__ import annotations

import numpy as np

#: Standard gravity (m/s^2), as the contract states (+9.81 up at rest).
GRAVITY = 9.81

#: Orientation in L of an upright body (frame M) facing +x of L: model z -> x, y -> z, x -> y.
#: A body with heading h (its forward direction's azimuth in L) has ``Rz(h) @ R_L_M_FACING_X``.
R_L_M_FACING_X = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
