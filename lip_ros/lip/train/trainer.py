"""The training loop: AdamW on random windows, cosine learning rate, validation, checkpoints and resume.

Both modules train at once from one optimizer: the translation corrector
sees the pose module's outputs detached (:class:`~lip_ros.lip.nets.models.LipNet`),
so this equals training them separately. A checkpoint holds weights,
optimizer, step, the sampler's and torch's random states and the best
validation score; it loads with ``torch.load(..., weights_only=True)``, and a
resumed run continues exactly where the saved one stood.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from lip_ros.core.skeleton import load_skeleton
from lip_ros.core.torch_kinematics import SkeletonTensors, forward_kinematics, six_d_to_matrix
from lip_ros.lip.nets.config import LipConfig
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.nets.losses import LossTargets, lip_losses, pose_metrics
from lip_ros.lip.nets.models import LipNet
from lip_ros.lip.train.dataset import PreparedSequence, WindowSampler, stack_prepared

__all__ = ["TrainOptions", "evaluate", "train"]


@dataclass(frozen=True)
class TrainOptions:
    """Optimisation settings."""

    steps: int = 3000  # length of the cosine schedule (and the run)
    batch: int = 12
    window: int = 48  # frames per training window
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup: int = 100
    clip: float = 1.0
    seed: int = 0
    log_every: int = 25
    val_every: int = 250
    max_minutes: float = math.inf  # stop early (with a checkpoint) after this much wall time
    stop_after: int = 0  # if > 0, stop (with a checkpoint) after this step; the schedule still spans ``steps``
    device: str = "cpu"  # torch device of the training ("cuda" on a GPU machine)
    fit_minutes: float = 0.0  # if > 0, the schedule is cut (once, at the 50th step) to end in about this time


_FIT_AFTER = 50  # steps timed before ``fit_minutes`` cuts the schedule
_FIT_MARGIN = 0.9  # of the remaining time's steps kept (validation and checkpoints take the rest)


def _lr(opt: TrainOptions, step: int) -> float:
    warm = min(1.0, (step + 1) / max(opt.warmup, 1))
    return opt.lr * warm * (0.05 + 0.95 * 0.5 * (1.0 + math.cos(math.pi * min(step / opt.steps, 1.0))))


def _to(device: torch.device, inputs: tuple[torch.Tensor, ...], target: LossTargets
        ) -> tuple[tuple[torch.Tensor, ...], LossTargets]:
    """A batch moved to ``device``."""
    moved = {k: v.to(device, non_blocking=True) for k, v in target.items()}
    return tuple(x.to(device, non_blocking=True) for x in inputs), LossTargets(**moved)


@torch.no_grad()
def evaluate(net: LipNet, sequences: list[PreparedSequence], skel: SkeletonTensors) -> dict[str, float]:
    """Mean errors over whole sequences fed from their start: MPJPE (mm), MPJPE of FK with the true
    skeleton (mm), global joint angle (deg), root translation (cm) on frames with a performer; and the loss.
    Runs on the device of ``net``."""
    net.eval()
    length = min(len(s) for s in sequences)
    inputs, target = _to(next(net.parameters()).device, *stack_prepared(sequences, [0] * len(sequences), length))
    out, _ = net(*inputs)
    loss, _ = lip_losses(out, target, skel, net.config.lambdas)
    rot = six_d_to_matrix(out["rot6d"])
    m = pose_metrics(out["joints"], rot, out["offset"], target["joints"], target["local_rot"], target["offset"], skel)
    _, fk = forward_kinematics(skel, rot, offsets=target["bone_offsets"][:, None])
    present = target["present"] > 0.5
    return {
        "loss": float(loss),
        "mpjpe_mm": 1000.0 * float(m["mpjpe"].mean()),
        "mpjpe_fk_mm": 1000.0 * float((fk - target["joints"]).norm(dim=-1).mean()),
        "angle_deg": math.degrees(float(m["angle"].mean())),
        "trans_cm": 100.0 * float(m["trans"][present].mean()),
    }


def _save_checkpoint(path: Path, net: LipNet, optim: torch.optim.Optimizer, step: int, sampler: WindowSampler,
                     best: float) -> None:
    state = {
        "model": net.state_dict(),
        "optim": optim.state_dict(),
        "step": step,
        "config": net.config.to_dict(),
        "sampler_rng": sampler.rng.bit_generator.state,
        "torch_rng": torch.get_rng_state(),
        "best": best,
    }
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    tmp.replace(path)


def train(
    config: LipConfig,
    train_set: list[PreparedSequence],
    val_set: list[PreparedSequence],
    opt: TrainOptions,
    out_dir: str | Path,
    resume: bool = False,
    init: dict[str, torch.Tensor] | None = None,
    log: Callable[[str], None] = lambda msg: print(msg, file=sys.stderr, flush=True),
) -> dict[str, float]:
    """Train (or resume from ``out_dir/checkpoint.pt``) from the weights ``init`` (a state_dict; None: random);
    the best validation weights go to ``out_dir/best``.

    Returns the last validation metrics.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    ckpt_path = out_dir / "checkpoint.pt"
    torch.manual_seed(opt.seed)
    device = torch.device(opt.device)
    net = LipNet(config)
    if init is not None:
        net.load_state_dict(init)
    net = net.to(device)
    optim = torch.optim.AdamW(net.parameters(), lr=opt.lr, weight_decay=opt.weight_decay)
    sampler = WindowSampler(train_set, opt.window, opt.batch, opt.seed)
    skel = SkeletonTensors(load_skeleton(), device=device)
    step, best = 0, math.inf
    if resume and ckpt_path.exists():
        ckpt = torch.load(ckpt_path, map_location="cpu", weights_only=True)
        if LipConfig.from_dict(ckpt["config"]) != config:
            raise ValueError(f"{ckpt_path} was trained with another config")
        net.load_state_dict(ckpt["model"])
        optim.load_state_dict(ckpt["optim"])
        sampler.rng.bit_generator.state = ckpt["sampler_rng"]
        torch.set_rng_state(ckpt["torch_rng"])
        step, best = int(ckpt["step"]), float(ckpt["best"])
        log(f"resumed at step {step} from {ckpt_path}")
    params = sum(p.numel() for p in net.parameters())
    log(f"model: {params} parameters on {device}; {len(train_set)} train / {len(val_set)} val sequences; "
        f"{sum(len(s) for s in train_set)} train frames")
    t0, metrics, running = time.monotonic(), {}, {}
    start_step = step
    while step < opt.steps:
        net.train()
        for g in optim.param_groups:
            g["lr"] = _lr(opt, step)
        inputs, target = _to(device, *sampler.next())
        out, _ = net(*inputs)
        loss, terms = lip_losses(out, target, skel, config.lambdas)
        optim.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), opt.clip)
        optim.step()
        step += 1
        for k, v in terms.items():
            running[k] = running.get(k, 0.0) + v
        elapsed = time.monotonic() - t0
        if opt.fit_minutes > 0 and step == start_step + _FIT_AFTER:
            left = max(60.0 * opt.fit_minutes - elapsed, 0.0)
            fitted = int(step + _FIT_MARGIN * (step - start_step) / elapsed * left)
            if fitted < opt.steps:
                log(f"schedule cut from {opt.steps} to {fitted} steps to end within {opt.fit_minutes} min")
                opt = replace(opt, steps=fitted)
        if step % opt.log_every == 0:
            rate = (step - start_step) / elapsed
            avg = " ".join(f"{k}={v / opt.log_every:.4f}" for k, v in running.items())
            log(f"step {step}/{opt.steps} lr={_lr(opt, step):.2e} {avg} | {rate:.2f} steps/s, "
                f"eta {(opt.steps - step) / rate / 60:.1f} min")
            running = {}
        stop = elapsed > 60.0 * opt.max_minutes or step == opt.stop_after
        if step % opt.val_every == 0 or step == opt.steps or stop:
            metrics = evaluate(net, val_set, skel)
            log(f"val step {step}: " + " ".join(f"{k}={v:.3f}" for k, v in metrics.items()))
            score = metrics["mpjpe_mm"] + metrics["angle_deg"] * 3.0 + metrics["trans_cm"] * 5.0
            if score < best:
                best = score
                LipModel(net).save(out_dir / "best")
                log(f"new best (score {score:.2f}) -> {out_dir / 'best'}.pt")
            _save_checkpoint(ckpt_path, net, optim, step, sampler, best)
        if stop:
            log(f"stopped at step {step} ({elapsed / 60:.1f} min)")
            break
    return metrics
