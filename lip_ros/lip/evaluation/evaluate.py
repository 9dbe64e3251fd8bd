"""End-to-end evaluation of LIP on recorded rig captures: every LiDAR frame through :class:`LipPipeline`,
matched to the ground truth by stamp, errors per frame, summaries over a set of captures.

Modes: ``end_to_end`` (the pipeline as deployed: segmentation, online
calibration, sync, network) and ``oracle`` (true performer labels and true
IMU calibration, :mod:`lip_ros.lip.evaluation.oracle`; the rest as deployed).
Being calibrated from the start, the oracle runs the network from the first
frame, through the calibration poses; end to end it starts once calibrated.

Scored frames are those whose truth holds after the calibration poses; a
scored frame without a pose (still calibrating, skipped) counts as such, with
its reason, and is not in the error means. Frames of the calibration poses are
counted separately. A pose is matched to the ``/gt/joint_poses`` message
nearest to its stamp; the stamp difference is reported.

Errors (paper section 5 and Table 2 of LIP, TransPose and PIP for jitter):

* MPJPE, PA-MPJPE (mm): root-relative joints of the estimated local
  rotations posed with the performer's true skeleton (as the paper poses SMPL
  with the true shape); ``mpjpe_published_mm`` is that of the joints the
  pipeline publishes (the contract skeleton scaled by the network's estimate
  of the performer's size);
* mesh error (mm): :class:`~lip_ros.core.body_surface.BodySurface` points of
  the performer's body, estimated vs true pose, root-relative;
* angular error (deg): geodesic angle of the 24 global joint rotations, and of the 19 joints that have a child
  (``angle19_deg``: hands, feet and head left out, their rotation moves no joint);
* translation error (cm): pelvis position in L;
* CD (cm): one-sided chamfer distance from the performer's true points to
  the estimated posed body surface (performer's body model, exact distance
  to its capsules); the true pose's CD is the floor (range noise, motion
  during the sweep);
* jitter (m/s^3): third finite difference of the estimated global joints over
  runs of consecutive posed frames (the truth's own for reference).

Translation baselines need no other network: ``point_average`` (mean of the
performer points the pipeline segmented, as LiDARCap) and ``icp`` (the
estimated pose on the contract body scaled by the estimated size, its surface
points facing the LiDAR aligned to those points by a translation-only ICP
from the point mean);
``corrector`` is the network's output. All use the same estimated rotations.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from lip_ros.core import metrics
from lip_ros.core.body import BodyModel
from lip_ros.core.body_surface import BodySurface
from lip_ros.core.skeleton import NUM_JOINTS, forward_kinematics, load_skeleton
from lip_ros.lip.batch import POSE_BATCH, process_bag_batch
from lip_ros.lip.evaluation.captures import CaptureTruth
from lip_ros.lip.evaluation.oracle import LabelSegmenter, truth_calibration
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.pipeline import FrameResult, LipPipeline, Outcome

__all__ = ["MODES", "TRANSLATION_METHODS", "POSE_ERRORS", "SURFACE_POINTS", "CaptureEvaluation", "evaluate_capture",
           "summarize"]

MODES = ("end_to_end", "oracle")
TRANSLATION_METHODS = ("corrector", "point_average", "icp")
POSE_ERRORS = ("mpjpe_mm", "pa_mpjpe_mm", "mesh_mm", "angle_deg", "angle19_deg", "mpjpe_published_mm")
SURFACE_POINTS = 3000  # fixed surface points per body (mesh error, ICP): about 2.5 cm apart


@dataclass
class CaptureEvaluation:
    """One capture through one model in one mode: frame accounting and per-frame errors of the scored poses."""

    capture: str
    scenario: str
    distance_m: float
    mode: str
    frames: int = 0
    outcomes: Counter[str] = field(default_factory=Counter)  # "<phase>/<outcome>[/<reason>]" -> frames
    stamp_diff_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # pose - matched truth
    errors: dict[str, np.ndarray] = field(default_factory=dict)  # POSE_ERRORS -> (P,)
    per_joint_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, NUM_JOINTS)))  # (P, 24)
    translation_cm: dict[str, np.ndarray] = field(default_factory=dict)  # method -> (P,)
    chamfer_cm: dict[str, np.ndarray] = field(default_factory=dict)  # method or "truth" -> (P,), NaN if no points
    jitter: tuple[float, float, int] = (float("nan"), float("nan"), 0)  # estimate, truth (m/s^3), jerk samples
    root_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (P, 2) corrector output
    true_root_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def posed(self) -> int:
        """Scored frames with a pose."""
        return len(self.stamp_diff_ns)


def _outcome_key(result: FrameResult, phase: str) -> str:
    """A short, countable description of a frame's outcome (reasons cut at their first colon)."""
    if result.outcome == Outcome.POSE:
        return f"{phase}/pose"
    if result.outcome == Outcome.CALIBRATING:
        return f"{phase}/calibrating"
    return f"{phase}/skipped/{result.reason.split(':')[0]}"


