"""The LIP networks (paper section 4) on batches of sequences, with recurrent state for streaming.

All tensors are batch-first, (B, T, ...), in the view frame V of
:mod:`lip_ros.lip.nets.preprocess`:

* pose module: a PointNet-GRU encoder and MLP decoder give the pose prior
  (24 root-relative joints, root 6D); the joint-map estimator refines the
  joints with the IMUs, the body-pose estimator regresses 24 local rotations
  in 6D (the root's is its orientation in V);
* translation module: its own PointNet-GRU encoder, fused with the estimated
  rotations and refined joints (detached: the two modules are trained
  separately, as in the paper), regresses the offset from the point mean to
  the root (equation 8).

With unidirectional GRUs (the default) every output at t depends on inputs
up to t only, and ``forward`` returns the GRU states so that a sequence fed
in pieces (down to one frame at a time) gives the same outputs as fed whole.
"""

from __future__ import annotations

import torch
from torch import nn

from lip_ros.core.skeleton import NUM_JOINTS
from lip_ros.lip.nets.config import LipConfig
from lip_ros.lip.nets.preprocess import FRAME_FEATURES, IMU_FEATURES

__all__ = ["PointNet", "PointGruEncoder", "Estimator", "LipNet", "State"]

#: Recurrent state: one hidden tensor per GRU (None = zeros at the start of a sequence).
State = list[torch.Tensor | None]

_JOINT_FEATURES = 3 * NUM_JOINTS
_ROT_FEATURES = 6 * NUM_JOINTS


def _mlp(widths: list[int], last_relu: bool) -> nn.Sequential:
    layers: list[nn.Module] = []
    for k, (a, b) in enumerate(zip(widths[:-1], widths[1:])):
        layers.append(nn.Linear(a, b))
        if last_relu or k < len(widths) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class PointNet(nn.Module):
    """Shared per-point MLP and max pooling: (..., N, 3) -> (..., widths[-1])."""

    def __init__(self, widths: tuple[int, ...]) -> None:
        super().__init__()
        self.mlp = _mlp([3, *widths], last_relu=True)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """Max over the points of the per-point features."""
        return self.mlp(points).amax(dim=-2)


