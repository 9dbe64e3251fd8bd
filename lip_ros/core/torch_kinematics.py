"""Batched, differentiable rotations and forward kinematics in torch.

Same conventions as :mod:`lip_ros.core.rotations` and :mod:`lip_ros.core.skeleton`.
"""

from __future__ import annotations

import torch

from lip_ros.core.skeleton import NUM_JOINTS, Skeleton

__all__ = ["axis_angle_to_matrix", "six_d_to_matrix", "matrix_to_six_d", "forward_kinematics", "SkeletonTensors"]


def axis_angle_to_matrix(v: torch.Tensor) -> torch.Tensor:
    """(N, 3) axis-angle vectors to (N, 3, 3) rotation matrices (Rodrigues), differentiable at zero."""
    theta2 = (v * v).sum(-1, keepdim=True)[..., None]
    theta = torch.sqrt(theta2 + 1e-24)
    zero = torch.zeros_like(v[:, 0])
    K = torch.stack([zero, -v[:, 2], v[:, 1], v[:, 2], zero, -v[:, 0], -v[:, 1], v[:, 0], zero], -1).view(-1, 3, 3)
    small = theta2 < 1e-12
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / (theta2 + 1e-24))
    return torch.eye(3, dtype=v.dtype, device=v.device) + a * K + b * (K @ K)


def six_d_to_matrix(d6: torch.Tensor) -> torch.Tensor:
    """(..., 6) first-two-columns representation to (..., 3, 3) by Gram-Schmidt."""
    a1, a2 = d6[..., 0:3], d6[..., 3:6]
    b1 = torch.nn.functional.normalize(a1, dim=-1)
    b2 = torch.nn.functional.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1)
    b3 = torch.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-1)


def matrix_to_six_d(rot: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) matrices to (..., 6): the first two columns, concatenated."""
    return torch.cat([rot[..., :, 0], rot[..., :, 1]], dim=-1)


class SkeletonTensors:
    """The skeleton's parents and rest offsets as tensors, for :func:`forward_kinematics`."""

    def __init__(self, skeleton: Skeleton, dtype: torch.dtype = torch.float32, device: str | torch.device = "cpu"):
        self.parents = [int(p) for p in skeleton.parents]
        self.offsets = torch.as_tensor(skeleton.offsets, dtype=dtype, device=device)


def forward_kinematics(
    skel: SkeletonTensors,
    local_rot: torch.Tensor,
    root_pos: torch.Tensor | None = None,
    offsets: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Global rotations (..., 24, 3, 3) and positions (..., 24, 3) from local rotations.

    ``local_rot[..., 0]`` is the root orientation; ``offsets`` (broadcastable to
    (..., 24, 3)) overrides the rest offsets, e.g. for scaled bodies.
    """
    off = skel.offsets if offsets is None else offsets
    off = off.to(local_rot.dtype).expand(local_rot.shape[:-3] + (NUM_JOINTS, 3))
    glob = [local_rot[..., 0, :, :]]
    pos = [torch.zeros_like(local_rot[..., 0, :, 0]) if root_pos is None else root_pos.to(local_rot.dtype)]
    for j in range(1, NUM_JOINTS):
        p = skel.parents[j]
        glob.append(glob[p] @ local_rot[..., j, :, :])
        pos.append(pos[p] + (glob[p] @ off[..., j, :, None])[..., 0])
    return torch.stack(glob, dim=-3), torch.stack(pos, dim=-2)
