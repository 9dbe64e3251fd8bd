"""LIP inference: frames in L in, poses in L out, frame by frame (streaming) or a whole sequence at once.

:class:`LipModel` wraps a :class:`~lip_ros.lip.nets.models.LipNet` with the
preprocessing (:class:`~lip_ros.lip.nets.preprocess.Preprocessor`) and the way
back from the view frame V to L. ``step`` carries the GRU states (and the
last point mean) from frame to frame, ``stream`` does the same for several
frames in one forward (batch tools); ``run`` feeds a whole sequence through
one batched forward. All give the same numbers (up to float rounding).
The recurrent networks learned motion at the rate of their training sequences
(``LipConfig.rate_hz``, 10 Hz); a LiDAR n times as fast (``lidar_rate_hz``:
an OS1 at 20 Hz) is fed to them as n interleaved sequences, frame k continuing
frame k - n's, so that each sees its frames as far apart as in training (fed
as one sequence, a 20 Hz capture's MPJPE was 23.7 mm against 15.6 mm at 10 Hz).
The published joints are forward kinematics of the estimated rotations on
the contract skeleton, scaled by the body scale that best fits the refined
joint map over the sequence so far (least squares), so joints and rotations
always agree; the translation is then fitted to the points
(:mod:`lip_ros.lip.surface_fit`, on by default).
Latency of ``step``: none beyond its own compute, every output uses frames up
to the current one only.

Weights are a plain ``state_dict`` file (``<name>.pt``, loadable with
``torch.load(..., weights_only=True)``; float32, or float16 for the shipped
ones, loaded into float32) beside a JSON :class:`LipConfig` (``<name>.json``)
and their SHA-256 (``<name>.sha256``, the ``sha256sum`` format: both files),
which :meth:`LipModel.load` checks before it reads either (:class:`WeightsError`
if it is missing or does not match: weights changed or swapped on the way are
never loaded); :meth:`LipModel.save` writes all three.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lip_ros.core.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from lip_ros.core.skeleton import forward_kinematics, load_skeleton
from lip_ros.core.torch_kinematics import six_d_to_matrix
from lip_ros.lip.nets.config import LipConfig
from lip_ros.lip.nets.models import LipNet, State
from lip_ros.lip.nets.preprocess import FrameInput, Preprocessor
from lip_ros.lip.sensors import IMU_NAMES
from lip_ros.lip.surface_fit import SURFACE_FIT, SurfaceFitConfig, SurfaceFitter
from lip_ros.resources import params_dir

__all__ = ["LipOutput", "LipModel", "SHIPPED_WEIGHTS", "BONE_TOLERANCE_DEG", "stack_frames", "WeightsError",
           "check_weights"]

class WeightsError(ValueError):
    """Weights whose SHA-256 file is missing or does not match them."""


def _weight_files(path: Path) -> tuple[Path, Path]:
    return path.with_suffix(".pt"), path.with_suffix(".json")


def _sha256(file: Path) -> str:
    digest = hashlib.sha256()
    with open(file, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def check_weights(path: str | Path) -> None:
    """Check ``<path>.pt`` and ``<path>.json`` against ``<path>.sha256``; :class:`WeightsError` if it is missing,
    lacks one of them or does not match."""
    path = Path(path)
    sums = path.with_suffix(".sha256")
    try:
        lines = [line.split(maxsplit=1) for line in sums.read_text(encoding="utf-8").splitlines() if line.strip()]
    except OSError as exc:
        raise WeightsError(f"{sums}: cannot read the weights' SHA-256 ({exc.strerror}); weights are only loaded "
                           f"with it (LipModel.save writes it; for weights of your own: "
                           f"cd {path.parent} && sha256sum {path.stem}.pt {path.stem}.json > {sums.name})") from None
    if any(len(parts) != 2 or re.fullmatch(r"[0-9a-fA-F]{64}", parts[0]) is None for parts in lines):
        raise WeightsError(f"{sums}: not in the sha256sum format (<hex>  <file name> per line)")
    listed = {name.strip().lstrip("*"): digest.lower() for digest, name in lines}  # "*": sha256sum -b
    for file in _weight_files(path):
        if file.name not in listed:
            raise WeightsError(f"{sums} has no SHA-256 of {file.name}")
        if _sha256(file) != listed[file.name]:
            raise WeightsError(f"{file} does not match its SHA-256 in {sums}: not loaded")


#: Stem of the shipped weights in the package's ``params/weights/``.
SHIPPED_WEIGHTS = "lip_small"
#: How far (deg) an instrumented bone may be from its IMU's calibrated orientation (docs/lip/transfer.md).
BONE_TOLERANCE_DEG = 5.0


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


def _measured_bones(rot: np.ndarray, imu_rot: np.ndarray, tolerance_deg: float) -> np.ndarray:
    """``rot`` (T, 24, 3, 3) with each instrumented bone's global rotation brought within ``tolerance_deg`` of
    its calibrated measurement ``imu_rot`` (T, 4, 3, 3) (turned towards it by the excess, about the axis
    between them; frames where the measurement is not finite keep the network's); the bones below it follow."""
    skeleton = load_skeleton()
    glob, _ = forward_kinematics(skeleton, rot)
    rot = rot.copy()
    limit = np.radians(tolerance_deg)
    # all four bones at once (none is another's ancestor, so each one's parent is the network's)
    bones = np.array([skeleton.index(skeleton.lip_imus[name]["bone_joint"]) for name in IMU_NAMES])
    ok = np.isfinite(imu_rot).all(axis=(-2, -1))  # (T, 4)
    measured = imu_rot[ok]
    away = matrix_to_axis_angle(np.swapaxes(measured, -1, -2) @ glob[:, bones][ok])  # network's bone in the measured
    angle = np.linalg.norm(away, axis=-1, keepdims=True)
    target = measured @ axis_angle_to_matrix(away * np.minimum(1.0, limit / np.maximum(angle, 1e-12)))
    measured_bones = rot[:, bones]
    measured_bones[ok] = np.swapaxes(glob[:, skeleton.parents[bones]][ok], -1, -2) @ target
    rot[:, bones] = measured_bones
    return rot


def _to_lidar(out: dict[str, torch.Tensor], frames: Sequence[FrameInput], scale: _ScaleTracker,
              imu_rot: np.ndarray, bone_tolerance_deg: float, clouds: Sequence[np.ndarray],
              fitter: SurfaceFitter | None) -> LipOutput:
    """Map the (1, T, ...) outputs in V back to L; the instrumented bones within ``bone_tolerance_deg`` of
    ``imu_rot`` (T, 4, 3, 3) (inf: the network's); joints by forward kinematics on the scaled skeleton; the
    translation fitted to the ``clouds`` by ``fitter`` (None: the network's)."""
    R = np.stack([f.R_L_V for f in frames])  # (T, 3, 3)
    mean = np.stack([f.mean for f in frames])
    rot = six_d_to_matrix(out["rot6d"][0].double()).numpy()
    rot[:, 0] = R @ rot[:, 0]
    if np.isfinite(bone_tolerance_deg):
        rot = _measured_bones(rot, imu_rot, bone_tolerance_deg)
    _, unit = forward_kinematics(load_skeleton(), rot)
    body_scale = scale.update(unit, np.einsum("tab,tjb->tja", R, out["joints"][0].double().numpy()))
    translation = mean + np.einsum("tab,tb->ta", R, out["offset"][0].double().numpy())
    if fitter is not None:
        translation = np.stack([fitter.fit(c, r, s, t).translation
                                for c, r, s, t in zip(clouds, rot, body_scale, translation, strict=True)])
    return LipOutput(
        joints=unit * body_scale[:, None, None],
        local_rot=rot,
        translation=translation,
        present=np.array([f.present for f in frames]),
        body_scale=body_scale,
    )


class LipModel:
    """A LIP network with its preprocessing and streaming state.

    The four instrumented bones (forearms, shanks) are kept within ``bone_tolerance_deg`` of the orientation
    their calibrated IMU measures: where a sensor gives a quantity directly, the network's prior cannot take
    the output far from it (0: the measurement itself; inf: the network's estimate; docs/lip/transfer.md).
    """

    def __init__(self, net: LipNet, bone_tolerance_deg: float = BONE_TOLERANCE_DEG,
                 surface_fit: SurfaceFitConfig | None = SURFACE_FIT, lidar_rate_hz: float | None = None) -> None:
        self.net = net.eval()
        self.bone_tolerance_deg = float(bone_tolerance_deg)
        self.surface_fit = surface_fit
        self._fitter = SurfaceFitter(surface_fit) if surface_fit is not None else None
        self.config: LipConfig = net.config
        if lidar_rate_hz is not None and not lidar_rate_hz > 0:
            raise ValueError(f"lidar_rate_hz must be > 0, got {lidar_rate_hz}")
        #: interleaved sequences the frames are fed as (the LiDAR's rate over the training's, at least 1)
        self.interleave = self.interleave_for(lidar_rate_hz or self.config.rate_hz)
        self._pres = self._preprocessors()
        self._states: list[State | None] = [None] * self.interleave
        self._turn = 0  # the sequence of the next frame
        self._scale = _ScaleTracker()

    @classmethod
    def load(cls, path: str | Path | None = None, bone_tolerance_deg: float = BONE_TOLERANCE_DEG,
             surface_fit: SurfaceFitConfig | None = SURFACE_FIT, lidar_rate_hz: float | None = None) -> LipModel:
        """Load ``<path>.pt`` and ``<path>.json`` (default: the shipped weights); the other arguments as the
        constructor's."""
        path = Path(path) if path is not None else params_dir() / "weights" / SHIPPED_WEIGHTS
        check_weights(path)
        net = LipNet(LipConfig.load(path.with_suffix(".json")))
        net.load_state_dict(torch.load(path.with_suffix(".pt"), map_location="cpu", weights_only=True))
        return cls(net, bone_tolerance_deg, surface_fit, lidar_rate_hz)

    def interleave_for(self, lidar_rate_hz: float) -> int:
        """How many interleaved sequences frames at ``lidar_rate_hz`` are fed as: the rate over the training's,
        rounded, at least 1."""
        return max(1, round(lidar_rate_hz / self.config.rate_hz))

    def for_rate(self, lidar_rate_hz: float) -> LipModel:
        """The same network and settings for a LiDAR at ``lidar_rate_hz``, with a streaming state of its own."""
        return LipModel(self.net, self.bone_tolerance_deg, self.surface_fit, lidar_rate_hz)

    def _preprocessors(self) -> list[Preprocessor]:
        return [Preprocessor(self.config.num_points) for _ in range(self.interleave)]

    def save(self, path: str | Path, float16: bool = False) -> None:
        """Write ``<path>.pt`` (state_dict on the CPU, floats as float32, or float16: half the file) and
        ``<path>.json``."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        dtype = torch.float16 if float16 else torch.float32
        state = {k: v.to("cpu", dtype) if v.is_floating_point() else v.cpu() for k, v in self.net.state_dict().items()}
        torch.save(state, path.with_suffix(".pt"))
        self.config.save(path.with_suffix(".json"))
        path.with_suffix(".sha256").write_text("".join(f"{_sha256(f)}  {f.name}\n" for f in _weight_files(path)),
                                                encoding="utf-8")

    @property
    def performer_shape(self) -> dict[str, float]:
        """The streamed performer's shape as the surface fit sees it so far (girths and bone lengths, 1 = the
        contract body); empty without the fit."""
        if self._fitter is None:
            return {}
        return {k: round(float(v), 3) for k, v in zip(self._fitter.shape_names, self._fitter.shape, strict=True)}

    def reset(self) -> None:
        """Start a new sequence: forget the recurrent states, the last point means, the body scale and shape."""
        for pre in self._pres:
            pre.reset()
        self._states = [None] * self.interleave
        self._turn = 0
        self._scale = _ScaleTracker()
        if self._fitter is not None:
            self._fitter.reset()

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
        result, self._states = self._forward(self._pres, clouds, imu_rot, imu_acc, self._states, self._turn,
                                             self._scale, self._fitter)
        self._turn = (self._turn + len(clouds)) % self.interleave
        return result

    def run(self, clouds: Sequence[np.ndarray], imu_rot: np.ndarray, imu_acc: np.ndarray) -> LipOutput:
        """A whole sequence from its start: T clouds (N_t, 3), (T, 4, 3, 3), (T, 4, 3); outputs with a leading T.

        Independent of (and not changing) the streaming state of ``step``.
        """
        fitter = SurfaceFitter(self.surface_fit) if self.surface_fit is not None else None
        return self._forward(self._preprocessors(), clouds, imu_rot, imu_acc, [None] * self.interleave, 0,
                             _ScaleTracker(), fitter)[0]

    @torch.inference_mode()  # as no_grad, and no version counters or views tracked: a tenth off a step
    def _forward(self, pres: list[Preprocessor], clouds: Sequence[np.ndarray], imu_rot: Sequence[np.ndarray],
                 imu_acc: Sequence[np.ndarray], states: list[State | None], turn: int, scale: _ScaleTracker,
                 fitter: SurfaceFitter | None) -> tuple[LipOutput, list[State | None]]:
        """Frames through the network as its interleaved sequences (frame k in sequence ``(turn + k) % n``, each
        through its preprocessor of ``pres`` from its state of ``states``); the outputs in L, in the frames'
        order, and the states after them.

        A bone whose acceleration is not finite is held for a silent sensor
        (:class:`lip_ros.lip.stages.BoneFrame`): its rotation is the network's input (acceleration 0), not a
        measurement the output is kept near."""
        imu_acc = np.array(imu_acc, dtype=np.float64).reshape(-1, len(IMU_NAMES), 3)
        held = ~np.isfinite(imu_acc).all(axis=-1)  # (T, 4)
        imu_acc[held] = 0.0
        inputs: dict[int, FrameInput] = {}
        order, parts, states = [], [], list(states)
        for s in range(len(pres)):
            ks = [k for k in range(len(clouds)) if (turn + k) % len(pres) == s]
            if not ks:
                continue
            inputs.update((k, pres[s](clouds[k], imu_rot[k], imu_acc[k])) for k in ks)
            out, states[s] = self.net(*stack_frames([inputs[k] for k in ks]), states[s])
            order += ks
            parts.append(out)
        frames = [inputs[k] for k in range(len(clouds))]
        inverse = torch.from_numpy(np.argsort(order))
        out = {key: torch.cat([part[key] for part in parts], dim=1)[:, inverse] for key in parts[0]}
        imu_rot = np.array(imu_rot, dtype=np.float64).reshape(-1, len(IMU_NAMES), 3, 3)
        imu_rot[held] = np.nan  # not kept near: see _measured_bones
        return _to_lidar(out, frames, scale, imu_rot, self.bone_tolerance_deg, clouds, fitter), states
