"""Gradient norm of each LIP loss term, weighted, for trained weights: which term drives the update.

For ``--batches`` training batches (the trainer's sampler: 12 random 48-frame
windows of the first ``--seqs`` cached training sequences, seed 0), the norm
over the pose module's parameters of the gradient of each weighted pose term
alone (``LipConfig.lambdas`` of the weights, or ``--lambdas``) and of all of
them, averaged over the batches. (The trainer clips the gradient of the whole
loss at norm 1; the translation module, which sees the pose outputs detached,
is left out.)
Run: ``python benchmarks/loss_gradients.py /tmp/ablation/full/best``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from lip_ros.core.skeleton import load_skeleton
from lip_ros.core.torch_kinematics import SkeletonTensors
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.nets.losses import LOSS_NAMES, lip_losses
from lip_ros.lip.train.dataset import blank_frames, prepare
from lip_ros.lip.train.rigdata import DEFAULT_DATA_DIR, TRAIN_SEEDS, ensure_cached, load_sequence, spec_for_seed
from lip_ros.lip.train.trainer import WindowSampler

_POSE_TERMS = LOSS_NAMES[:5]


def _grad_norm(params: list[torch.nn.Parameter], loss: torch.Tensor) -> float:
    grads = torch.autograd.grad(loss, params, retain_graph=True, allow_unused=True)
    return float(torch.sqrt(sum(g.pow(2).sum() for g in grads if g is not None)))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("weights", type=Path, help="<path> of <path>.pt/.json")
    p.add_argument("--lambdas", type=float, nargs=5, help="weights of the five pose terms (default: the weights')")
    p.add_argument("--seqs", type=int, default=40, help="training sequences to sample from")
    p.add_argument("--batches", type=int, default=4)
    p.add_argument("--data-dir", type=Path, default=DEFAULT_DATA_DIR, help="lip_train's sequence cache")
    args = p.parse_args()
    torch.set_num_threads(1)
    net = LipModel.load(args.weights).net.float().train()
    lambdas = tuple(args.lambdas) if args.lambdas else net.config.lambdas
    specs = [spec_for_seed(s, 30.0) for s in TRAIN_SEEDS[: args.seqs]]
    sequences = []
    for spec, path in zip(specs, ensure_cached(specs, args.data_dir, 1)):
        seq = load_sequence(path)
        sequences.append(prepare(seq, net.config.num_points,
                                 blank_frames(seq.num_frames, np.random.default_rng([spec.seed, 9]))))
    sampler = WindowSampler(sequences, 48, 12, 0)
    skel = SkeletonTensors(load_skeleton())
    pose_params = [p for name, p in net.named_parameters() if not name.startswith("trans_")]
    norms: dict[str, list[float]] = {name: [] for name in (*_POSE_TERMS, "total")}
    for _ in range(args.batches):
        inputs, target = sampler.next()
        out, _ = net(*inputs)
        _, terms = lip_losses(out, target, skel, lambdas)
        for k, name in enumerate(_POSE_TERMS):
            if name in terms:
                only = tuple(lam if i == k else 0.0 for i, lam in enumerate(lambdas))
                norms[name].append(_grad_norm(pose_params, lip_losses(out, target, skel, only)[0]))
        norms["total"].append(_grad_norm(pose_params, lip_losses(out, target, skel, lambdas)[0]))
    print(f"{args.weights} ({net.config.variant}), lambdas {lambdas}, {args.batches} batches")
    for name, values in norms.items():
        if values:
            print(f"  {name:12s} {np.mean(values):7.3f}")


if __name__ == "__main__":
    main()
