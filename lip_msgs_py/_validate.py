"""Shape, finiteness and unit-quaternion checks shared by the converters."""

from __future__ import annotations

from typing import Any

import numpy as np

from lip_msgs_py.errors import MalformedMessageError

#: Largest accepted deviation of a quaternion's norm from 1; closer ones are normalised.
QUAT_UNIT_TOLERANCE = 1e-3


def finite_array(value: Any, shape: tuple[int | None, ...], what: str) -> np.ndarray:
    """``value`` as a new finite float64 array of ``shape`` (None: any length on that axis)."""
    try:
        arr = np.array(value, dtype=np.float64)  # a copy: never a view of a message
    except (TypeError, ValueError) as exc:
        raise MalformedMessageError(f"{what}: not numeric ({exc})") from None
    if arr.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, arr.shape)):
        want = "(" + ", ".join("N" if n is None else str(n) for n in shape) + ("," if len(shape) == 1 else "") + ")"
        raise MalformedMessageError(f"{what}: expected shape {want}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise MalformedMessageError(f"{what}: non-finite values at {np.argwhere(~np.isfinite(arr)).tolist()[:5]}")
    return arr


def unit_quaternions(
    value: Any, shape: tuple[int | None, ...], what: str, tolerance: float = QUAT_UNIT_TOLERANCE
) -> np.ndarray:
    """``value`` (shape + (4,), xyzw) normalised; zero or farther than ``tolerance`` from unit raises."""
    quat = finite_array(value, shape + (4,), what)
    norm = np.linalg.norm(quat, axis=-1, keepdims=True)
    if (norm == 0.0).any():
        raise MalformedMessageError(f"{what}: zero quaternion")
    bad = np.abs(norm[..., 0] - 1.0) > tolerance
    if bad.any():
        raise MalformedMessageError(
            f"{what}: quaternion norm {norm[..., 0][bad].ravel()[0]:.6g} is not 1 (tolerance {tolerance:g})"
        )
    return quat / norm


def covariance_matrix(value: Any, n: int, what: str) -> np.ndarray:
    """(n, n) covariance from n*n row-major values or an (n, n) array; None = unknown (zeros)."""
    if value is None:
        return np.zeros((n, n))
    return finite_array(np.ravel(value), (n * n,), f"{what} covariance").reshape(n, n)
