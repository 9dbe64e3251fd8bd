"""The legs' length from the walk (ROS-free).

While a foot stands, the pelvis moves over it only by the legs' turn: between two frames that foot stands in, the
fused pelvis's step (the LiDAR's, in ``map``) equals minus the change of the foot's offset from the pelvis, which
the suit's joint rotations give on the skeleton's bones. Their ratio is how much longer the legs are than the bones
the suit's body was given. That size came from the standing pelvis's height above the ground, through the hip
LiDAR's lever arm, whose part along the body the walk cannot measure (nominal, up to 3 cm off on the rig: 2-4 %
of the body's size); the walk's ratio does not need it: on the rig, within 0.6 % of the truth over a 90 s
capture, within 2 % over its first 10 s (docs/hsc4d/optimisation.md "The legs' length from the walk").

Each pair counts by Tukey's biweight of its residual (the pelvis's step less the legs' at the ratio): a foot the
suit calls standing as it lifts (20-40 cm a frame at a stance's edge), a registration's jump, count for nothing.
Iteratively reweighted least squares from a ratio of 1 (the size the body was given, a few per cent off at most):
from the plain least squares such pairs took the ratio 60-70 % off on a walk where a third of the stance pairs were
a lifting foot's, from 1 within 0.5 % (test_leg_scale.py). The newest :attr:`LegScaleConfig.capacity` pairs are
kept.

What it cannot tell apart: an error of the legs' sensors that moves the foot along the walk in step with it (a
2 deg swing of the hips' rotations at 1.7 Hz took a 10 s walk's ratio to 1.06, 1 deg to 1.015; the rig's suit
errors are slow and gave none of that), and noise on the legs' rotations, which biases the ratio low by the
noise's square over the legs' step's (0.1 % at 0.2 deg a frame, 2 % at 1 deg).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["LegScaleConfig", "LegScale", "standing_steps"]


@dataclass(frozen=True)
class LegScaleConfig:
    """How many pairs of standing frames make an estimate, how they are weighed, and how many are kept."""

    #: pairs whose legs turned by at least ``min_step_m`` before the ratio is believed (10 s of walking at 10 Hz
    #: give about 60)
    min_pairs: int = 50
    min_step_m: float = 0.01  # a pair whose foot's offset changed less tells nothing of the ratio (standing still)
    outlier_m: float = 0.03  # a pair's residual (the pelvis's step less the legs') beyond this counts for nothing
    capacity: int = 4096  # pairs kept, the newest (about 7 minutes of walking at 10 Hz)
    bounds: tuple[float, float] = (0.8, 1.25)  # a ratio outside is not believed (the legs' sensors, not the size)
    iterations: int = 10  # reweightings

    def __post_init__(self) -> None:
        if not (self.min_pairs >= 1 and self.min_step_m > 0.0 and self.outlier_m > 0.0 and self.capacity >= 1
                and 0.0 < self.bounds[0] < 1.0 < self.bounds[1] and self.iterations >= 1):
            raise ValueError(f"invalid {self}")


def standing_steps(pelvis: np.ndarray, offsets: np.ndarray, stance: np.ndarray, pairs: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The pelvis's steps (M, 3) and the standing foot's offset's changes (M, 3) between consecutive frames of N
    in which that foot stands in both: pelvis positions (N, 3), each foot's offset from the pelvis (N, 2, 3) at
    the bones' size, which foot stands (N, 2); ``pairs`` (N - 1,) bool: only those consecutive pairs (None: all)."""
    both = stance[1:] & stance[:-1]  # (N - 1, 2)
    if pairs is not None:
        both &= np.asarray(pairs, dtype=bool)[:, None]
    steps = np.diff(pelvis, axis=0)[:, None, :].repeat(2, axis=1)
    return steps[both], np.diff(offsets, axis=0)[both]


class LegScale:
    """The ratio of the legs' length to the bones' (:func:`standing_steps`' pairs, module docstring)."""

    def __init__(self, config: LegScaleConfig | None = None) -> None:
        self.config = c = config or LegScaleConfig()
        self._pairs: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=c.capacity)
        self._fitted: tuple[float | None] | None = None  # the ratio of the pairs as they are, once asked

    def __len__(self) -> int:
        return len(self._pairs)

    def add(self, pelvis_steps: np.ndarray, leg_steps: np.ndarray) -> int:
        """Pairs of the pelvis's step (M, 3) and its standing foot's offset's change (M, 3); those whose legs
        turned (``min_step_m``) and are finite are kept; how many."""
        pelvis_steps, leg_steps = (np.asarray(a, dtype=np.float64).reshape(-1, 3) for a in (pelvis_steps,
                                                                                           leg_steps))
        keep = (np.isfinite(pelvis_steps).all(1) & np.isfinite(leg_steps).all(1)
                & (np.linalg.norm(leg_steps, axis=1) >= self.config.min_step_m))
        self._pairs.extend(zip(pelvis_steps[keep], leg_steps[keep], strict=True))
        if keep.any():
            self._fitted = None
        return int(keep.sum())

    @property
    def ratio(self) -> float | None:
        """The legs' length over the bones' (the pelvis steps by minus that times the offset's change), None
        before ``min_pairs`` pairs, with fewer than that within ``outlier_m`` of the fit, or outside ``bounds``."""
        if self._fitted is None:
            self._fitted = (self._fit(),)
        return self._fitted[0]

    def _fit(self) -> float | None:
        c = self.config
        if len(self._pairs) < c.min_pairs:
            return None
        steps, legs = (np.array(a) for a in zip(*self._pairs, strict=True))
        ratio = 1.0
        for _ in range(c.iterations):
            residual = np.linalg.norm(steps + ratio * legs, axis=1)
            weights = np.clip(1.0 - (residual / c.outlier_m) ** 2, 0.0, None) ** 2
            if np.count_nonzero(weights) < c.min_pairs:
                return None
            ratio = float(-np.einsum("k,ka,ka->", weights, legs, steps) / np.einsum("k,ka,ka->", weights, legs, legs))
        return ratio if c.bounds[0] <= ratio <= c.bounds[1] else None
