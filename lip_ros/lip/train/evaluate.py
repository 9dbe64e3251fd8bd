"""Errors of LIP outputs against a rig sequence's truth (the numbers docs/lip/training.md reports)."""

from __future__ import annotations

import numpy as np

from lip_ros.core import metrics
from lip_ros.core.skeleton import forward_kinematics, load_skeleton
from lip_ros.lip.nets.lip_model import LipModel, LipOutput
from lip_ros.lip.train.rigdata import RigSequence

__all__ = ["score", "run_sequence"]


def run_sequence(model: LipModel, seq: RigSequence) -> LipOutput:
    """The model over a whole sequence (one batched forward, as streaming would give)."""
    return model.run([seq.frame_points(k) for k in range(seq.num_frames)], seq.imu_rot, seq.imu_acc)


def score(out: LipOutput, seq: RigSequence, skip_s: float = 0.0) -> dict[str, float]:
    """Mean errors after the first ``skip_s`` seconds: MPJPE (mm) of the root-relative joints, mean global
    joint rotation error over the 24 joints (deg), root translation error (cm, frames with a performer)."""
    keep = seq.pose_time >= seq.pose_time[0] + skip_s
    skel = load_skeleton()
    glob, _ = forward_kinematics(skel, out.local_rot[keep])
    glob_gt, _ = forward_kinematics(skel, seq.local_rot[keep])
    rel_gt = seq.joint_pos[keep] - seq.root_pos[keep, None]
    seen = out.present & keep
    return {
        "mpjpe_mm": 1000.0 * float(metrics.mpjpe(out.joints[keep], rel_gt).mean()),
        "angle_deg": float(np.rad2deg(metrics.angular_error(glob, glob_gt)).mean()),
        "trans_cm": 100.0 * float(metrics.translation_error(out.translation[seen], seq.root_pos[seen]).mean()),
    }
