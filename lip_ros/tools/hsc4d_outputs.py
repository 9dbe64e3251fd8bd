"""What ``lip_process_bag`` reports of an HSC4D run: frames, latency, accuracy against the rig's truth, plots.

The fused trajectory (``/hsc4d/odometry``) is in ``map``, the truth in the
site's frame: as in :mod:`lip_ros.hsc4d.evaluation`, a rotation about z and a
translation fitted on the 5 s after the jump's landing (from the bag's
``rig_truth.yaml``) and kept fixed maps one onto the other (drift is not
forgiven). Reported: pelvis ATE, the error at the end, the vertical error off
the start's level, root-relative MPJPE of ``/hsc4d/joint_poses`` (through the
same alignment), and Baseline1 (the suit's own ``/mocap/odometry``, moved onto
the LiDAR's clock by the offset the graph found) through the same alignment
fitted for it; the same of the body node's scene-aware optimisation
(``/hsc4d/optimised/*``) when the run has it, and of the offline refinement
(``/hsc4d/refined/*``, ``lip_process_bag --refine``). The ground under the wearer comes from the site rebuilt from
the capture's seed. Truth between its 100 Hz samples (``site_truth.npz``) is
interpolated linearly at each output's stamp.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from lip_msgs_py import cloud_to_xyz, msg_to_odometry, msg_to_pose_array
from lip_ros.bagio import read_messages
from lip_ros.core import metrics
from lip_ros.hsc4d.sensors import (
    HSC4D_TOPICS,
    MAP_TOPIC,
    ODOMETRY_TOPIC,
    OPTIMISED_ODOMETRY_TOPIC,
    OPTIMISED_TOPICS,
    REFINED_ODOMETRY_TOPIC,
    REFINED_TOPICS,
    SUIT_ODOMETRY_TOPIC,
)
from lip_ros.outputs import PoseTopics

__all__ = ["Hsc4dAccuracy", "hsc4d_accuracy", "plot_hsc4d", "FIT_S"]

FIT_S = 5.0  # seconds after the landing the alignment is fitted on
LEVEL_M = 0.05  # ground this far off the start's level counts as stairs, ramps, the terrace


@dataclass
class Hsc4dAccuracy:
    """The run against the truth (m, mm), and the suit-only baseline's figures."""

    matched: int
    ate_m: float
    final_m: float
    vertical_m: float
    mpjpe_mm: float
    suit_ate_m: float | None = None
    suit_final_m: float | None = None
    series: dict[str, np.ndarray] = field(default_factory=dict, repr=False)  # for the plot
    optimised: Hsc4dAccuracy | None = None  # the same of /hsc4d/optimised/*
    refined: Hsc4dAccuracy | None = None  # the same of the offline refinement (/hsc4d/refined/*)

    def lines(self) -> list[str]:
        """Human-readable report."""
        out = [f"accuracy on {self.matched} poses vs the rig's truth (aligned on the {FIT_S:g} s after the jump's "
               f"landing): {self._figures()}"]
        if self.optimised is not None:
            out.append(f"after the scene-aware optimisation ({self.optimised.matched} poses on "
                       f"{OPTIMISED_ODOMETRY_TOPIC}): {self.optimised._figures()}")
        if self.refined is not None:
            out.append(f"after the offline refinement ({self.refined.matched} poses on {REFINED_ODOMETRY_TOPIC}): "
                       f"{self.refined._figures()}")
        if self.suit_ate_m is not None:
            out.append(f"Baseline1 (the suit's own odometry) the same way: ATE {100 * self.suit_ate_m:.1f} cm, at the "
                       f"end {100 * self.suit_final_m:.1f} cm")
        return out

    def _figures(self) -> str:
        return (f"pelvis ATE {100 * self.ate_m:.1f} cm, at the end {100 * self.final_m:.1f} cm, vertical off the "
                f"start's level {100 * self.vertical_m:.1f} cm, MPJPE {self.mpjpe_mm:.1f} mm")


