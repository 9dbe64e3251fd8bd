"""Which hip the HSC4D method reads the hip LiDAR on, on rig variants built to break the reading.

For each variant and seed, a 14 s HSC4D rig capture (``lip_ros.rig.site_capture``)
is made with the sensor on the right hip (the nominal lever arm's) and on the
left; its first sweeps go through the checks the trajectory pipeline runs while
the wearer stands before the jump: :class:`~lip_ros.hsc4d.mount.SpinCheck` on
sweeps until it decides, then :class:`~lip_ros.hsc4d.mount.SideCheck` through
the mounting's rotation as the spin check leaves it, levelled with the ground's
up it read (as ``TrajectoryPipeline._use_side``). Each capture is "found" (read
on its true hip), "none" (the check did not tell: the lever arm stays as
configured) or "wrong". Variants: the rig's own (``base``); the LiDAR's minimum
range 0.3 or 0.1 m instead of 0.5 (it sees its own side's arm); the true tilt
15, 45 or 50 deg (the method is told 30); spun 180 deg; spun -25 deg (under
the spin check's 30: not corrected, the sides read through a rotation that far
off); hardly tilted (3 deg) and spun 180 (the ground shows no spin: not read);
2048 or 512 columns; 16, 32 or 128 beams over the OS1-64's field of view, and
32 beams at 512 columns (fewer or more returns seen through the same body); 20 Hz;
the wearer 0.8 or 1.35 times as thick, or 0.8 or 1.2 times the contract's size
(the rig's: 0.9-1.1; the method assumes the contract's body);
the lever arm 4-12 cm off the nominal along each axis (``lever``, six levers,
three per hip, each seed; the last beyond the 5 / 5 / 10 cm the check tries).

Progress (one line per capture) on stderr, the table on stdout.

Run:
  python benchmarks/hip_side_check.py [--seeds 0 1 2 3 4 5 7 11 1000 1001 1002] [--variants base mr0.3 ...]
      [--json out/hip_side_check.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

from lip_ros.core.body import BodyModel
from lip_ros.hsc4d.mount import HipMountPrior, SideCheck, SpinCheck
from lip_ros.rig.site_capture import SiteCapture, SiteCaptureConfig

LEFT = (0.15, 0.0, -0.1)  # the nominal lever arm mirrored
#: name: (SiteCaptureConfig fields, OusterModel fields (the rig's minimum range 0.5 m), the wearer's girth (None: the
#: seed's), the true lever arms (None: the nominal's, on the right hip))
VARIANTS: dict[str, tuple[dict, dict, float | None, tuple]] = {
    "base": ({}, {}, None, (None, LEFT)),
    "mr0.3": ({}, {"min_range": 0.3}, None, (None, LEFT)),
    "mr0.1": ({}, {"min_range": 0.1}, None, (None, LEFT)),
    "tilt15": ({"mount_tilt_up_deg": 15.0}, {}, None, (None, LEFT)),
    "tilt45": ({"mount_tilt_up_deg": 45.0}, {}, None, (None, LEFT)),
    "tilt50": ({"mount_tilt_up_deg": 50.0}, {}, None, (None, LEFT)),
    "spin180": ({"mount_spin_deg": 180.0}, {}, None, (None, LEFT)),
    "spin-25": ({"mount_spin_deg": -25.0}, {}, None, (None, LEFT)),
    "level180": ({"mount_tilt_up_deg": 3.0, "mount_spin_deg": 180.0}, {}, None, (None, LEFT)),
    "2048": ({"columns": 2048}, {}, None, (None, LEFT)),
    "512": ({"columns": 512}, {}, None, (None, LEFT)),
    "32beams": ({"beams": 32}, {}, None, (None, LEFT)),
    "16beams": ({"beams": 16}, {}, None, (None, LEFT)),
    "128beams": ({"beams": 128}, {}, None, (None, LEFT)),
    "32x512": ({"columns": 512, "beams": 32}, {}, None, (None, LEFT)),
    "20hz": ({"rate_hz": 20.0}, {}, None, (None, LEFT)),
    "girth0.8": ({}, {}, 0.8, (None, LEFT)),
    "girth1.35": ({}, {}, 1.35, (None, LEFT)),
    "scale0.8": ({"body_scale": 0.8}, {}, None, (None, LEFT)),
    "scale1.2": ({"body_scale": 1.2}, {}, None, (None, LEFT)),
    "lever": ({}, {}, None, ((-0.19, 0.03, -0.03), (0.19, 0.03, -0.03), (-0.12, -0.04, -0.17), (0.12, -0.04, -0.17),
                             (-0.21, -0.02, -0.22), (0.21, -0.02, -0.22))),
}
SEEDS = (0, 1, 2, 3, 4, 5, 7, 11, 1000, 1001, 1002)


def read_hip(capture: SiteCapture) -> tuple[str, SideCheck]:
    """The hip the checks read ``capture`` on ("right", "left" or "none": not told) and the side check."""
    spin, sweeps = SpinCheck(HipMountPrior()), []
    for _, frame in capture.frames(0, spin.config.max_sweeps):
        p = frame.points.ravel()
        sweeps.append(np.stack([p["x"], p["y"], p["z"]], axis=1).astype(np.float64))
        if spin.add(sweeps[-1]):
            break
    mount = dataclasses.replace(HipMountPrior(), spin_deg=spin.spin_deg)
    side = SideCheck(mount)
    side.check(sweeps, mount.R_M_L, spin.up_L)
    return side.hip or "none", side


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    parser.add_argument("--seconds", type=float, default=14.0)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    table: dict[str, dict[str, Counter]] = {}
    for name in args.variants:
        fields, lidar, girth, levers = VARIANTS[name]
        table[name] = {"right": Counter(), "left": Counter()}
        for seed in args.seeds:
            for lever in levers:
                config = SiteCaptureConfig(seed=seed, seconds=args.seconds, **fields,
                                           **({} if lever is None else {"mount_lever_m": lever}))
                capture = SiteCapture(config)
                capture.lidar = dataclasses.replace(capture.lidar, **lidar)
                if girth is not None:
                    capture.body = BodyModel(capture.motion.skeleton, girth=girth)
                true = "left" if lever is not None and lever[0] > 0.0 else "right"
                t0 = time.perf_counter()
                read, side = read_hip(capture)
                verdict = "found" if read == true else read if read == "none" else "wrong"
                table[name][true][verdict] += 1
                print(f"{name:9s} seed {seed:5d} {true:5s} hip {str(lever or ''):20s} {verdict:5s} "
                      f"({time.perf_counter() - t0:.1f} s) {side.status}", file=sys.stderr, flush=True)
    print(f"{'variant':10s} {'right hip: found / none / wrong':>32s} {'left hip: found / none / wrong':>32s}")
    for name, hips in table.items():
        cells = [f"{c['found']} / {c['none']} / {c['wrong']}" for c in (hips["right"], hips["left"])]
        print(f"{name:10s} {cells[0]:>32s} {cells[1]:>32s}")
    total = sum((c for hips in table.values() for c in hips.values()), Counter())
    print(f"all: {total['found']} found, {total['none']} none, {total['wrong']} wrong")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({n: {h: dict(c) for h, c in hips.items()} for n, hips in table.items()},
                                        indent=1))
    return 1 if total["wrong"] else 0


if __name__ == "__main__":
    sys.exit(main())
