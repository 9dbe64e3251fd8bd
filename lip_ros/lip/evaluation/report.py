"""The evaluation report: JSON, markdown tables (after LIP's Tables 2, 3, 6, 7) and PNG plots.

``results`` everywhere maps a model name (``ours`` or a variant of
:data:`VARIANTS`) to a mode of :data:`~lip_ros.lip.evaluation.evaluate.MODES` to
the :class:`~lip_ros.lip.evaluation.evaluate.CaptureEvaluation` of each capture.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from lip_ros.core.skeleton import load_skeleton
from lip_ros.lip.evaluation.evaluate import CaptureEvaluation, summarize

__all__ = ["OURS", "VARIANTS", "POSE_VARIANTS", "TARGETS", "build_report", "to_markdown", "plot_report"]

OURS = "ours"
#: Ablations that need a network trained for them: name -> table label.
VARIANTS = {
    "lidar_only": "LiDAR only",
    "imu_only": "4 IMUs only",
    "no_prior": "w/o pose-prior regressor (RE)",
    "no_joint_map": "w/o joint-map estimator (JE)",
    "trans_no_pose": "corrector w/o pose guidance (PG)",
}
#: The variants whose pose is compared (the last one only changes the translation).
POSE_VARIANTS = ("lidar_only", "imu_only", "no_prior", "no_joint_map")
#: The issue's targets for the shipped weights on the held-out set (end-to-end).
TARGETS = {"mpjpe_mm": 45.0, "angle_deg": 12.0, "trans_cm": 5.0, "corrector_vs_point_average": 2.0}
_MIN_HALF_SPAN_M = 0.3  # trajectory plots show at least 0.6 m x 0.6 m
_MODE_LABEL = {"end_to_end": "end-to-end", "oracle": "oracle (true labels + calibration)"}

Results = Mapping[str, Mapping[str, list[CaptureEvaluation]]]


def _primary_mode(modes: list[str]) -> str:
    """The mode the ablations, targets and trajectories are reported in: end-to-end if it was run."""
    return "end_to_end" if "end_to_end" in modes else modes[0]


def _per_capture(ev: CaptureEvaluation) -> dict:
    s = summarize([ev])
    return {"capture": ev.capture, "scenario": ev.scenario, "distance_m": ev.distance_m,
            "scored_frames": s["scored_frames"], "posed_frames": s["posed_frames"], "outcomes": s["outcomes"],
            **{k: s[k] for k in ("mpjpe_mm", "pa_mpjpe_mm", "angle_deg", "angle19_deg", "jitter_m_s3")},
            "trans_cm": s["translation"]["corrector"]["trans_cm"], "cd_cm": s["translation"]["corrector"]["cd_cm"]}


def _family(s: dict) -> dict:
    """The errors of a summary that the transfer comparison reads (:mod:`lip_ros.lip.evaluation.transfer`)."""
    return {"captures": s["captures"], "scored_frames": s["scored_frames"], "posed_frames": s["posed_frames"],
            **{k: s[k] for k in ("mpjpe_mm", "pa_mpjpe_mm", "angle_deg", "angle19_deg")},
            "trans_cm": s["translation"]["corrector"]["trans_cm"]}


def _check(target: str, value: float | None, limit: float | None, passed: bool | None) -> dict:
    return {"target": target, "value": value, "reference": limit, "pass": passed}


def _checks(summaries: dict, mode: str) -> list[dict]:
    """The issue's targets on the results of ``ours`` in ``mode``: value, the limit or the compared value, and
    pass (None: not checked, the variant was not trained)."""
    ours = summaries[OURS][mode]["summary"]
    trans = {m: t["trans_cm"] for m, t in ours["translation"].items()}
    ratio = trans["point_average"] / trans["corrector"]
    checks = [
        _check("MPJPE (mm) <=", ours["mpjpe_mm"], TARGETS["mpjpe_mm"], ours["mpjpe_mm"] <= TARGETS["mpjpe_mm"]),
        _check("angular error (deg) <=", ours["angle_deg"], TARGETS["angle_deg"],
               ours["angle_deg"] <= TARGETS["angle_deg"]),
        _check("root translation error (cm) <=", trans["corrector"], TARGETS["trans_cm"],
               trans["corrector"] <= TARGETS["trans_cm"]),
        _check("point average / corrector translation error >=", ratio, TARGETS["corrector_vs_point_average"],
               ratio >= TARGETS["corrector_vs_point_average"]),
        _check("corrector translation error (cm) < ICP's", trans["corrector"], trans["icp"],
               trans["corrector"] < trans["icp"]),
    ]
    for name, label in VARIANTS.items():
        if name not in summaries:
            checks.append(_check(f"beats {label}", None, None, None))
            continue
        other = summaries[name][mode]["summary"]
        if name in POSE_VARIANTS:
            checks.append(_check(f"MPJPE (mm) < {label}'s", ours["mpjpe_mm"], other["mpjpe_mm"],
                                 ours["mpjpe_mm"] < other["mpjpe_mm"]))
            checks.append(_check(f"angular error (deg) < {label}'s", ours["angle_deg"], other["angle_deg"],
                                 ours["angle_deg"] < other["angle_deg"]))
        else:
            value = other["translation"]["corrector"]["trans_cm"]
            checks.append(_check(f"translation error (cm) < {label}'s", trans["corrector"], value,
                                 trans["corrector"] < value))
    return checks


def build_report(results: Results, weights: Mapping[str, str], meta: Mapping) -> dict:
    """The JSON report: ``meta`` (command, machine, ...), weights, captures, summaries, per capture, targets."""
    first = next(iter(next(iter(results.values())).values()))
    summaries = {
        model: {mode: {"summary": summarize(evs), "per_capture": [_per_capture(e) for e in evs],
                       "per_family": {"all": _family(summarize(evs)),
                                      **{f: _family(summarize([e for e in evs if e.scenario == f]))
                                         for f in sorted({e.scenario for e in evs})}}}
                for mode, evs in modes.items()}
        for model, modes in results.items()
    }
    return {
        **meta,
        "weights": dict(weights),
        "captures": [{"name": e.capture, "scenario": e.scenario, "distance_m": e.distance_m} for e in first],
        "results": summaries,
        "targets": _checks(summaries, _primary_mode(list(summaries[OURS]))),
    }


def _f(value: float | None, digits: int = 1) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header), *("| " + " | ".join(r) + " |" for r in rows)]


def _pose_row(s: dict) -> list[str]:
    return [f"{s['posed_frames']}/{s['scored_frames']}", _f(s["mpjpe_mm"]), _f(s["pa_mpjpe_mm"]), _f(s["mesh_mm"]),
            _f(s["angle_deg"], 2), _f(s["translation"]["corrector"]["trans_cm"], 2),
            _f(s["translation"]["corrector"]["cd_cm"], 2), _f(s["jitter_m_s3"], 0)]


def _no_pose(s: dict) -> str:
    """Scored frames without a pose, by outcome."""
    rest = {k.removeprefix("motion/"): v for k, v in s["outcomes"].items()
            if k.startswith("motion/") and k != "motion/pose"}
    return ", ".join(f"{k} {v}" for k, v in rest.items()) or "none"


def to_markdown(report: dict) -> str:
    """The report's tables as markdown."""
    res = report["results"]
    modes = list(res[OURS])
    mode0 = _primary_mode(modes)
    lines = [f"Weights: `{report['weights'][OURS]}`; {len(report['captures'])} held-out captures; "
             f"scored frames: those after the calibration poses (posed / scored).", ""]
    header = ["mode", "posed/scored", "MPJPE mm", "PA-MPJPE mm", "Mesh mm", "Ang deg", "Trans cm", "CD cm",
              "Jitter m/s^3"]
    rows = [[_MODE_LABEL[m], *_pose_row(res[OURS][m]["summary"])] for m in modes]
    truth = res[OURS][mode0]["summary"]
    rows.append(["ground truth (CD floor, jitter of the true motion)", "", "", "", "", "", "",
                 _f(truth["translation"]["truth"]["cd_cm"], 2), _f(truth["jitter_true_m_s3"], 0)])
    lines += ["**LiDAR + 4 IMUs (ours)**", "", *_table(header, rows), ""]
    lines += ["MPJPE, PA-MPJPE and mesh error pose the estimated rotations on the performer's true skeleton and "
              "body (as the paper poses SMPL with the true shape); the joints the pipeline publishes (contract "
              "skeleton scaled by the estimated body size) have MPJPE "
              + ", ".join(f"{_f(res[OURS][m]['summary']['mpjpe_published_mm'])} mm ({_MODE_LABEL[m]})"
                          for m in modes) + ".", ""]

    lines += [f"**Ablations: input and network** ({_MODE_LABEL[mode0]}; Tables 3, 6, 7)", ""]
    rows = []
    for name in (*POSE_VARIANTS[:2], OURS, *POSE_VARIANTS[2:]):
        label = "LiDAR + 4 IMUs (ours)" if name == OURS else VARIANTS[name]
        if name in res:
            s = res[name][mode0]["summary"]
            rows.append([label, _f(s["mpjpe_mm"]), _f(s["pa_mpjpe_mm"]), _f(s["mesh_mm"]), _f(s["angle_deg"], 2)])
        else:
            rows.append([label, "not trained", "", "", ""])
    lines += [*_table(["variant", "MPJPE mm", "PA-MPJPE mm", "Mesh mm", "Ang deg"], rows), ""]

    lines += [f"**Translation** ({_MODE_LABEL[mode0]}; Table 6 bottom; all with the estimated pose of ours)", ""]
    trans = res[OURS][mode0]["summary"]["translation"]
    rows = [["point average", _f(trans["point_average"]["trans_cm"], 2), _f(trans["point_average"]["cd_cm"], 2)],
            ["ICP (estimated body to the points)", _f(trans["icp"]["trans_cm"], 2), _f(trans["icp"]["cd_cm"], 2)]]
    if "trans_no_pose" in res:
        t = res["trans_no_pose"][mode0]["summary"]["translation"]["corrector"]
        rows.append([VARIANTS["trans_no_pose"], _f(t["trans_cm"], 2), _f(t["cd_cm"], 2)])
    else:
        rows.append([VARIANTS["trans_no_pose"], "not trained", ""])
    rows.append(["full corrector (ours)", _f(trans["corrector"]["trans_cm"], 2), _f(trans["corrector"]["cd_cm"], 2)])
    lines += [*_table(["method", "Trans cm", "CD cm"], rows),
              "", "Ours: the network's corrector, then the surface fit (docs/lip/transfer.md) unless the command says "
              "`--no-surface-fit`.", ""]

    lines += ["**Frames** (all captures)", ""]
    rows = []
    for m in modes:
        s = res[OURS][m]["summary"]
        calib = {k.removeprefix("calibration/"): v for k, v in s["outcomes"].items() if k.startswith("calibration/")}
        rows.append([_MODE_LABEL[m], str(s["frames"]), ", ".join(f"{k} {v}" for k, v in calib.items()),
                     str(s["scored_frames"]), _no_pose(s),
                     f"{_f(s['stamp_diff_ms']['mean_abs'], 3)} / {_f(s['stamp_diff_ms']['max_abs'], 3)}"])
    lines += [*_table(["mode", "frames", "calibration poses: outcome", "scored", "scored without pose",
                       "pose - truth stamp ms (mean abs / max abs)"], rows), ""]

    lines += [f"**Per capture** (ours, {_MODE_LABEL[mode0]})", ""]
    rows = [[c["capture"], c["scenario"], _f(c["distance_m"]), f"{c['posed_frames']}/{c['scored_frames']}",
             _f(c["mpjpe_mm"]), _f(c["angle_deg"], 2), _f(c["trans_cm"], 2), _f(c["cd_cm"], 2)]
            for c in res[OURS][mode0]["per_capture"]]
    lines += [*_table(["capture", "scenario", "distance m", "posed/scored", "MPJPE mm", "Ang deg", "Trans cm",
                       "CD cm"], rows), ""]

    lines += [f"**Targets** ({_MODE_LABEL[mode0]})", ""]
    verdict = {True: "pass", False: "FAIL", None: "not checked (not trained)"}
    lines += [f"- {c['target']} {_f(c['reference'], 2)}: {_f(c['value'], 2)} -> {verdict[c['pass']]}"
              if c["pass"] is not None else f"- {c['target']}: {verdict[None]}" for c in report["targets"]]
    return "\n".join(lines) + "\n"


