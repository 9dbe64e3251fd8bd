"""The Ouster ``original`` point layout of the contract (point_step 48)."""

from __future__ import annotations

import numpy as np

#: x f32 @0, y f32 @4, z f32 @8, intensity f32 @16, t u32 @20 (ns after header.stamp),
#: reflectivity u16 @24, ring u16 @26, ambient u16 @28, range u32 @32 (mm); 48 bytes.
OUSTER_ORIGINAL_DTYPE = np.dtype(
    {
        "names": ["x", "y", "z", "intensity", "t", "reflectivity", "ring", "ambient", "range"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "<u2", "<u4"],
        "offsets": [0, 4, 8, 16, 20, 24, 26, 28, 32],
        "itemsize": 48,
    }
)