def _odometry(bag: Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    stamps, positions = [], []
    for m in read_messages(bag, [topic]):
        o = msg_to_odometry(m.msg)
        stamps.append(o.stamp_ns)
        positions.append(o.position)
    return np.array(stamps, dtype=np.int64), np.array(positions).reshape(-1, 3)


def _interp(t: np.ndarray, ts: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` (T, ...) sampled at ``ts`` (T,), linearly at ``t``."""
    flat = values.reshape(len(ts), -1)
    out = np.column_stack([np.interp(t.astype(np.float64), ts.astype(np.float64), flat[:, i])
                           for i in range(flat.shape[1])])
    return out.reshape((len(t),) + values.shape[1:])


def _accuracy(outputs: Path, odometry_topic: str, topics: PoseTopics, truth: dict[str, np.ndarray], rig: dict
              ) -> Hsc4dAccuracy | None:
    """One trajectory's (``odometry_topic``, and its body on ``topics.joint_poses``) accuracy; None if too few
    poses after the landing."""
    landing = next(p["end_ns"] for p in rig["phases"] if p["name"] == "jump")
    stamps, pelvis = _odometry(outputs, odometry_topic)
    inside = (stamps >= truth["stamp_ns"][0]) & (stamps <= truth["stamp_ns"][-1])
    stamps, pelvis = stamps[inside], pelvis[inside]
    fit = (stamps >= landing) & (stamps <= landing + FIT_S * 1e9)
    if fit.sum() < 2:
        return None
    true_pelvis = _interp(stamps, truth["stamp_ns"], truth["pelvis"])
    T = metrics.align_yaw_translation(pelvis, true_pelvis, fit)
    aligned = pelvis @ T[:3, :3].T + T[:3, 3]
    err = np.linalg.norm(aligned - true_pelvis, axis=1)
    from lip_ros.rig.terrain import Terrain  # the rig (scipy.signal): only on a rig capture

    ground = Terrain.random(int(rig["config"]["seed"])).surface_height(true_pelvis[:, :2])
    off_level = np.abs(ground - ground[0]) > LEVEL_M
    dz = aligned[:, 2] - true_pelvis[:, 2]
    joints = {p.stamp_ns: p.positions
              for p in (msg_to_pose_array(m.msg) for m in read_messages(outputs, [topics.joint_poses]))}
    have = [k for k, s in enumerate(stamps) if int(s) in joints]
    mpjpe = float("nan")
    if have:
        est = np.array([joints[int(stamps[k])] for k in have]) @ T[:3, :3].T
        true_joints = _interp(stamps[have], truth["stamp_ns"], truth["joints"])
        mpjpe = 1000 * float(metrics.mpjpe(est - est[:, :1], true_joints - true_joints[:, :1]).mean())
    return Hsc4dAccuracy(len(stamps), float(np.sqrt(np.mean(err ** 2))), float(err[-1]),
                         float(np.sqrt(np.mean(dz[off_level] ** 2))) if off_level.any() else float("nan"), mpjpe,
                         series={"t_s": (stamps - stamps[0]) * 1e-9, "truth": true_pelvis, "live": aligned,
                                 "stamp_ns": stamps, "fit": fit})


def hsc4d_accuracy(inputs: Path, outputs: Path, offset_ns: int | None, refined: Path | None = None
                   ) -> Hsc4dAccuracy | None:
    """The run's accuracy (and of the offline refinement's bag ``refined``, if given), or None without the rig's
    truth files or outputs in its span."""
    from lip_ros.rig.bag import TRUTH_FILE  # the rig (scipy.signal): not for a real capture's summary
    from lip_ros.rig.site_bag import SITE_TRUTH_FILE

    truth_file, sidecar = inputs / SITE_TRUTH_FILE, inputs / TRUTH_FILE
    if not (truth_file.is_file() and sidecar.is_file()):
        return None
    truth = dict(np.load(truth_file))
    rig = yaml.safe_load(sidecar.read_text(encoding="utf-8"))
    out = _accuracy(outputs, ODOMETRY_TOPIC, HSC4D_TOPICS, truth, rig)
    if out is None:
        return None
    out.optimised = _accuracy(outputs, OPTIMISED_ODOMETRY_TOPIC, OPTIMISED_TOPICS, truth, rig)
    if refined is not None:
        out.refined = _accuracy(refined, REFINED_ODOMETRY_TOPIC, REFINED_TOPICS, truth, rig)
    stamps, fit, true_pelvis = out.series["stamp_ns"], out.series["fit"], out.series["truth"]
    suit_ns, suit = _odometry(inputs, SUIT_ODOMETRY_TOPIC)
    if offset_ns is not None and len(suit_ns) > 1:
        suit_at = _interp(stamps + offset_ns, suit_ns, suit)
        S = metrics.align_yaw_translation(suit_at, true_pelvis, fit)
        suit_aligned = suit_at @ S[:3, :3].T + S[:3, 3]
        suit_err = np.linalg.norm(suit_aligned - true_pelvis, axis=1)
        out.suit_ate_m, out.suit_final_m = float(np.sqrt(np.mean(suit_err ** 2))), float(suit_err[-1])
        out.series["suit"] = suit_aligned
    return out


def _last_map(outputs: Path) -> np.ndarray | None:
    """(M, 3) the last map the graph published, if any."""
    last = None
    for m in read_messages(outputs, [MAP_TOPIC]):
        last = m.msg
    return None if last is None else cloud_to_xyz(last)


def plot_hsc4d(outputs: Path, accuracy: Hsc4dAccuracy | None, png: Path) -> Path:
    """Top view and height over time of the fused pelvis (against the truth and Baseline1 when known) and the
    last map from above with the trajectory on it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stamps, pelvis = _odometry(outputs, ODOMETRY_TOPIC)
    if not len(stamps):
        raise ValueError("no fused poses to plot")
    cloud = _last_map(outputs)
    fig, (top, side, view) = plt.subplots(1, 3, figsize=(18, 5.5))
    if accuracy is not None:
        s, frame = accuracy.series, "site frame (aligned)"
        lines = [("truth", s["truth"], "k-", s["t_s"]), ("live (fused)", s["live"], "r-", s["t_s"])]
        if accuracy.optimised is not None:
            o = accuracy.optimised.series
            lines.append(("optimised", o["live"], "m--", o["t_s"] + (o["stamp_ns"][0] - s["stamp_ns"][0]) * 1e-9))
        if accuracy.refined is not None:
            r = accuracy.refined.series
            lines.append(("refined (offline)", r["live"], "b--",
                          r["t_s"] + (r["stamp_ns"][0] - s["stamp_ns"][0]) * 1e-9))
        lines += [("Baseline1 (suit)", s["suit"], "c:", s["t_s"])] if "suit" in s else []
    else:
        lines, frame = [("live (fused)", pelvis, "r-", (stamps - stamps[0]) * 1e-9)], "map"
    for label, p, style, t in lines:
        top.plot(p[:, 0], p[:, 1], style, lw=1.2, label=label)
        side.plot(t, p[:, 2], style, lw=1.2, label=label)
    top.set(aspect="equal", xlabel="x (m)", ylabel="y (m)", title=f"pelvis from above ({frame})")
    side.set(xlabel="time (s)", ylabel="pelvis height (m)", title="pelvis height")
    top.legend(fontsize=8)
    side.legend(fontsize=8)
    if cloud is not None and len(cloud):
        keep = cloud[:, 2] < pelvis[:, 2].max() + 1.0  # no roof over the path
        sc = view.scatter(cloud[keep, 0], cloud[keep, 1], c=cloud[keep, 2], s=0.2, cmap="viridis")
        fig.colorbar(sc, ax=view, label="z (m)")
    view.plot(pelvis[:, 0], pelvis[:, 1], "r-", lw=1.0, label="pelvis")
    view.set(aspect="equal", xlabel="x (m)", ylabel="y (m)", title="last /hsc4d/map (map frame) from above")
    view.legend(fontsize=8)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=90)
    plt.close(fig)
    return png