def _runs(index: np.ndarray) -> list[np.ndarray]:
    """Positions in ``index`` (ascending frame indices) split into runs of consecutive frames."""
    return np.split(np.arange(len(index)), np.flatnonzero(np.diff(index) != 1) + 1)


def _jitter(index: np.ndarray, est: np.ndarray, true: np.ndarray, dt: float) -> tuple[float, float, int]:
    """Jitter of the estimated and the true joints over the runs of consecutive frames, and its sample count."""
    runs = [r for r in _runs(index) if len(r) >= 4]
    if not runs:
        return float("nan"), float("nan"), 0
    weights = np.array([len(r) - 3 for r in runs], dtype=np.float64)
    values = np.array([[metrics.jitter(est[r], dt), metrics.jitter(true[r], dt)] for r in runs])
    mean = weights @ values / weights.sum()
    return float(mean[0]), float(mean[1]), int(weights.sum())


class _Scorer:
    """Errors of one capture's posed frames against its truth."""

    def __init__(self, capture: CaptureTruth, contract_surface: BodySurface) -> None:
        self.capture = capture
        self.surface = BodySurface(capture.body, SURFACE_POINTS)
        self.contract_surface = contract_surface
        self.non_leaf = [j for j in range(NUM_JOINTS) if capture.skeleton.children(j)]

    def icp_root(self, result: FrameResult) -> np.ndarray:
        """The ICP baseline's pelvis position for a posed frame."""
        pose, points = result.pose, result.segmentation.points.astype(np.float64)
        mean = points.mean(axis=0)
        # the contract body scaled by the estimated size is the contract body's surface scaled about the root
        unit = (pose.joint_pos - pose.root_pos) / pose.body_scale
        rel = pose.body_scale * self.contract_surface.points(pose.glob_rot, unit) + mean
        facing = np.einsum("nc,nc->n", self.contract_surface.normals(pose.glob_rot), -rel) > 0.0  # towards L's origin
        return mean + metrics.icp_translation(points, rel[facing])

    def chamfer_cm(self, frames: np.ndarray, glob: np.ndarray, pos: np.ndarray) -> np.ndarray:
        """(P,) CD (cm) from each frame's true performer points to the body in poses (P, 24, 3, 3), (P, 24, 3);
        NaN where the performer was not scanned."""
        cap = self.capture
        return np.array([100.0 * metrics.surface_chamfer(cap.performer_points[k], cap.body, g, p)
                         if len(cap.performer_points[k]) else np.nan for k, g, p in zip(frames, glob, pos)])

    def score(self, ev: CaptureEvaluation, results: list[FrameResult], frames: np.ndarray, gt: np.ndarray) -> None:
        """Fill ``ev``'s errors from posed ``results`` of frames ``frames`` matched to truth messages ``gt``."""
        cap = self.capture
        local = np.stack([r.pose.local_rot for r in results])
        root = np.stack([r.pose.root_pos for r in results])
        glob, pos = forward_kinematics(cap.skeleton, local, root)
        glob_t, pos_t = cap.gt_glob_rot[gt], cap.gt_joint_pos[gt]
        root_t = pos_t[:, 0]
        surf = self.surface.points(glob, pos - root[:, None])
        surf_t = self.surface.points(glob_t, pos_t - root_t[:, None])
        ev.errors = {
            "mpjpe_mm": 1000.0 * metrics.mpjpe(pos, pos_t),
            "pa_mpjpe_mm": 1000.0 * metrics.pa_mpjpe(pos, pos_t),
            "mesh_mm": 1000.0 * metrics.mean_distance(surf, surf_t),
            "angle_deg": np.rad2deg(metrics.angular_error(glob, glob_t)),
            "angle19_deg": np.rad2deg(metrics.angular_error(glob[:, self.non_leaf], glob_t[:, self.non_leaf])),
            "mpjpe_published_mm": 1000.0 * metrics.mpjpe(np.stack([r.pose.joint_pos for r in results]), pos_t),
        }
        ev.per_joint_mm = 1000.0 * np.linalg.norm(metrics.root_relative(pos) - metrics.root_relative(pos_t), axis=-1)
        roots = {
            "corrector": root,
            "point_average": np.stack([r.segmentation.points.astype(np.float64).mean(axis=0) for r in results]),
            "icp": np.stack([self.icp_root(r) for r in results]),
        }
        ev.translation_cm = {m: 100.0 * metrics.translation_error(r, root_t) for m, r in roots.items()}
        ev.chamfer_cm = {m: self.chamfer_cm(frames, glob, pos - root[:, None] + r[:, None]) for m, r in roots.items()}
        ev.chamfer_cm["truth"] = self.chamfer_cm(frames, glob_t, pos_t)
        ev.jitter = _jitter(frames, pos, pos_t, 1.0 / cap.rate_hz)
        ev.root_xy, ev.true_root_xy = root[:, :2], root_t[:, :2]


