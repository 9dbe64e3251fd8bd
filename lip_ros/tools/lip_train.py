"""``lip_train``: simulate (and cache) rig sequences, then train the LIP networks.

The shipped weights (docs/lip/training.md; on a GPU)::

    lip_train --hold-out martial --device cuda --workers 16 --train-seqs 569 --val-seqs 24 \\
        --steps 3912 --batch 32 --val-every 500 --data-dir /tmp/rd --out /tmp/protocol
    lip_train --device cuda --workers 16 --train-seqs 335 --val-seqs 24 --steps 1263 --batch 32 \\
        --lr 5e-4 --warmup 20 --val-every 250 --init /tmp/protocol/best --data-dir /tmp/rd2 \\
        --out /tmp/shipped --export params/weights/lip_small
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from lip_ros.core.torch_runtime import set_threads
from lip_ros.lip.nets.config import VARIANTS, LipConfig
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.train.dataset import PreparedSequence, blank_frames, prepare
from lip_ros.lip.train.rigdata import (
    DEFAULT_DATA_DIR,
    TRAIN_SEEDS,
    VAL_SEEDS,
    ensure_cached,
    load_sequence,
    spec_for_seed,
)
from lip_ros.lip.train.trainer import TrainOptions, train
from lip_ros.rig.domain import HELD_OUT_ACTIVITIES
from lip_ros.rig.motion import ACTIVITIES

__all__ = ["main", "build_parser"]

_CONFIGS = {"small": LipConfig, "paper": LipConfig.paper, "tiny": LipConfig.tiny}


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``lip_train``."""
    p = argparse.ArgumentParser(prog="lip_train", description=__doc__.split("\n")[0])
    p.add_argument("--data-dir", type=Path, default=DEFAULT_DATA_DIR, help="cache of simulated sequences (.npz)")
    p.add_argument("--out", type=Path, required=True, help="run directory: checkpoint.pt, best.pt/.json")
    p.add_argument("--config", choices=sorted(_CONFIGS), default="small", help="network sizes")
    p.add_argument("--config-json", type=Path, help="a LipConfig JSON (overrides --config)")
    p.add_argument("--bidirectional", action="store_true", help="offline bi-GRUs (the paper's; cannot stream)")
    p.add_argument("--variant", choices=VARIANTS, default="full",
                   help="the method or one of its ablations (docs/lip/evaluation.md)")
    p.add_argument("--train-seqs", type=int, default=400, help="training sequences (seeds 0..n-1)")
    p.add_argument("--val-seqs", type=int, default=24, help="validation sequences (seeds 500000..)")
    p.add_argument("--seconds", type=float, default=30.0, help="length of each sequence")
    p.add_argument("--workers", type=int, default=2,
                   help="simulation and preprocessing processes (at most the machine's cores)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (1: fastest on a busy 2-core machine)")
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    p.add_argument("--export", type=Path, help="copy the best weights here as float16 (<path>.pt + <path>.json)")
    p.add_argument("--hold-out", nargs="*", choices=ACTIVITIES, default=[], metavar="FAMILY",
                   help=f"motion families left out of the training and validation data (the out-of-distribution "
                        f"protocol's weights: --hold-out {' '.join(HELD_OUT_ACTIVITIES)})")
    p.add_argument("--init", type=Path, help="start from these weights (<path>.pt/.json of the same config)")
    defaults = TrainOptions()
    for name in TrainOptions.__dataclass_fields__:
        value = getattr(defaults, name)
        p.add_argument("--" + name.replace("_", "-"), type=type(value), default=value)
    return p


def _prepared(job: tuple[Path, int, int | None]) -> PreparedSequence:
    """One cached sequence through the preprocessing; a training one (with its seed) gets blanked bursts."""
    path, num_points, blank_seed = job
    seq = load_sequence(path)
    blank = None if blank_seed is None else blank_frames(seq.num_frames, np.random.default_rng([blank_seed, 9]))
    return prepare(seq, num_points, blank)


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    args = build_parser().parse_args(argv)
    set_threads(args.threads)
    config = LipConfig.load(args.config_json) if args.config_json else _CONFIGS[args.config]()
    if args.bidirectional:
        config = config.with_(bidirectional=True)
    if args.variant != "full":
        config = config.with_(variant=args.variant)
    if args.train_seqs < 1 or args.val_seqs < 1:
        print("lip_train: need at least one training and one validation sequence", file=sys.stderr)
        return 2
    held_out = tuple(args.hold_out)
    train_specs = [spec_for_seed(s, args.seconds, held_out) for s in TRAIN_SEEDS[: args.train_seqs]]
    val_specs = [spec_for_seed(s, args.seconds, held_out) for s in VAL_SEEDS[: args.val_seqs]]
    paths = ensure_cached(val_specs + train_specs, args.data_dir, args.workers)
    print(f"lip_train: preparing {len(paths)} sequences", file=sys.stderr, flush=True)
    jobs = [(path, config.num_points, None if i < len(val_specs) else spec.seed)
            for i, (spec, path) in enumerate(zip(val_specs + train_specs, paths))]
    if args.workers > 1:
        with ProcessPoolExecutor(min(args.workers, os.cpu_count() or 1),
                                 mp_context=multiprocessing.get_context("spawn")) as pool:
            prepared = list(pool.map(_prepared, jobs, chunksize=4))
    else:
        prepared = [_prepared(job) for job in jobs]
    opt = TrainOptions(**{k: getattr(args, k) for k in TrainOptions.__dataclass_fields__})
    init = LipModel.load(args.init).net.state_dict() if args.init else None
    metrics = train(config, prepared[len(val_specs):], prepared[: len(val_specs)], opt, args.out, args.resume, init)
    if args.export:
        LipModel.load(args.out / "best").save(args.export, float16=True)
        print(f"lip_train: best weights exported to {args.export}.pt/.json", file=sys.stderr)
    print("lip_train: final validation " + " ".join(f"{k}={v:.3f}" for k, v in metrics.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
