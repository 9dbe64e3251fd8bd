"""LIP inference: frames in L in, poses in L out, frame by frame (streaming) or a whole sequence at once.

:class:`LipModel` wraps a :class:`~lip_ros.lip.nets.models.LipNet` with the
preprocessing (:class:`~lip_ros.lip.nets.preprocess.Preprocessor`) and the way
back from the view frame V to L. ``step`` carries the GRU states (and the
last point mean) from frame to frame, ``stream`` does the same for several
frames in one forward (batch tools); ``run`` feeds a whole sequence through
one batched forward. All give the same numbers (up to float rounding).
The published joints are forward kinematics of the estimated rotations on
the contract skeleton, scaled by the body scale that best fits the refined
joint map over the sequence so far (least squares), so joints and rotations
always agree.
Latency of ``step``: none beyond its own compute, every output uses frames up
to the current one only.

Weights are a plain ``state_dict`` file (``<name>.pt``, loadable with
``torch.load(..., weights_only=True)``; float32, or float16 for the shipped
ones, loaded into float32) beside a JSON :class:`LipConfig` (``<name>.json``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lip_ros.core.skeleton import forward_kinematics, load_skeleton
from lip_ros.core.torch_kinematics import six_d_to_matrix
from lip_ros.lip.nets.config import LipConfig
from lip_ros.lip.nets.models import LipNet, State
from lip_ros.lip.nets.preprocess import FrameInput, Preprocessor
from lip_ros.resources import params_dir

__all__ = ["LipOutput", "LipModel", "SHIPPED_WEIGHTS", "stack_frames"]

#: Stem of the shipped weights in the package's ``params/weights/``.
SHIPPED_WEIGHTS = "lip_small"


@dataclass(frozen=True)
class LipOutput:
    """Poses in L, for one frame or with a leading time axis T."""

    joints: np.ndarray  # (..., 24, 3) root-relative joint positions, axes of L: FK of local_rot, scaled skeleton
    local_rot: np.ndarray  # (..., 24, 3, 3) local rotations, [0] = pelvis orientation in L
    translation: np.ndarray  # (..., 3) pelvis position in L (NaN until the performer was seen once)
    present: np.ndarray  # (...,) bool, the frame had performer points
    body_scale: np.ndarray  # (...,) estimated skeleton scale (contract skeleton = 1), running mean so far


@dataclass
class _ScaleTracker:
    """Least-squares body scale over the sequence so far: the s minimising |s P - J|^2 summed over frames and
    joints, P the root-relative joints of the estimated rotations on the contract skeleton, J the refined
    joint map (unbiased by noise in J, unlike a ratio of bone lengths)."""

    num: float = 0.0
    den: float = 0.0

    def update(self, unit: np.ndarray, joint_map: np.ndarray) -> np.ndarray:
        """(T,) scales after each frame of (T, 24, 3) unit-skeleton joints and joint maps."""
        num = self.num + np.cumsum(np.einsum("tjk,tjk->t", unit, joint_map))
        den = self.den + np.cumsum(np.einsum("tjk,tjk->t", unit, unit))
        self.num, self.den = float(num[-1]), float(den[-1])
        return num / den


def stack_frames(frames: Sequence[FrameInput]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Network inputs (1, T, N, 3), (1, T, F), (1, T, 48) from preprocessed frames."""
    return tuple(torch.from_numpy(np.stack([getattr(f, k) for f in frames]))[None] for k in ("points", "frame", "imu"))


def _to_lidar(out: dict[str, torch.Tensor], frames: Sequence[FrameInput], scale: _ScaleTracker) -> LipOutput:
    """Map the (1, T, ...) outputs in V back to L; joints by forward kinematics on the scaled skeleton."""
    R = np.stack([f.R_L_V for f in frames])  # (T, 3, 3)
    mean = np.stack([f.mean for f in frames])
    rot = six_d_to_matrix(out["rot6d"][0].double()).numpy()
    rot[:, 0] = R @ rot[:, 0]
    _, unit = forward_kinematics(load_skeleton(), rot)
    body_scale = scale.update(unit, np.einsum("tab,tjb->tja", R, out["joints"][0].double().numpy()))
    offset = np.einsum("tab,tb->ta", R, out["offset"][0].double().numpy())
    return LipOutput(
        joints=unit * body_scale[:, None, None],
        local_rot=rot,
        translation=mean + offset,
        present=np.array([f.present for f in frames]),
        body_scale=body_scale,
    )


