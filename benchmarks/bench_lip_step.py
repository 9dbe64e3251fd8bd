"""Streaming LIP inference: latency of ``LipModel.step`` and accuracy on held-out rig sequences.

For each distance a held-out sequence (seed >= 1_000_000, with the calibration
poses at its start) is built with the training code's ``make_sequence``; the
model runs over it frame by frame (``step``), timed, and the errors are
reported (``lip_ros.lip.train.evaluate.score``). ``--weights`` picks other weights
(a bidirectional model is run offline with ``run``, not timed per frame);
``--validation N`` scores ``lip_train``'s first N validation sequences instead.
Run: ``python benchmarks/bench_lip_step.py [--distances 5 10 20] [--validation 24] [--weights PATH]``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from lip_ros.lip.nets.lip_model import LipModel, LipOutput
from lip_ros.lip.train.evaluate import run_sequence, score
from lip_ros.lip.train.rigdata import (
    DEFAULT_DATA_DIR,
    EVAL_SEED_MIN,
    VAL_SEEDS,
    RigSequence,
    ensure_cached,
    evaluation_spec,
    load_sequence,
    make_sequence,
    spec_for_seed,
)


def _sequences(args: argparse.Namespace) -> Iterator[tuple[str, RigSequence]]:
    """(label, sequence): held-out ones per distance, or lip_train's validation sequences (cached)."""
    if args.validation:
        specs = [spec_for_seed(s) for s in VAL_SEEDS[: args.validation]]
        for spec, path in zip(specs, ensure_cached(specs, args.data_dir)):
            yield f"validation seed {spec.seed}", load_sequence(path)
        return
    for d in args.distances:
        for i in range(args.seeds):
            spec = evaluation_spec(EVAL_SEED_MIN + 1000 * int(d) + i, d, args.seconds)
            yield f"{d:5.1f} m seed {i}", make_sequence(spec)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--weights", help="<path> of <path>.pt/.json (default: the shipped weights)")
    p.add_argument("--distances", type=float, nargs="+", default=[5.0, 10.0, 15.0, 20.0, 25.0])
    p.add_argument("--seeds", type=int, default=2, help="sequences per distance")
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--validation", type=int, default=0, help="score lip_train's first N validation sequences instead")
    p.add_argument("--data-dir", type=Path, default=DEFAULT_DATA_DIR, help="lip_train's sequence cache")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    model = LipModel.load(args.weights)
    params = sum(t.numel() for t in model.net.parameters())
    print(f"weights: {args.weights or 'shipped'} ({params} parameters, bidirectional={model.config.bidirectional})")
    rows, times = [], []
    for label, seq in _sequences(args):
        if model.config.bidirectional:
            out = run_sequence(model, seq)
        else:
            model.reset()
            steps = []
            for k in range(seq.num_frames):
                t0 = time.perf_counter()
                steps.append(model.step(seq.frame_points(k), seq.imu_rot[k], seq.imu_acc[k]))
                times.append(time.perf_counter() - t0)
            out = LipOutput(*(np.stack([getattr(s, f) for s in steps]) for f in LipOutput.__dataclass_fields__))
        rows.append(score(out, seq))
        m = rows[-1]
        print(f"  {label}: MPJPE {m['mpjpe_mm']:6.1f} mm  angle {m['angle_deg']:5.2f} deg  "
              f"translation {m['trans_cm']:5.2f} cm  ({seq.meta['scenario']}, {seq.meta['mean_points']:.0f} pts)")
    for key, unit in (("mpjpe_mm", "mm"), ("angle_deg", "deg"), ("trans_cm", "cm")):
        print(f"mean {key}: {np.mean([m[key] for m in rows]):.2f} {unit}")
    if times:
        t = 1000.0 * np.array(times)
        print(f"step latency: median {np.median(t):.1f} ms, p95 {np.percentile(t, 95):.1f} ms, max {t.max():.1f} ms "
              f"({args.threads} thread(s), {len(t)} frames)")


if __name__ == "__main__":
    main()
