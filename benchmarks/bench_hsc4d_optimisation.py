"""Time per window of the HSC4D scene-aware optimisation (lip_ros.hsc4d.scene_optimisation) on 1 and 2 torch threads,
alone and beside a busy core.

A rig capture's true pelvis and feet (``--seed``, ``--seconds`` at 10 Hz) with
1.5 cm of noise on the pelvis are optimised window by window
(``optimise_sequence``, 100 frames a window) on the true ground sampled every
10 cm under the walk. For each ``--threads`` count, printed: the seconds per
window, once alone and once with a second process spinning on one core, as the
body node's optimisation runs beside the trajectory node on two cores (run it
on an otherwise idle machine).

Run: ``python benchmarks/bench_hsc4d_optimisation.py [--threads 1 2] [--seconds 40] [--seed 3] [--repeats 3]``
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

import numpy as np

from lip_ros.core.skeleton import load_skeleton
from lip_ros.core.torch_runtime import set_threads
from lip_ros.hsc4d.scene_optimisation import optimise_sequence
from lip_ros.hsc4d.suit_body import FEET, leg_chains
from lip_ros.rig.site_capture import SiteCapture, SiteCaptureConfig


def _inputs(seed: int, seconds: float) -> tuple:
    """Times, noisy pelvis poses, the legs' rotations and bones, the suit's pelvis and feet, the ground points."""
    capture = SiteCapture(SiteCaptureConfig(seed=seed, seconds=seconds))
    t = np.arange(0.0, capture.motion.duration, 0.1)
    truth = capture.truth(t)
    feet = truth.joints[:, [load_skeleton().index(f) for f in FEET]]
    pelvis = np.tile(np.eye(4), (len(t), 1, 1))
    pelvis[:, :3, :3] = truth.R_W_M
    pelvis[:, :3, 3] = truth.pelvis + np.random.default_rng(seed).normal(0.0, 0.015, truth.pelvis.shape)
    lo, hi = truth.pelvis[:, :2].min(axis=0) - 2.0, truth.pelvis[:, :2].max(axis=0) + 2.0
    x, y = np.meshgrid(np.arange(lo[0], hi[0], 0.1), np.arange(lo[1], hi[1], 0.1))
    xy = np.column_stack([x.ravel(), y.ravel()])
    ground = np.column_stack([xy, capture.terrain.surface_height(xy)])
    return t, pelvis, leg_chains(capture.motion.skeleton, truth.local_rot), truth.pelvis * 1.03, feet, ground


def main() -> int:
    """Command line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--seconds", type=float, default=40.0)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    t, pelvis, (legs, bones), suit_pelvis, suit_feet, ground = _inputs(args.seed, args.seconds)
    print(f"{len(t)} frames, {len(ground)} ground points", file=sys.stderr)
    optimise_sequence(t[:20], pelvis[:20], legs[:20], bones, suit_pelvis[:20], suit_feet[:20],
                      lambda k: ground)  # warm-up
    for busy in (False, True):
        spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy else None
        try:
            for threads in args.threads:
                set_threads(threads)
                took = []
                for _ in range(args.repeats):
                    start = time.perf_counter()
                    result = optimise_sequence(t, pelvis, legs, bones, suit_pelvis, suit_feet, lambda k: ground)
                    took.append((time.perf_counter() - start) / len(result.windows))
                print(f"{'beside a busy core' if busy else 'alone':18s} {threads} thread(s): "
                      f"{np.median(took):.3f} s per window (median of {args.repeats} runs of {len(result.windows)} "
                      f"windows; min {np.min(took):.3f}, max {np.max(took):.3f})", flush=True)
        finally:
            if spinner is not None:
                spinner.kill()
                spinner.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
