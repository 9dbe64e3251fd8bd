"""How the package's hot loops are compiled with numba: the options and the argument types they share.

The compiled modules (:mod:`lip_ros.core.capsule_rays`, :mod:`lip_ros.core.kinematics_kernel`,
:mod:`lip_ros.lip.surface_kernel`, :mod:`lip_ros.lip.segmentation.clusters`) give the functions Python calls their
types, so each is compiled, or loaded from numba's cache on disk, when its module is imported: never on a first
frame. The cache lies beside the sources (``NUMBA_CACHE_DIR`` moves it); it takes some seconds to fill after an
install or a change to a module, a fraction of a second to load (``make kernels`` fills it). numba notices a
change to a compiled function's own file only: a compiled function therefore calls no compiled function of
another module (the Python code between them does).
"""

from __future__ import annotations

from numba import types

__all__ = ["COMPILE", "array_in"]

#: numba's options for every compiled function of the package: cached on disk, the GIL released while it runs.
COMPILE = {"cache": True, "nogil": True}


def array_in(ndim: int, dtype: types.Type = types.float64) -> types.Array:
    """The numba type of an input array a compiled function only reads: any layout, read-only or not."""
    return types.Array(dtype, ndim, "A", readonly=True)