class LipModel:
    """A LIP network with its preprocessing and streaming state."""

    def __init__(self, net: LipNet) -> None:
        self.net = net.eval()
        self.config: LipConfig = net.config
        self._pre = Preprocessor(self.config.num_points)
        self._state: State | None = None
        self._scale = _ScaleTracker()

    @classmethod
    def load(cls, path: str | Path | None = None) -> LipModel:
        """Load ``<path>.pt`` and ``<path>.json`` (default: the shipped weights)."""
        path = Path(path) if path is not None else params_dir() / "weights" / SHIPPED_WEIGHTS
        net = LipNet(LipConfig.load(path.with_suffix(".json")))
        net.load_state_dict(torch.load(path.with_suffix(".pt"), map_location="cpu", weights_only=True))
        return cls(net)

    def save(self, path: str | Path, float16: bool = False) -> None:
        """Write ``<path>.pt`` (state_dict, floats as float32, or float16: half the file) and ``<path>.json``."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        dtype = torch.float16 if float16 else torch.float32
        state = {k: v.to(dtype) if v.is_floating_point() else v for k, v in self.net.state_dict().items()}
        torch.save(state, path.with_suffix(".pt"))
        self.config.save(path.with_suffix(".json"))

    def reset(self) -> None:
        """Start a new sequence: forget the recurrent state, the last point mean and the body scale."""
        self._pre.reset()
        self._state = None
        self._scale = _ScaleTracker()

    def step(self, points: np.ndarray, imu_rot: np.ndarray, imu_acc: np.ndarray) -> LipOutput:
        """One LiDAR frame: performer points (N, 3) in L (N may be 0), bone rotations (4, 3, 3) and free
        accelerations (4, 3) in L at the frame's pose time, order ``IMU_NAMES``; the pose at that time."""
        result = self.stream([points], [imu_rot], [imu_acc])
        return LipOutput(*(getattr(result, k)[0] for k in LipOutput.__dataclass_fields__))

    def stream(self, clouds: Sequence[np.ndarray], imu_rot: Sequence[np.ndarray], imu_acc: Sequence[np.ndarray]
               ) -> LipOutput:
        """The next T frames of the streamed sequence in one forward: ``step`` of each in turn (up to float
        rounding); T clouds (N_t, 3), (T, 4, 3, 3), (T, 4, 3); outputs with a leading T."""
        if self.config.bidirectional:
            raise ValueError("a bidirectional (offline) model cannot stream; use run()")
        result, self._state = self._forward(self._pre, clouds, imu_rot, imu_acc, self._state, self._scale)
        return result

    def run(self, clouds: Sequence[np.ndarray], imu_rot: np.ndarray, imu_acc: np.ndarray) -> LipOutput:
        """A whole sequence from its start: T clouds (N_t, 3), (T, 4, 3, 3), (T, 4, 3); outputs with a leading T.

        Independent of (and not changing) the streaming state of ``step``.
        """
        return self._forward(Preprocessor(self.config.num_points), clouds, imu_rot, imu_acc, None, _ScaleTracker())[0]

    @torch.no_grad()
    def _forward(self, pre: Preprocessor, clouds: Sequence[np.ndarray], imu_rot: Sequence[np.ndarray],
                 imu_acc: Sequence[np.ndarray], state: State | None, scale: _ScaleTracker) -> tuple[LipOutput, State]:
        """Frames through ``pre`` and the network from ``state``; the outputs in L and the state after them."""
        frames = [pre(p, r, a) for p, r, a in zip(clouds, imu_rot, imu_acc, strict=True)]
        out, state = self.net(*stack_frames(frames), state)
        return _to_lidar(out, frames, scale), state