def plot_report(report: dict, results: Results, out_dir: Path) -> list[Path]:
    """PNG plots: mean error per joint, and each capture's trajectory from above against the truth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    names = load_skeleton().names
    modes = list(report["results"][OURS])
    fig, ax = plt.subplots(figsize=(11, 4))
    width = 0.8 / len(modes)
    for i, m in enumerate(modes):
        err = report["results"][OURS][m]["summary"]["per_joint_mm"]
        ax.bar(np.arange(len(names)) + i * width, err, width, label=_MODE_LABEL[m])
    ax.set_xticks(np.arange(len(names)) + 0.4 - width / 2, names, rotation=60, ha="right", fontsize=8)
    ax.set_ylabel("mean error, root-relative (mm)")
    ax.set_title("Joint position error per joint (held-out rig captures)")
    ax.legend()
    fig.tight_layout()
    joint_png = out_dir / "eval_per_joint_error.png"
    fig.savefig(joint_png, dpi=110)
    plt.close(fig)

    mode0 = _primary_mode(modes)
    evals = results[OURS][mode0]
    cols = min(4, len(evals))
    rows = math.ceil(len(evals) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.4 * rows), squeeze=False)
    for ax, ev in zip(axes.ravel(), evals):
        ax.set_title(f"{ev.scenario}, {ev.distance_m:g} m", fontsize=9)
        if not ev.posed:
            ax.text(0.5, 0.5, "no pose", ha="center", va="center", transform=ax.transAxes)
            continue
        ax.plot(ev.true_root_xy[:, 0], ev.true_root_xy[:, 1], "k-", lw=1.5, label="truth")
        ax.plot(ev.root_xy[:, 0], ev.root_xy[:, 1], "r.-", ms=2, lw=0.6, label="LIP")
        xy = np.concatenate([ev.true_root_xy, ev.root_xy])
        centre = 0.5 * (xy.min(axis=0) + xy.max(axis=0))
        half = max(0.5 * float(np.ptp(xy, axis=0).max()) + 0.05, _MIN_HALF_SPAN_M)  # same scale on both axes
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[len(evals):]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"Pelvis from above (os_lidar x, y in m), {_MODE_LABEL[mode0]}", fontsize=9)
    fig.tight_layout()
    traj_png = out_dir / "eval_trajectories.png"
    fig.savefig(traj_png, dpi=110)
    plt.close(fig)
    return [joint_png, traj_png]
