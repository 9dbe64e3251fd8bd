"""How well the LIP pipeline estimates each DOT's latency online, by distance: rig captures, DOTs late or on time.

For each distance, ``--seeds`` rig captures (``--scenario``, default a walk; ``--columns``, default 1024; DOTs
stamped 20-60 ms late with 5 ms of jitter, as ``test/lip/test_dot_latency.py``'s, or on time with ``--on-time``) are
recorded to ``--bag-dir`` (kept and reused) and run through :class:`lip_ros.lip.pipeline.LipPipeline`; per DOT,
against its true mean delay (``CaptureSession.dot_delays_ms``): the first estimate (its error, and how many frames
had come out of the pipeline when it came, the calibration's and skipped ones included), every new estimate over the
capture (each change; how many were more than ``WRONG_MS`` off), and the estimate at the end of the bag. Prints each
capture's estimates and, per distance, how many of the DOTs had an estimate, the errors of the first and last ones,
the wrong ones, and the error of what was taken off at the end (an estimate, or the configured 0 ms where there is
none). Run:
``python benchmarks/bench_dot_latency.py --distances 7 12 16 --seeds 10 [--seconds 20] [--on-time]
[--scenario mixed]``.
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
from lip_ros.rig.motion.performer import SCENARIOS

WALK = CaptureConfig(scenario="walk", seconds=20.0, columns=1024, imu_latency_ms=(20.0, 60.0),
                     imu_latency_jitter_ms=5.0)
#: An estimate this far from the truth (ms) is counted as wrong.
WRONG_MS = 20.0


def _capture(args: argparse.Namespace, seed: int, distance_m: float, bag_dir: Path
             ) -> tuple[CaptureSession, Path]:
    config = dataclasses.replace(WALK, scenario=args.scenario, seed=seed, distance_m=distance_m,
                                 seconds=args.seconds, columns=args.columns)
    if args.on_time:
        config = dataclasses.replace(config, imu_latency_ms=(0.0, 0.0), imu_latency_jitter_ms=0.0)
    session = CaptureSession(config)
    suffix = "" if args.columns == WALK.columns else f"_{args.columns}c"
    suffix += "_on_time" if args.on_time else ""
    bag = bag_dir / f"{args.scenario}_{distance_m:g}m_{args.seconds:g}s_{seed}{suffix}"
    if not (bag / "metadata.yaml").exists():
        write_capture_bag(session, bag, progress=False)
    return session, bag


def _estimates(pipeline: LipPipeline, bag: Path) -> dict[str, list[tuple[int, float]]]:
    """Per DOT, every new latency estimate over the bag: (frames out before it, estimate ms); one taken as the bag
    ended, after its last frame came out, too."""
    estimator = pipeline.imu.latency
    seen = dict.fromkeys(estimator.estimate_ns)
    found: dict[str, list[tuple[int, float]]] = {name: [] for name in seen}

    def look(frames: int) -> None:
        for name, estimate in estimator.estimate_ns.items():
            if estimate != seen[name]:
                seen[name] = estimate
                found[name].append((frames, estimate * 1e-6))

    frames = 0
    for frames, _ in enumerate(process_bag_batch(pipeline, bag), start=1):
        look(frames - 1)
    look(frames)
    return found


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--distances", type=float, nargs="+", default=[7.0, 12.0, 16.0])
    p.add_argument("--seeds", type=int, default=10, help="captures per distance (seeds 0..N-1)")
    p.add_argument("--seconds", type=float, default=WALK.seconds)
    p.add_argument("--columns", type=int, choices=(512, 1024, 2048), default=WALK.columns)
    p.add_argument("--scenario", choices=SCENARIOS, default=WALK.scenario)
    p.add_argument("--on-time", action="store_true", help="DOTs stamped on time (their latency 0)")
    p.add_argument("--bag-dir", type=Path, help="where the captures are recorded (default: a temporary directory)")
    args = p.parse_args()
    set_threads(1)
    model = LipModel.load()
    with tempfile.TemporaryDirectory() as tmp:
        bag_dir = args.bag_dir or Path(tmp)
        bag_dir.mkdir(parents=True, exist_ok=True)
        for distance in args.distances:
            first, first_at, last, taken_off, wrong, estimates = [], [], [], [], 0, 0
            for seed in range(args.seeds):
                session, bag = _capture(args, seed, distance, bag_dir)
                pipeline = LipPipeline(model)
                found = _estimates(pipeline, bag)
                row = []
                for name, true_ms in session.dot_delays_ms().items():
                    taken_off.append(abs(pipeline.imu.sync.latency_ns(name) * 1e-6 - true_ms))
                    wrong += sum(abs(ms - true_ms) > WRONG_MS for _, ms in found[name])
                    estimates += len(found[name])
                    if found[name]:
                        first.append(abs(found[name][0][1] - true_ms))
                        first_at.append(found[name][0][0])
                        last.append(abs(found[name][-1][1] - true_ms))
                    shown = "-" if not found[name] else f"{found[name][0][1]:.1f}..{found[name][-1][1]:.1f}"
                    row.append(f"{name} {shown}/{true_ms:.1f}")
                print(f"{distance:g} m, seed {seed} (first..last estimate/true ms): {' '.join(row)}", flush=True)
            f, a, e, t = np.array(first), np.array(first_at), np.array(last), np.array(taken_off)
            print(f"{distance:g} m, {args.scenario} {args.seconds:g} s, {args.columns} columns, DOTs "
                  f"{'on time' if args.on_time else 'late'}: {len(e)} of {len(t)} DOTs estimated; first estimate "
                  f"error mean {f.mean() if len(f) else np.nan:.1f} / max {f.max() if len(f) else np.nan:.1f} ms, "
                  f"after {np.median(a) if len(a) else np.nan:.0f} frames (median); {wrong} of {estimates} "
                  f"estimates over {WRONG_MS:g} ms off; last estimate error mean "
                  f"{e.mean() if len(e) else np.nan:.1f} / max {e.max() if len(e) else np.nan:.1f} ms; what was "
                  f"taken off at the end: mean {t.mean():.1f} / max {t.max():.1f} ms from the truth", flush=True)


if __name__ == "__main__":
    main()
