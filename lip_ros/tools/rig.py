"""lip_rig: make synthetic capture bags and inspect bags.

  lip_rig make-bag --scenario walk --seconds 20 --seed 3 --out DIR
  lip_rig inspect DIR [--plot PNG]
  lip_rig site --seed 3 [--walk 90] [--plot PNG]     (a scene with height of the HSC4D rig, a walk through it)
  lip_rig site-bag --seed 3 --seconds 90 --out DIR   (an HSC4D capture: hip LiDAR, suit, its odometry; the rig
                                                     variants of hsc4d_eval: --mount-lever 0.15 0 -0.1, ...)
  lip_rig faults IN OUT --fault imu_silent 6 3 [--fault ...] [--imu TOPIC]   (IN with faults: kind, start s, seconds)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from lip_ros.rig.capture import SENSORS, CaptureConfig, CaptureSession
from lip_ros.rig.faults import FAULT_KINDS, ONE_IMU_FAULTS, FaultSpec, write_faulty_bag
from lip_ros.rig.motion import SCENARIOS
from lip_ros.rig.site_capture import SiteCaptureConfig
from lip_ros.rig.terrain import SCENES
from lip_ros.tools.site_variants import add_site_arguments, site_capture_config


def _make_bag(args: argparse.Namespace) -> int:
    from lip_ros.rig.bag import write_capture_bag

    if args.out.exists():
        print(f"lip_rig: {args.out} exists; choose a new directory", file=sys.stderr)
        return 2
    window = tuple(args.azimuth_window) if args.azimuth_window else None
    config = CaptureConfig(scenario=args.scenario, seconds=args.seconds, seed=args.seed, distance_m=args.distance,
                           bearing_deg=args.bearing, sensor=args.sensor, columns=args.columns,
                           lidar_height_m=args.lidar_height, lidar_pitch_deg=args.lidar_pitch,
                           lidar_roll_deg=args.lidar_roll, body_scale=args.body_scale, facing_deg=args.facing,
                           imu_heading_spread_deg=args.imu_heading_spread, imu_latency_ms=tuple(args.imu_latency),
                           imu_latency_jitter_ms=args.imu_latency_jitter,
                           azimuth_window_deg=window, column0_azimuth_deg=args.column0_azimuth,
                           beam_azimuth_deg=tuple(args.beam_azimuth), clutter=not args.no_clutter,
                           second_person=args.second_person, max_mount_deg=args.max_mount_deg)
    t0 = time.perf_counter()
    session = CaptureSession(config)
    counts = write_capture_bag(session, args.out, progress=not args.quiet)
    wall = time.perf_counter() - t0
    size = sum(f.stat().st_size for f in args.out.iterdir()) / 1e6
    print(f"wrote {args.out}: {session.num_frames} frames, {sum(counts.values())} messages, {size:.1f} MB, "
          f"{wall:.1f} s ({session.motion.duration / wall:.1f}x real time)")
    return 0


def _inspect(args: argparse.Namespace) -> int:
    from lip_ros.rig.inspect import plot_bag, summarize_bag

    print("\n".join(summarize_bag(args.bag).lines()))
    if args.plot:
        print(f"plot: {plot_bag(args.bag, args.plot)}")
    return 0


def _site(args: argparse.Namespace) -> int:
    from lip_ros.rig.inspect import plot_terrain
    from lip_ros.rig.terrain import SITE_HALF_M, Terrain

    terrain = Terrain.random(args.seed, args.scene)
    print(f"site {2 * SITE_HALF_M[0]:g} x {2 * SITE_HALF_M[1]:g} m, {len(terrain.blocks)} blocks: "
          + ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in terrain.layout.items()
                      if not isinstance(v, tuple)))
    motion = None
    if args.walk:
        from lip_ros.rig.motion import make_site_motion

        motion = make_site_motion(terrain, args.walk, args.seed)
        print("phases: " + ", ".join(f"{p.name} {p.t_start:.1f}-{p.t_end:.1f} s" for p in motion.phases))
    if args.plot:
        print(f"plot: {plot_terrain(terrain, args.plot, motion=motion)}")
    return 0


def _site_bag(args: argparse.Namespace) -> int:
    from lip_ros.rig.site_bag import write_site_bag
    from lip_ros.rig.site_capture import SiteCapture

    if args.out.exists():
        print(f"lip_rig: {args.out} exists; choose a new directory", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    capture = SiteCapture(site_capture_config(args, args.seed))
    counts = write_site_bag(capture, args.out, progress=not args.quiet)
    wall = time.perf_counter() - t0
    size = sum(f.stat().st_size for f in args.out.iterdir()) / 1e6
    print(f"wrote {args.out}: {capture.num_frames} frames, {sum(counts.values())} messages, {size:.1f} MB, "
          f"{wall:.1f} s ({capture.motion.duration / wall:.2f}x real time)")
    return 0


def _faults(args: argparse.Namespace) -> int:
    specs = [FaultSpec(kind, float(start), float(seconds), args.imu if kind in ONE_IMU_FAULTS else None)
             for kind, start, seconds in args.fault]
    for w in write_faulty_bag(args.bag, args.out, specs, seed=args.seed):
        print(f"{w.kind}: stamps {w.start_ns} .. {w.end_ns} ({(w.end_ns - w.start_ns) * 1e-9:.2f} s): "
              f"{w.description}")
    print(f"wrote {args.out}")
    return 0


def parser() -> argparse.ArgumentParser:
    """The command-line interface."""
    p = argparse.ArgumentParser(prog="lip_rig", description="Synthetic LiDAR + IMU capture rig of lip_ros.")
    sub = p.add_subparsers(dest="command", required=True)
    m = sub.add_parser("make-bag", help="simulate a capture and record it as a rosbag2 MCAP bag")
    m.add_argument("--scenario", choices=SCENARIOS, default="walk")
    m.add_argument("--seconds", type=float, default=20.0, help="capture length, calibration included")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--out", type=Path, required=True, help="bag directory to create")
    m.add_argument("--distance", type=float, default=8.0, help="LiDAR to capture-area centre (m)")
    m.add_argument("--bearing", type=float, default=0.0, help="azimuth of the capture area in os_lidar (deg)")
    m.add_argument("--sensor", choices=sorted(SENSORS), default=CaptureConfig.sensor)
    m.add_argument("--lidar-height", type=float, default=CaptureConfig.lidar_height_m, metavar="M",
                   help="height of the LiDAR above the ground")
    m.add_argument("--lidar-pitch", type=float, default=CaptureConfig.lidar_pitch_deg, metavar="DEG",
                   help="LiDAR tilt about its y axis (positive: +x looks down)")
    m.add_argument("--lidar-roll", type=float, default=CaptureConfig.lidar_roll_deg, metavar="DEG",
                   help="LiDAR tilt about its x axis (positive: +y looks up)")
    m.add_argument("--body-scale", type=float, default=CaptureConfig.body_scale, metavar="S",
                   help="the performer's size times the contract skeleton's, about 1.72 m (default: random 0.9-1.1)")
    m.add_argument("--facing", type=float, default=CaptureConfig.facing_deg, metavar="DEG",
                   help="the performer calibrates facing the LiDAR turned by DEG (counter-clockwise from above)")
    m.add_argument("--imu-heading-spread", type=float, default=CaptureConfig.imu_heading_spread_deg, metavar="DEG",
                   help="each DOT's own inertial heading within +-DEG of the rig's (default 0: reset together)")
    m.add_argument("--imu-latency", type=float, nargs=2, default=CaptureConfig.imu_latency_ms, metavar=("LO", "HI"),
                   help="each DOT stamped on arrival, late by a constant drawn in [LO, HI] ms (default: not late)")
    m.add_argument("--imu-latency-jitter", type=float, default=CaptureConfig.imu_latency_jitter_ms, metavar="MS",
                   help="plus |normal| of this std per sample (with --imu-latency)")
    m.add_argument("--columns", type=int, choices=(512, 1024, 2048), default=1024)
    m.add_argument("--azimuth-window", type=float, nargs=2, metavar=("START", "END"),
                   help="Ouster azimuth window in encoder degrees from column 0, in sweep order (with the default "
                        "--column0-azimuth, 180 is +x); other columns return nothing")
    m.add_argument("--column0-azimuth", type=float, default=CaptureConfig.column0_azimuth_deg, metavar="DEG",
                   help="where column 0 looks in the cloud's frame: 0 is ouster-ros's os_lidar (+x), the default "
                        "180 the rig's own convention (-x); any other value is a mounting yaw")
    m.add_argument("--beam-azimuth", type=float, nargs="+", default=list(CaptureConfig.beam_azimuth_deg),
                   metavar="DEG", help="per-row azimuth offsets, cycled over the rows: a staggered (raw) OS1 cloud "
                                       "has about 4.2 1.4 -1.4 -4.2; a destaggered one a fraction of a column")
    m.add_argument("--no-clutter", action="store_true", help="ground plane only")
    m.add_argument("--second-person", action="store_true", help="add a bystander walking near the performer")
    m.add_argument("--max-mount-deg", type=float, default=40.0, help="largest IMU mounting rotation (deg)")
    m.add_argument("--quiet", action="store_true", help="no progress output")
    m.set_defaults(func=_make_bag)
    i = sub.add_parser("inspect", help="summarise a bag (and plot a frame with its ground truth)")
    i.add_argument("bag", type=Path)
    i.add_argument("--plot", type=Path, help="write a PNG here")
    i.set_defaults(func=_inspect)
    t = sub.add_parser("site", help="a scene with height of the HSC4D rig, drawn from a seed (and its plot)")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--walk", type=float, metavar="SECONDS", help="also a performer's capture through it")
    t.add_argument("--scene", choices=SCENES, default=SiteCaptureConfig.scene,
                   help="what the site holds besides the walk's terrace, stairs and ramp (all, facades only, nothing)")
    t.add_argument("--plot", type=Path, help="write a PNG here")
    t.set_defaults(func=_site)
    b = sub.add_parser("site-bag", help="simulate an HSC4D capture (hip LiDAR, suit, odometry) as an MCAP bag")
    b.add_argument("--seed", type=int, default=SiteCaptureConfig.seed)
    add_site_arguments(b)
    b.add_argument("--out", type=Path, required=True, help="bag directory to create")
    b.add_argument("--quiet", action="store_true", help="no progress output")
    b.set_defaults(func=_site_bag)
    f = sub.add_parser("faults", help="rewrite a bag with sensor faults in given windows (deterministic)",
                       epilog="fault kinds: " + "; ".join(f"{k}: {v}" for k, v in FAULT_KINDS.items()))
    f.add_argument("bag", type=Path, help="the bag to rewrite")
    f.add_argument("out", type=Path, help="bag directory to create (with faults.yaml: the windows on the sensors' "
                                          "clock)")
    f.add_argument("--fault", nargs=3, action="append", required=True, metavar=("KIND", "START_S", "SECONDS"),
                   help="a fault from START_S (receive time from the bag's first message) for SECONDS; repeatable")
    f.add_argument("--imu", metavar="TOPIC", help=f"the IMU topic the faults of one IMU ({', '.join(ONE_IMU_FAULTS)}) "
                                                  "hit (default: the first IMU topic by name)")
    f.add_argument("--seed", type=int, default=0, help="for the faults drawn at random (lidar_drops)")
    f.set_defaults(func=_faults)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``lip_rig``."""
    args = parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError, FileExistsError) as exc:
        print(f"lip_rig: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
