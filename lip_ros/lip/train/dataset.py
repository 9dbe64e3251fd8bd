"""Rig sequences as network inputs and targets in the view frame, and random training windows of them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from lip_ros.lip.nets.losses import LossTargets
from lip_ros.lip.nets.preprocess import Preprocessor
from lip_ros.lip.train.rigdata import RigSequence

__all__ = ["PreparedSequence", "prepare", "blank_frames", "WindowSampler", "stack_prepared"]


@dataclass
class PreparedSequence:
    """One sequence through the :class:`Preprocessor`, with its targets in V (arrays with leading T)."""

    points: np.ndarray  # (T, N, 3) float32
    frame: np.ndarray  # (T, FRAME_FEATURES) float32
    imu: np.ndarray  # (T, IMU_FEATURES) float32
    joints: np.ndarray  # (T, 24, 3) root-relative
    local_rot: np.ndarray  # (T, 24, 3, 3), [0] in V
    offset: np.ndarray  # (T, 3) root minus point mean (0 where never seen)
    present: np.ndarray  # (T,) float32
    bone_offsets: np.ndarray  # (24, 3)

    def __len__(self) -> int:
        return len(self.points)


def blank_frames(num_frames: int, rng: np.random.Generator, rate: float = 0.01, max_len: int = 5) -> np.ndarray:
    """(T,) bool: bursts of 1..max_len frames (about ``rate`` bursts per frame) in which the performer is hidden."""
    blank = np.zeros(num_frames, dtype=bool)
    for start in rng.integers(0, num_frames, size=rng.poisson(rate * num_frames)):
        blank[start : start + rng.integers(1, max_len + 1)] = True
    return blank


def prepare(seq: RigSequence, num_points: int, blank: np.ndarray | None = None) -> PreparedSequence:
    """Preprocess every frame (frames where ``blank`` is set lose their points) and map the truth to V."""
    pre = Preprocessor(num_points)
    empty = np.zeros((0, 3), np.float32)
    frames = [
        pre(empty if blank is not None and blank[k] else seq.frame_points(k), seq.imu_rot[k], seq.imu_acc[k])
        for k in range(seq.num_frames)
    ]
    R_V_L = np.stack([f.R_L_V.T for f in frames])
    mean = np.stack([f.mean for f in frames])
    root = seq.root_pos.astype(np.float64)
    local_rot = seq.local_rot.astype(np.float64).copy()
    local_rot[:, 0] = R_V_L @ local_rot[:, 0]
    joints = np.einsum("tab,tjb->tja", R_V_L, seq.joint_pos - root[:, None])
    offset = np.nan_to_num(np.einsum("tab,tb->ta", R_V_L, root - mean))
    return PreparedSequence(
        points=np.stack([f.points for f in frames]),
        frame=np.stack([f.frame for f in frames]),
        imu=np.stack([f.imu for f in frames]),
        joints=joints.astype(np.float32),
        local_rot=local_rot.astype(np.float32),
        offset=offset.astype(np.float32),
        present=np.array([f.present for f in frames], dtype=np.float32),
        bone_offsets=seq.bone_offsets.astype(np.float32),
    )


def stack_prepared(items: list[PreparedSequence], start: list[int], length: int
                   ) -> tuple[tuple[torch.Tensor, ...], LossTargets]:
    """Network inputs (points, frame, imu) and targets of windows [start, start + length) as (B, T, ...) tensors."""

    def cat(name: str) -> torch.Tensor:
        return torch.from_numpy(np.stack([getattr(s, name)[a : a + length] for s, a in zip(items, start)]))

    inputs = (cat("points"), cat("frame"), cat("imu"))
    target = LossTargets(
        joints=cat("joints"), local_rot=cat("local_rot"), offset=cat("offset"), present=cat("present"),
        bone_offsets=torch.from_numpy(np.stack([s.bone_offsets for s in items])),
    )
    return inputs, target


class WindowSampler:
    """Random batches of ``window``-frame pieces of the training sequences (deterministic given its rng state)."""

    def __init__(self, sequences: list[PreparedSequence], window: int, batch: int, seed: int) -> None:
        if not sequences or min(len(s) for s in sequences) < window:
            raise ValueError(f"need sequences of at least {window} frames")
        self.sequences, self.window, self.batch = sequences, window, batch
        self.rng = np.random.default_rng(seed)

    def next(self) -> tuple[tuple[torch.Tensor, ...], LossTargets]:
        """One batch."""
        which = self.rng.integers(0, len(self.sequences), size=self.batch)
        items = [self.sequences[i] for i in which]
        start = [int(self.rng.integers(0, len(s) - self.window + 1)) for s in items]
        return stack_prepared(items, start, self.window)
