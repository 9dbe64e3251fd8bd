"""``lip_eval``: make the held-out rig captures, and evaluate LIP on them end to end.

  lip_eval make-set --out DIR [--count 8 --seconds 20 --first-seed N --columns 1024 --domain standard|shifted]
  lip_eval run DIR_OR_BAG... [--weights PATH] [--variant NAME=PATH ...] [--mode both] [--out DIR] [--plots DIR]
  lip_eval transfer IN_REPORT.json OUT_REPORT.json [--mode end_to_end] [--out DIR]

``run`` writes ``report.json`` and ``report.md`` to ``--out`` and two PNG
plots to ``--plots`` (default: ``--out``), and prints the markdown.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import shlex
import sys
import time
from pathlib import Path

from lip_ros.bagio import BagError
from lip_ros.core.body import BodyModel
from lip_ros.core.body_surface import BodySurface
from lip_ros.core.skeleton import load_skeleton
from lip_ros.core.torch_runtime import set_threads
from lip_ros.lip.evaluation import transfer
from lip_ros.lip.evaluation.captures import FIRST_SEEDS, find_captures, heldout_configs, load_capture, make_heldout_set
from lip_ros.lip.evaluation.evaluate import MODES, SURFACE_POINTS, CaptureEvaluation, evaluate_capture
from lip_ros.lip.evaluation.report import OURS, VARIANTS, build_report, plot_report, to_markdown
from lip_ros.lip.nets.lip_model import BONE_TOLERANCE_DEG, SHIPPED_WEIGHTS, LipModel
from lip_ros.lip.surface_fit import SURFACE_FIT
from lip_ros.lip.train.rigdata import EVAL_SEED_MIN
from lip_ros.resources import params_dir
from lip_ros.rig.domain import DOMAINS
from lip_ros.rig.motion import ACTIVITIES

__all__ = ["main", "build_parser"]


def _variant(text: str) -> tuple[str, Path]:
    name, sep, path = text.partition("=")
    if not sep or name not in VARIANTS:
        raise argparse.ArgumentTypeError(f"expected NAME=PATH with NAME one of {', '.join(VARIANTS)}, got {text!r}")
    return name, Path(path)


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``lip_eval``."""
    p = argparse.ArgumentParser(prog="lip_eval", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    m = sub.add_parser("make-set", help="record the held-out rig captures (bags that exist are kept)")
    m.add_argument("--out", type=Path, required=True, help="directory of the bags")
    m.add_argument("--count", type=int, default=8,
                   help="captures (scenarios cycled, distances over the domain's range)")
    m.add_argument("--seconds", type=float, default=20.0, help="length of each capture, calibration included")
    m.add_argument("--first-seed", type=int,
                   help=f"seeds from here (>= {EVAL_SEED_MIN}; default: the domain's, {FIRST_SEEDS})")
    m.add_argument("--columns", type=int, choices=(512, 1024, 2048), default=1024)
    m.add_argument("--domain", choices=sorted(DOMAINS), default="standard",
                   help="standard: in distribution; shifted: the out-of-distribution variant (docs/lip/transfer.md)")
    m.set_defaults(func=_make_set)
    r = sub.add_parser("run", help="evaluate on rig bags (directories of bags or bags)")
    r.add_argument("captures", type=Path, nargs="+", help="rig bags, or directories of rig bags")
    r.add_argument("--weights", type=Path, help=f"<path> of <path>.pt/.json (default: the shipped {SHIPPED_WEIGHTS})")
    r.add_argument("--variant", type=_variant, action="append", default=[], metavar="NAME=PATH",
                   help=f"weights of an ablation trained for it; NAME: {', '.join(VARIANTS)}")
    r.add_argument("--mode", choices=(*MODES, "both"), default="both",
                   help="end_to_end (as deployed), oracle (true labels and calibration), or both")
    r.add_argument("--out", type=Path, default=Path("out/eval"), help="report.json and report.md go here")
    r.add_argument("--plots", type=Path, help="PNG plots go here (default: --out)")
    r.add_argument("--threads", type=int, default=1, help="torch threads")
    r.add_argument("--bone-tolerance", type=float, default=BONE_TOLERANCE_DEG, metavar="DEG",
                   help="how far the forearms and shanks may be from their calibrated IMUs' orientations "
                        "(0: the measurement; inf: the network's estimate)")
    r.add_argument("--no-surface-fit", dest="surface_fit", action="store_false",
                   help="the network's translation, not fitted to the body surface the LiDAR sees")
    r.set_defaults(func=_run)
    t = sub.add_parser("transfer", help="in distribution against out of distribution: two run reports side by side")
    t.add_argument("in_report", type=Path, help="report.json of a run on STANDARD captures")
    t.add_argument("out_report", type=Path, help="report.json of a run on SHIFTED captures")
    t.add_argument("--mode", choices=MODES, default="end_to_end")
    t.add_argument("--out", type=Path, help="transfer.json and transfer.md go here")
    t.add_argument("--held-out", nargs="*", choices=ACTIVITIES, default=[], metavar="FAMILY",
                   help="motion families the weights were trained without (lip_train --hold-out)")
    t.set_defaults(func=_transfer)
    return p


def _make_set(args: argparse.Namespace) -> int:
    configs = heldout_configs(args.count, args.seconds, args.first_seed, args.columns, args.domain)
    for bag in make_heldout_set(args.out, configs):
        print(bag)
    return 0


def _load(path: Path | None, bone_tolerance_deg: float, surface_fit: bool) -> tuple[LipModel, str]:
    if path is None:
        path = params_dir() / "weights" / SHIPPED_WEIGHTS
    if not path.with_suffix(".pt").is_file():
        raise FileNotFoundError(f"no weights at {path}.pt (train them: lip_train ... --export PATH)")
    return LipModel.load(path, bone_tolerance_deg, SURFACE_FIT if surface_fit else None), str(path)


def _run(args: argparse.Namespace) -> int:
    set_threads(args.threads)
    bags = find_captures(args.captures)
    models = {OURS: _load(args.weights, args.bone_tolerance, args.surface_fit)}
    models.update({name: _load(path, args.bone_tolerance, args.surface_fit) for name, path in args.variant})
    modes = MODES if args.mode == "both" else (args.mode,)
    contract_surface = BodySurface(BodyModel(load_skeleton()), SURFACE_POINTS)
    results: dict[str, dict[str, list[CaptureEvaluation]]] = {m: {mode: [] for mode in modes} for m in models}
    start = time.perf_counter()
    for bag in bags:
        capture = load_capture(bag)
        for name, (model, _) in models.items():
            for mode in modes:
                ev = evaluate_capture(capture, model, mode, contract_surface)
                results[name][mode].append(ev)
                print(f"lip_eval: {bag.name} {name} {mode}: {ev.frames} frames, {ev.posed} posed after the "
                      f"calibration poses ({time.perf_counter() - start:.0f} s)", file=sys.stderr, flush=True)
    meta = {
        "command": "lip_eval " + shlex.join(args.argv),
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "load_average": os.getloadavg(),
        "wall_s": round(time.perf_counter() - start, 1),
    }
    report = build_report(results, {n: w for n, (_, w) in models.items()}, meta)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "report.json").write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
    markdown = to_markdown(report)
    (args.out / "report.md").write_text(markdown, encoding="utf-8")
    plots = plot_report(report, results, args.plots or args.out)
    print(markdown)
    print(f"lip_eval: wrote {args.out / 'report.json'}, {args.out / 'report.md'}, "
          f"{', '.join(map(str, plots))}", file=sys.stderr)
    return 0


def _transfer(args: argparse.Namespace) -> int:
    reports = [json.loads(p.read_text(encoding="utf-8")) for p in (args.in_report, args.out_report)]
    try:
        comparison = transfer.compare(*reports, mode=args.mode, held_out=tuple(args.held_out))
    except KeyError as exc:
        raise ValueError(f"the reports lack {exc} (made by an older lip_eval, or without --mode {args.mode})") from None
    markdown = transfer.to_markdown(comparison)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "transfer.json").write_text(json.dumps(comparison, indent=1) + "\n", encoding="utf-8")
        (args.out / "transfer.md").write_text(markdown, encoding="utf-8")
    print(markdown)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser().parse_args(argv)
    args.argv = argv
    try:
        return args.func(args)
    except (FileNotFoundError, FileExistsError, BagError, ValueError) as exc:
        print(f"lip_eval: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
