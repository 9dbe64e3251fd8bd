"""The static scene seen by a static LiDAR: a per-pixel background range image.

Part of the performer segmentation (:mod:`lip_ros.lip.segmentation`), ROS-free.

The ground is one plane, fitted robustly to returns below the sensor
(:func:`lip_ros.core.ground_plane.fit_ground_plane`). The background is learned online per pixel of the
organized range image: the *farthest surface seen consistently*. A pixel's
background starts unknown (0); a return farther than the background (or any
return while it is unknown) becomes a candidate, and a candidate seen in
``confirm_frames`` consecutive returns of the pixel replaces the background. A
nearer candidate (something placed in the scene) only replaces it after
``absorb_frames``, so people, who move, never become background; a performer
who stands still from the first frame does, until the caller ``forget``s those
pixels once it has found the performer. No-return pixels (range 0) change
nothing. A return that matches no known background (unknown, or farther) is
not background either: what was learned there may have been a person who
stood still for a moment in front of the open sky.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BackgroundModel"]


class BackgroundModel:
    """Per-pixel background range (metres, 0 = unknown) of an organized LiDAR, learned online."""

    def __init__(
        self, shape: tuple[int, int], margin_m: float, margin_per_m: float, confirm_frames: int, absorb_frames: int
    ) -> None:
        self.shape = shape
        self.range = np.zeros(shape, dtype=np.float32)
        self._candidate = np.zeros(shape, dtype=np.float32)
        self._count = np.zeros(shape, dtype=np.uint16)
        self._margin = (np.float32(margin_m), np.float32(margin_per_m))
        self._confirm = confirm_frames
        self._absorb = absorb_frames

    def margin(self, range_m: np.ndarray) -> np.ndarray:
        """Range difference (m) that separates two surfaces at ``range_m``."""
        return self._margin[0] + self._margin[1] * range_m

    def classify(self, range_m: np.ndarray, cols: np.ndarray | slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """Masks (nearer, unexplained) (H, C) of the returns ``range_m`` (0 = none) in columns ``cols``: nearer
        than a known background by the margin; matching no background otherwise (unknown, or farther: what was
        taken for background has left)."""
        bg = self.range[:, cols]
        seen = range_m > 0.0
        margin = self.margin(bg)
        nearer = seen & (range_m < bg - margin)
        return nearer, seen & ~nearer & ((bg == 0.0) | (range_m > bg + margin))

    def update(self, range_m: np.ndarray, exclude: np.ndarray) -> None:
        """Learn from a full range image (H, W) (0 = no return), except at pixels ``exclude`` (H, W) bool."""
        bg, cand, count = self.range.reshape(-1), self._candidate.reshape(-1), self._count.reshape(-1)
        r = range_m.reshape(-1)
        seen = (r > 0.0) & ~exclude.reshape(-1)
        new = seen & ((np.abs(r - bg) > self.margin(np.maximum(r, bg))) | (bg == 0.0))
        count[np.flatnonzero(seen & ~new & (count > 0))] = 0  # the background again: a candidate must start over
        i = np.flatnonzero(new)
        ri, ci = r[i], count[i]
        repeat = (ci > 0) & (np.abs(ri - cand[i]) <= self.margin(ri))
        ci = np.where(repeat, np.minimum(ci, np.iinfo(np.uint16).max - 1) + 1, 1).astype(np.uint16)
        cand[i[~repeat]] = ri[~repeat]
        promote = ci >= np.where(cand[i] > bg[i], self._confirm, self._absorb)
        bg[i[promote]] = cand[i[promote]]
        ci[promote] = 0
        count[i] = ci

    def forget(self, mask: np.ndarray) -> None:
        """Make the background of pixels ``mask`` (H, W) bool unknown again."""
        self.range[mask] = 0.0
        self._count[mask] = 0
