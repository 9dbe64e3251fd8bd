"""How well the LIP pipeline estimates each DOT's latency online, by distance: rig walks, DOTs stamped late.

For each distance, ``--seeds`` rig walks (``--columns``, default 1024; DOTs stamped 20-60 ms late with 5 ms of
jitter, as ``test/lip/test_dot_latency.py``'s) are recorded to ``--bag-dir`` (kept and reused) and run through
:class:`lip_ros.lip.pipeline.LipPipeline`; per DOT, the latency estimate at the end of the bag against the DOT's
true mean delay (``CaptureSession.dot_delays_ms``). Prints each walk's estimates and, per distance, how many of the
DOTs had an estimate, their mean and largest error, and the error of what was taken off (an estimate, or the
configured 0 ms where there is none). Run:
``python benchmarks/bench_dot_latency.py --distances 7 12 16 --seeds 10 [--seconds 20]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from lip_ros.core.torch_runtime import set_threads
from lip_ros.lip.batch import process_bag_batch
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.pipeline import LipPipeline
from lip_ros.rig.bag import write_capture_bag
from lip_ros.rig.capture import CaptureConfig, CaptureSession

WALK = CaptureConfig(scenario="walk", seconds=20.0, columns=1024, imu_latency_ms=(20.0, 60.0),
                     imu_latency_jitter_ms=5.0)


def _walk(seed: int, distance_m: float, seconds: float, columns: int, bag_dir: Path) -> tuple[CaptureSession, Path]:
    session = CaptureSession(dataclasses.replace(WALK, seed=seed, distance_m=distance_m, seconds=seconds,
                                                 columns=columns))
    suffix = "" if columns == WALK.columns else f"_{columns}c"
    bag = bag_dir / f"walk_{distance_m:g}m_{seconds:g}s_{seed}{suffix}"
    if not (bag / "metadata.yaml").exists():
        write_capture_bag(session, bag, progress=False)
    return session, bag


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--distances", type=float, nargs="+", default=[7.0, 12.0, 16.0])
    p.add_argument("--seeds", type=int, default=10, help="walks per distance (seeds 0..N-1)")
    p.add_argument("--seconds", type=float, default=WALK.seconds)
    p.add_argument("--columns", type=int, choices=(512, 1024, 2048), default=WALK.columns)
    p.add_argument("--bag-dir", type=Path, help="where the walks are recorded (default: a temporary directory)")
    args = p.parse_args()
    set_threads(1)
    model = LipModel.load()
    with tempfile.TemporaryDirectory() as tmp:
        bag_dir = args.bag_dir or Path(tmp)
        bag_dir.mkdir(parents=True, exist_ok=True)
        for distance in args.distances:
            errors, taken_off = [], []
            for seed in range(args.seeds):
                session, bag = _walk(seed, distance, args.seconds, args.columns, bag_dir)
                pipeline = LipPipeline(model)
                for _ in process_bag_batch(pipeline, bag):
                    pass
                row = []
                for name, true_ms in session.dot_delays_ms().items():
                    estimate = pipeline.imu.latency.estimate_ns[name]
                    ms = None if estimate is None else estimate * 1e-6
                    errors.append(np.nan if ms is None else abs(ms - true_ms))
                    taken_off.append(abs(pipeline.imu.sync.latency_ns(name) * 1e-6 - true_ms))
                    row.append(f"{name} {'-' if ms is None else f'{ms:.1f}'}/{true_ms:.1f}")
                print(f"{distance:g} m, seed {seed} (estimate/true ms): {' '.join(row)}", flush=True)
            e, t = np.array(errors), np.array(taken_off)
            print(f"{distance:g} m, {args.seconds:g} s walks, {args.columns} columns: "
                  f"{np.isfinite(e).sum()} of {len(e)} DOTs estimated, "
                  f"error mean {np.nanmean(e) if np.isfinite(e).any() else np.nan:.1f} / max "
                  f"{np.nanmax(e) if np.isfinite(e).any() else np.nan:.1f} ms; what was taken off: mean "
                  f"{t.mean():.1f} / max {t.max():.1f} ms from the truth", flush=True)


if __name__ == "__main__":
    main()
