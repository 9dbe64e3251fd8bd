"""The LIP losses (paper equations 1-9) and the evaluation metrics.

Every loss is a squared L2 norm over one frame's whole vector (72 joint
coordinates, 6 or 144 rotation numbers, 3 offset coordinates), averaged over
frames: the paper's sums over t with the common 1/T.
"""

from __future__ import annotations

from typing import TypedDict

import torch

from lip_ros.core.torch_kinematics import SkeletonTensors, forward_kinematics, matrix_to_six_d, six_d_to_matrix

__all__ = ["LOSS_NAMES", "LossTargets", "lip_losses", "pose_metrics"]

#: Names of the losses, in the order of ``LipConfig.lambdas``, then the translation loss (weight 1).
LOSS_NAMES = ("joint_prior", "ori_prior", "fine_joints", "ik", "fk", "trans")


class LossTargets(TypedDict):
    """Targets in V, batch-first."""

    joints: torch.Tensor  # (B, T, 24, 3) root-relative
    local_rot: torch.Tensor  # (B, T, 24, 3, 3), [0] = root orientation in V
    offset: torch.Tensor  # (B, T, 3) root minus point mean
    present: torch.Tensor  # (B, T) performer seen
    bone_offsets: torch.Tensor  # (B, 24, 3) the performer's skeleton


def _sq(x: torch.Tensor, dims: int) -> torch.Tensor:
    """Squared norm over the last ``dims`` axes."""
    return x.pow(2).flatten(-dims).sum(-1)


def lip_losses(
    out: dict[str, torch.Tensor], target: LossTargets, skel: SkeletonTensors, lambdas: tuple[float, ...]
) -> tuple[torch.Tensor, dict[str, float]]:
    """Weighted total loss and each term's value (equations 3, 7, 9; translation only where the performer was seen).

    The prior and refined-joint terms apply to the outputs the network has
    (an ablation without the prior or the joint map lacks them).
    """
    rot6d_gt = matrix_to_six_d(target["local_rot"])
    _, fk = forward_kinematics(skel, six_d_to_matrix(out["rot6d"]), offsets=target["bone_offsets"][:, None])
    present = target["present"].to(out["offset"].dtype)
    terms = {
        "ik": _sq(out["rot6d"] - rot6d_gt, 2).mean(),
        "fk": _sq(fk - target["joints"], 2).mean(),
        "trans": (_sq(out["offset"] - target["offset"], 1) * present).sum() / present.sum().clamp(min=1.0),
    }
    if "joints_prior" in out:
        terms["joint_prior"] = _sq(out["joints_prior"] - target["joints"], 2).mean()
        terms["ori_prior"] = _sq(out["root6d_prior"] - rot6d_gt[..., 0, :], 1).mean()
    if "fine_joints" in out:
        terms["fine_joints"] = _sq(out["fine_joints"] - target["joints"], 2).mean()
    weights = dict(zip(LOSS_NAMES, (*lambdas, 1.0)))
    total = sum(weights[n] * v for n, v in terms.items())
    return total, {n: float(v.detach()) for n, v in terms.items()}


@torch.no_grad()
def pose_metrics(
    joints: torch.Tensor, local_rot: torch.Tensor, root: torch.Tensor, target_joints: torch.Tensor,
    target_local_rot: torch.Tensor, target_root: torch.Tensor, skel: SkeletonTensors,
) -> dict[str, torch.Tensor]:
    """Per-frame errors (...,): MPJPE (m) of root-relative joints, mean global joint angle error (rad), root error (m).

    Rotations (..., 24, 3, 3) are local (root = global orientation); both are
    turned global with the same forward kinematics, whose angles do not depend on bone offsets.
    """
    glob, _ = forward_kinematics(skel, local_rot)
    glob_gt, _ = forward_kinematics(skel, target_local_rot)
    rel = glob.transpose(-1, -2) @ glob_gt
    cos = ((rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0) / 2.0).clamp(-1.0, 1.0)
    return {
        "mpjpe": (joints - target_joints).norm(dim=-1).mean(-1),
        "angle": torch.arccos(cos).mean(-1),
        "trans": (root - target_root).norm(dim=-1),
    }
