"""Streaming LIP inference: latency of ``LipModel.step`` and accuracy on held-out rig sequences.

For each distance a held-out sequence (seed >= 1_000_000, with the calibration
poses at its start) is built with the training code's ``make_sequence``; the
model runs over it frame by frame (``step``), timed, and the errors are
reported (``lip_ros.train.evaluate.score``). ``--weights`` picks other weights
(a bidirectional model is run offline with ``run``, not timed per frame).
Run: ``python benchmarks/bench_lip_step.py [--distances 5 10 20] [--weights PATH]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from lip_ros.nets.lip_model import LipModel, LipOutput
from lip_ros.train.evaluate import run_sequence, score
from lip_ros.train.rigdata import EVAL_SEED_MIN, evaluation_spec, make_sequence


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--weights", help="<path> of <path>.pt/.json (default: the shipped weights)")
    p.add_argument("--distances", type=float, nargs="+", default=[5.0, 10.0, 15.0, 20.0, 25.0])
    p.add_argument("--seeds", type=int, default=2, help="sequences per distance")
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    model = LipModel.load(args.weights)
    params = sum(t.numel() for t in model.net.parameters())
    print(f"weights: {args.weights or 'shipped'} ({params} parameters, bidirectional={model.config.bidirectional})")
    rows, times = [], []
    for d in args.distances:
        for i in range(args.seeds):
            seq = make_sequence(evaluation_spec(EVAL_SEED_MIN + 1000 * int(d) + i, d, args.seconds))
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
            rows.append((d, score(out, seq)))
            m = rows[-1][1]
            print(f"  {d:5.1f} m seed {i}: MPJPE {m['mpjpe_mm']:6.1f} mm  angle {m['angle_deg']:5.2f} deg  "
                  f"translation {m['trans_cm']:5.2f} cm  ({seq.meta['scenario']}, {seq.meta['mean_points']:.0f} pts)")
    for key, unit in (("mpjpe_mm", "mm"), ("angle_deg", "deg"), ("trans_cm", "cm")):
        print(f"mean {key}: {np.mean([m[key] for _, m in rows]):.2f} {unit}")
    if times:
        t = 1000.0 * np.array(times)
        print(f"step latency: median {np.median(t):.1f} ms, p95 {np.percentile(t, 95):.1f} ms, max {t.max():.1f} ms "
              f"({args.threads} thread(s), {len(t)} frames)")


if __name__ == "__main__":
    main()