def _pipeline(capture: CaptureTruth, model: LipModel, mode: str) -> LipPipeline:
    if mode == "end_to_end":
        return LipPipeline(model, pose_batch=POSE_BATCH)
    if mode == "oracle":
        return LipPipeline(model, calibration=truth_calibration(capture), segmenter=LabelSegmenter(capture),
                           pose_batch=POSE_BATCH)
    raise ValueError(f"mode must be one of {MODES}, not {mode!r}")


def evaluate_capture(capture: CaptureTruth, model: LipModel, mode: str,
                     contract_surface: BodySurface | None = None) -> CaptureEvaluation:
    """Replay ``capture``'s bag through a pipeline with ``model`` in ``mode`` and score every frame."""
    contract_surface = contract_surface or BodySurface(BodyModel(load_skeleton()), SURFACE_POINTS)
    ev = CaptureEvaluation(capture.name, capture.scenario, capture.distance_m, mode)
    gt_stamps = capture.gt_stamp_ns
    tolerance_ns = int(0.5e9 / capture.rate_hz)
    posed, frames, gt, diffs = [], [], [], []
    for result in process_bag_batch(_pipeline(capture, model.for_rate(capture.rate_hz), mode), capture.bag):
        ev.frames += 1
        k = capture.frame_index(result.frame_stamp_ns)
        if k is None:
            ev.outcomes["unknown frame"] += 1
            continue
        phase = "motion" if capture.truth_stamp_ns[k] >= capture.motion_start_ns else "calibration"
        if phase == "motion" and result.pose is not None:
            g = int(np.argmin(np.abs(gt_stamps - result.pose.stamp_ns)))
            if abs(int(gt_stamps[g]) - result.pose.stamp_ns) > tolerance_ns:
                ev.outcomes["motion/pose without truth"] += 1
                continue
            posed.append(result)
            frames.append(k)
            gt.append(g)
            diffs.append(result.pose.stamp_ns - int(gt_stamps[g]))
        ev.outcomes[_outcome_key(result, phase)] += 1
    ev.stamp_diff_ns = np.asarray(diffs, dtype=np.int64)
    if posed:
        _Scorer(capture, contract_surface).score(ev, posed, np.asarray(frames), np.asarray(gt))
    return ev


def _mean(values: list[np.ndarray]) -> float:
    joined = np.concatenate(values) if values else np.zeros(0)
    joined = joined[np.isfinite(joined)]
    return float(joined.mean()) if joined.size else float("nan")


def summarize(evals: list[CaptureEvaluation]) -> dict:
    """Frame-weighted means over captures (JSON-ready): frame accounting, stamp differences, errors."""
    posed = [e for e in evals if e.posed]
    outcomes = sum((e.outcomes for e in evals), Counter())
    diffs = np.concatenate([e.stamp_diff_ns for e in evals]) if evals else np.zeros(0)
    weights = np.array([e.jitter[2] for e in posed], dtype=np.float64)
    jitter = np.array([e.jitter[:2] for e in posed]).reshape(-1, 2)
    ok = weights > 0
    return {
        "captures": len(evals),
        "frames": int(sum(e.frames for e in evals)),
        "scored_frames": int(sum(v for k, v in outcomes.items() if k.startswith("motion/"))),
        "posed_frames": int(sum(e.posed for e in evals)),
        "outcomes": dict(sorted(outcomes.items())),
        "stamp_diff_ms": {"mean_abs": float(np.abs(diffs).mean() * 1e-6) if diffs.size else float("nan"),
                          "max_abs": float(np.abs(diffs).max() * 1e-6) if diffs.size else float("nan")},
        **{k: _mean([e.errors[k] for e in posed]) for k in POSE_ERRORS},
        "per_joint_mm": (np.concatenate([e.per_joint_mm for e in posed]).mean(axis=0).tolist() if posed
                         else [float("nan")] * NUM_JOINTS),
        "translation": {
            **{m: {"trans_cm": _mean([e.translation_cm[m] for e in posed]),
                   "cd_cm": _mean([e.chamfer_cm[m] for e in posed])} for m in TRANSLATION_METHODS},
            "truth": {"trans_cm": 0.0, "cd_cm": _mean([e.chamfer_cm["truth"] for e in posed])},
        },
        "jitter_m_s3": float(weights[ok] @ jitter[ok, 0] / weights[ok].sum()) if ok.any() else float("nan"),
        "jitter_true_m_s3": float(weights[ok] @ jitter[ok, 1] / weights[ok].sum()) if ok.any() else float("nan"),
    }