class _Gru(nn.Module):
    """A GRU layer stack that keeps its state, uni- or bidirectional (then ``hidden`` is split in two)."""

    def __init__(self, n_in: int, hidden: int, layers: int, bidirectional: bool) -> None:
        super().__init__()
        self.gru = nn.GRU(n_in, hidden // 2 if bidirectional else hidden, layers, batch_first=True,
                          bidirectional=bidirectional)

    def forward(self, x: torch.Tensor, h: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """Outputs (B, T, hidden) and the final state."""
        return self.gru(x, h)


class PointGruEncoder(nn.Module):
    """PointNet per frame, the frame scalars appended, then a GRU over time: (B, T, N, 3) -> (B, T, hidden)."""

    def __init__(self, widths: tuple[int, ...], hidden: int, layers: int, bidirectional: bool) -> None:
        super().__init__()
        self.pointnet = PointNet(widths)
        self.gru = _Gru(widths[-1] + FRAME_FEATURES, hidden, layers, bidirectional)

    def forward(self, points: torch.Tensor, frame: torch.Tensor, h: torch.Tensor | None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """Temporal features and the GRU state."""
        feat = self.pointnet(points) * frame[..., :1]  # no performer: no point features
        return self.gru(torch.cat([feat, frame], dim=-1), h)


class Estimator(nn.Module):
    """Three sequential GRUs with a skip connection from the input projection to the output head."""

    def __init__(self, n_in: int, n_out: int, hidden: int, bidirectional: bool) -> None:
        super().__init__()
        self.inp = nn.Linear(n_in, hidden)
        self.grus = nn.ModuleList(_Gru(hidden, hidden, 1, bidirectional) for _ in range(3))
        self.out = nn.Linear(hidden, n_out)

    def forward(self, x: torch.Tensor, state: State) -> tuple[torch.Tensor, State]:
        """Outputs (B, T, n_out) and the three GRU states."""
        skip = h = torch.relu(self.inp(x))
        new_state: State = []
        for gru, h0 in zip(self.grus, state):
            h, hn = gru(h, h0)
            new_state.append(hn)
        return self.out(h + skip), new_state


class LipNet(nn.Module):
    """Pose module (prior, joint-map and body-pose estimators) and translation module."""

    #: GRUs in the state list: prior encoder, 3 joint-map, 3 body-pose, translation encoder.
    NUM_STATES = 8

    def __init__(self, config: LipConfig) -> None:
        super().__init__()
        c = config
        self.config = c
        self.prior_encoder = PointGruEncoder(c.point_widths, c.prior_hidden, c.prior_layers, c.bidirectional)
        if c.variant == "no_prior":  # the paper's "w/o RE": encoder features straight into the second stage
            self.prior_decoder = None
            x3 = IMU_FEATURES + c.prior_hidden
        else:
            self.prior_decoder = _mlp([c.prior_hidden, c.decoder_hidden, c.decoder_hidden, _JOINT_FEATURES + 6],
                                      last_relu=False)
            x3 = IMU_FEATURES + _JOINT_FEATURES + 6
        if c.variant == "no_joint_map":  # "w/o JE": rotations from the prior and the IMUs, no refined joints
            self.joint_map = None
            self.body_pose = Estimator(x3, _ROT_FEATURES, c.estimator_hidden, c.bidirectional)
        else:
            self.joint_map = Estimator(x3, _JOINT_FEATURES, c.estimator_hidden, c.bidirectional)
            self.body_pose = Estimator(x3 + _JOINT_FEATURES, _ROT_FEATURES, c.estimator_hidden, c.bidirectional)
        self.trans_encoder = PointGruEncoder(c.trans_point_widths, c.trans_hidden, 1, c.bidirectional)
        guide = 0 if c.variant == "trans_no_pose" else _ROT_FEATURES + _JOINT_FEATURES
        self.trans_head = _mlp([c.trans_hidden + guide, c.trans_hidden, 3], last_relu=False)

    def forward(
        self, points: torch.Tensor, frame: torch.Tensor, imu: torch.Tensor, state: State | None = None
    ) -> tuple[dict[str, torch.Tensor], State]:
        """Outputs for inputs (B, T, N, 3), (B, T, FRAME_FEATURES), (B, T, IMU_FEATURES), all in V.

        Returns ``joints`` (B, T, 24, 3) root-relative (the refined joint map,
        or what the variant has instead), ``rot6d`` (B, T, 24, 6) local
        rotations, ``offset`` (B, T, 3) root minus point mean; the supervised
        intermediate outputs the variant has: ``joints_prior`` (B, T, 24, 3),
        ``root6d_prior`` (B, T, 6), ``fine_joints`` (the refined joint map);
        and the final recurrent state (pass it back in to continue the sequence).
        """
        if state is not None and self.config.bidirectional:
            raise ValueError("a bidirectional LipNet cannot continue a sequence (no streaming state)")
        state = state or [None] * self.NUM_STATES
        variant = self.config.variant
        lead = points.shape[:2]
        if variant == "lidar_only":
            imu = torch.zeros_like(imu)
        pose_points, pose_frame = points, frame
        if variant == "imu_only":  # the pose module sees no points (the translation module still does)
            pose_points, pose_frame = torch.zeros_like(points), torch.zeros_like(frame)
        h, s0 = self.prior_encoder(pose_points, pose_frame, state[0])
        out: dict[str, torch.Tensor] = {}
        if self.prior_decoder is None:
            x3 = torch.cat([imu, h], dim=-1)
            base = 0.0
        else:
            prior = self.prior_decoder(h)
            x3 = torch.cat([imu, prior], dim=-1)
            base = prior[..., :_JOINT_FEATURES]
            out["joints_prior"] = base.reshape(*lead, NUM_JOINTS, 3)
            out["root6d_prior"] = prior[..., _JOINT_FEATURES:]
        if self.joint_map is None:
            joints, s_jm = base, [None] * 3
            rot6d, s_bp = self.body_pose(x3, state[4:7])
        else:
            delta, s_jm = self.joint_map(x3, state[1:4])
            joints = base + delta
            out["fine_joints"] = joints.reshape(*lead, NUM_JOINTS, 3)
            rot6d, s_bp = self.body_pose(torch.cat([x3, joints], dim=-1), state[4:7])
        ht, s_t = self.trans_encoder(points, frame, state[7])
        guide = [] if variant == "trans_no_pose" else [rot6d.detach(), joints.detach()]
        out["offset"] = self.trans_head(torch.cat([ht, *guide], dim=-1))
        out["joints"] = joints.reshape(*lead, NUM_JOINTS, 3)
        out["rot6d"] = rot6d.reshape(*lead, NUM_JOINTS, 6)
        return out, [s0, *s_jm, *s_bp, s_t]
