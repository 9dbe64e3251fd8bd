"""The scene-aware optimisation's settings on development captures: the offline refinement per setting.

Each capture (``--seeds``, ``--seconds``) is simulated and played through a
:class:`~lip_ros.hsc4d.refinement.CaptureRefiner` once; the refinement is then
repeated for every combination of the contact weight, the stance speed, the
orientation weight, an offset on the sole height measured, the sliding
weight and the legs' pose weight (``--contact``, ``--stance``, ``--orientation``,
``--sole-offset``, ``--sliding``, ``--pose``), and the refined trajectory and body are measured against the
truth as ``hsc4d_eval`` does, but with the refined body's standing feet not held afterwards (the optimisation's
own bodies; ``RefinementConfig.foot_lock``). Per setting also where the sliding comes from:
the motion of a truly standing foot from frame to frame where the suit finds
it standing too (the sliding term holds it there) and where it does not (the
stance's edges, where the foot rolls), each against the truth's own motion on
the same frames. Prints per capture and setting, then the means per setting.
Use development seeds only (the held-out ones, 1000 and up, judge the choice).

Run:
  python benchmarks/hsc4d_scene_grid.py --seeds 0 3 11 [--seconds 90] [--contact 0 1 3] [--stance 0.5 0.7 1.0]
      [--orientation 1 0.5] [--sole-offset 0 0.015] [--sliding 3] [--pose 0.3]
"""

from __future__ import annotations

import argparse
import itertools
from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from lip_ros.core.skeleton import load_skeleton
from lip_ros.hsc4d import evaluation as ev
from lip_ros.hsc4d.refinement import CaptureRefiner, RefinementConfig
from lip_ros.hsc4d.scene_optimisation import SceneOptimisationConfig, stance_from_suit
from lip_ros.hsc4d.suit_body import FEET
from lip_ros.rig.site_capture import SiteCapture, SiteCaptureConfig

_KEYS = ("ate_m", "vertical_m", "checkpoint_m", "contact_m", "sliding_m")


def _figures(m: dict[str, float]) -> str:
    where = "; ".join(f"where the suit {'finds the stance' if name == 'suit_stands' else 'does not'}: "
                      f"{100 * m[f'sliding_{name}_m']:.2f} (truth {100 * m[f'truth_{name}_m']:.2f}, "
                      f"{100 * m[f'share_{name}']:.0f} % of the sliding)" for name in ("suit_stands", "suit_not"))
    return (" ".join(f"{k.removesuffix('_m')} {100 * m[k]:.2f}" for k in _KEYS) + f" mpjpe {m['mpjpe_mm']:.2f}"
            + f"; sliding {where}")


def _setting(setting: tuple[float, ...]) -> str:
    contact, stance, orientation, offset, sliding, pose = setting
    return (f"contact {contact:g} stance {stance:g} orientation {orientation:g} sole {offset:+.3f} "
            f"sliding {sliding:g} pose {pose:g}")


def main() -> None:
    """Command line."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 3, 11])
    p.add_argument("--seconds", type=float, default=90.0)
    p.add_argument("--contact", type=float, nargs="+", default=[0.0, 1.0, 3.0])
    p.add_argument("--stance", type=float, nargs="+", default=[0.5, 0.7, 1.0])
    p.add_argument("--orientation", type=float, nargs="+", default=[1.0, 0.5])
    p.add_argument("--sole-offset", type=float, nargs="+", default=[0.0, 0.015])
    p.add_argument("--sliding", type=float, nargs="+", default=[SceneOptimisationConfig.sliding])
    p.add_argument("--pose", type=float, nargs="+", default=[SceneOptimisationConfig.pose])
    args = p.parse_args()
    settings = [s for s in itertools.product(args.contact, args.stance, args.orientation, args.sole_offset,
                                             args.sliding, args.pose)
                if s[0] or not s[3]]  # a sole offset matters only with contact
    feet = [load_skeleton().index(f) for f in FEET]
    results: dict[tuple, list[dict[str, float]]] = {s: [] for s in settings}
    for seed in args.seeds:
        capture = SiteCapture(SiteCaptureConfig(seed=seed, seconds=args.seconds))
        refiner = CaptureRefiner(RefinementConfig(foot_lock=None))  # the optimisation's bodies, their feet not held
        for k, stamp_ns, points, point_ns in ev.capture_sweeps(capture, refiner):
            refiner.add_sweep(points, point_ns, stamp_ns)
            if k % 100 == 0:
                print(f"  seed {seed}: sweep {k + 1}/{capture.num_frames}", flush=True)
        live = refiner.record
        t_s = (live.stamps_ns - capture.epoch_ns) * 1e-9
        truth = capture.truth(t_s)
        jump = next(end for name, _, end in capture.phases_ns() if name == "jump")
        sole = refiner.refine().sole_m
        landing_s = (jump - capture.epoch_ns) * 1e-9
        standing = truth.contacts.stance & (t_s >= landing_s)[:, None]
        both = standing[1:] & standing[:-1]  # the frame pairs the sliding metric measures
        true_steps = np.linalg.norm(np.diff(truth.joints[:, feet], axis=0), axis=-1)
        for setting in settings:
            contact, stance, orientation, offset, sliding, pose = setting
            config = replace(SceneOptimisationConfig(), contact=contact, stance_speed_mps=stance,
                             orientation=orientation, sliding=sliding, pose=pose)
            r = refiner.refine(config, sole + offset)
            run = SimpleNamespace(  # what the metrics read of a TrajectoryRun
                seed=seed, t_s=t_s, positions={"refined": r.pelvis[:, :3, 3]}, joints={"refined": r.body.joints},
                truth=truth.pelvis, true_joints=truth.joints, true_stance=truth.contacts.stance,
                ground=capture.terrain.surface_height(truth.pelvis[:, :2]),
                landing_s=landing_s)
            m = ev.trajectory_metrics(run)["refined"] | ev.body_metrics(run, capture.terrain)["refined"]
            steps = np.linalg.norm(np.diff(r.body.joints[:, feet], axis=0), axis=-1)
            suit = stance_from_suit(live.suit_joints[:, feet], t_s, stance)
            held = both & suit[1:] & suit[:-1]
            for name, pairs in (("suit_stands", held), ("suit_not", both & ~held)):
                m[f"sliding_{name}_m"] = float(steps[pairs].mean())
                m[f"truth_{name}_m"] = float(true_steps[pairs].mean())
                m[f"share_{name}"] = float(steps[pairs].sum() / steps[both].sum())
            results[setting].append(m)
            print(f"seed {seed} {_setting(setting)}: {_figures(m)}", flush=True)
    print("means (cm; sliding cm per frame; MPJPE mm):")
    for setting, ms in results.items():
        mean = {k: float(np.mean([m[k] for m in ms])) for k in ms[0]}
        print(f"{_setting(setting)}: {_figures(mean)}")


if __name__ == "__main__":
    main()
