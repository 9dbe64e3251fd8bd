"""hsc4d_eval: the HSC4D trajectory on rig captures against the truth and the paper's baselines.

  hsc4d_eval --seeds 1000 1001 1002 --seconds 90 --out DIR [--columns 1024] [--rate 10]

Each capture is simulated and played through the live pipeline in arrival
order (lip_ros.hsc4d.evaluation). Printed per capture and averaged: pelvis ATE
(RMSE after a yaw + translation fit on the 5 s after the jump's landing, kept
fixed), vertical error off the start's level (stairs, ramps, terrace), error at
the end, for Baseline1 (suit only), Baseline2 (LiDAR odometry only), the live
fusion and the offline refinement; the clock offset found; the registrations
not believed; the time per sweep. Writes DIR/metrics.json and DIR/trajectories.png
(per capture: top view and height over time, all four against the truth).
Held-out seeds: 1000 and up (development used 0-20).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from lip_ros.hsc4d.evaluation import METHODS, TrajectoryRun, aligned, run_capture, trajectory_metrics
from lip_ros.rig.site_capture import SiteCapture, SiteCaptureConfig

_LABELS = {"baseline1_suit": "Baseline1 (suit)", "baseline2_lidar": "Baseline2 (LiDAR)", "live": "live",
           "refined": "refined"}
_STYLES = {"baseline1_suit": "c:", "baseline2_lidar": "g-.", "live": "r-", "refined": "b--"}


def plot(runs: list[TrajectoryRun], out: Path) -> None:
    """Per capture: the trajectories from above and their heights over time, aligned as the metrics are."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(runs), figsize=(6.0 * len(runs), 9.0), squeeze=False)
    for col, run in enumerate(runs):
        top, side = axes[0, col], axes[1, col]
        top.plot(run.truth[:, 0], run.truth[:, 1], "k-", lw=2.0, alpha=0.4, label="truth")
        side.plot(run.t_s, run.truth[:, 2], "k-", lw=2.0, alpha=0.4, label="truth")
        for name in METHODS:
            p = aligned(run, name)
            top.plot(p[:, 0], p[:, 1], _STYLES[name], lw=1.0, label=_LABELS[name])
            side.plot(run.t_s, p[:, 2], _STYLES[name], lw=1.0, label=_LABELS[name])
        top.set(aspect="equal", xlabel="x (m)", ylabel="y (m)", title=f"seed {run.seed}: pelvis from above")
        side.set(xlabel="time (s)", ylabel="pelvis height (m)", title=f"seed {run.seed}: height")
        top.legend(fontsize=8)
        side.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Command line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1000, 1001, 1002])
    parser.add_argument("--seconds", type=float, default=90.0)
    parser.add_argument("--columns", type=int, choices=(512, 1024, 2048), default=1024)
    parser.add_argument("--rate", type=float, choices=(10.0, 20.0), default=10.0)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    runs, report = [], {}
    for seed in args.seeds:
        t0 = time.perf_counter()
        capture = SiteCapture(SiteCaptureConfig(seed=seed, seconds=args.seconds, columns=args.columns,
                                                rate_hz=args.rate))

        def progress(k: int, n: int, seed: int = seed) -> None:
            if k % 100 == 0 or k == n - 1:
                print(f"  seed {seed}: sweep {k + 1}/{n}", flush=True)

        run = run_capture(capture, progress=progress)
        metrics = trajectory_metrics(run)
        path = float(np.sum(np.linalg.norm(np.diff(run.truth, axis=0), axis=1)))
        report[seed] = {
            "metrics": metrics, "path_m": path, "offset_error_ms": (run.offset_ns - run.true_offset_ns) * 1e-6,
            "not_believed": int(run.rejected.sum()), "sweeps": len(run.t_s),
            "sweep_ms_p50": float(np.median(run.sweep_ms)), "sweep_ms_p99": float(np.percentile(run.sweep_ms, 99)),
            "counts": run.counts, "wall_s": time.perf_counter() - t0,
        }
        runs.append(run)
        r = report[seed]
        print(f"seed {seed}: {r['sweeps']} sweeps, path {path:.0f} m, clock offset off by "
              f"{r['offset_error_ms']:+.1f} ms, {r['not_believed']} registrations not believed, "
              f"sweep p50 {r['sweep_ms_p50']:.0f} ms p99 {r['sweep_ms_p99']:.0f} ms (the simulation runs between)")
        for name in METHODS:
            m = metrics[name]
            print(f"  {_LABELS[name]:18s} ATE {m['ate_m']:.3f} m  vertical {m['vertical_m']:.3f} m  "
                  f"end {m['final_m']:.3f} m")
    print("mean over captures:")
    for name in METHODS:
        mean = {k: float(np.nanmean([report[s]["metrics"][name][k] for s in args.seeds]))
                for k in ("ate_m", "vertical_m", "final_m")}
        report.setdefault("mean", {})[name] = mean
        print(f"  {_LABELS[name]:18s} ATE {mean['ate_m']:.3f} m  vertical {mean['vertical_m']:.3f} m  "
              f"end {mean['final_m']:.3f} m")
    (args.out / "metrics.json").write_text(json.dumps(report, indent=1, default=str))
    plot(runs, args.out / "trajectories.png")
    print(f"wrote {args.out / 'metrics.json'} and {args.out / 'trajectories.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
