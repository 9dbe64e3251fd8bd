"""Accuracy and time of the hip LiDAR's odometry (lip_ros.hsc4d.lidar_odometry) on HSC4D rig captures.

Each capture (``--seeds``, ``--seconds``, ``--columns``, 10 Hz) is simulated
sweep by sweep and registered online, with the suit's pelvis IMU for the
rotation over each sweep and the vertical motion between sweeps (the nominal
mounting; the suit's clock offset taken as known: the jump sync finds it
within about 10 ms) or, with ``--no-imu``, kiss-icp's constant-velocity model;
with the suit's own odometry for the horizontal motion and the speed rule, or
without it (``--no-suit``). Printed per capture: the path
walked, the sensor's position error against the truth (in the first sweep's
frame: drift is not forgiven) at the end, its maximum and RMS, the rotation
error, and the time per sweep (p50, p99; only ``register``, not the
simulation). ``--plot PNG`` draws the trajectories from above and their
heights over time. Run: ``python benchmarks/bench_hsc4d_odometry.py``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from lip_ros.core.rotations import matrix_to_axis_angle
from lip_ros.hsc4d.lidar_odometry import LidarOdometry
from lip_ros.hsc4d.mount import HipMountPrior
from lip_ros.hsc4d.pelvis_rotation import PelvisRotation
from lip_ros.hsc4d.suit_track import SuitTrack
from lip_ros.rig.site_capture import SiteCapture, SiteCaptureConfig


def run(seed: int, seconds: float, columns: int, imu: bool, suit: bool) -> dict:
    """One capture: estimated and true sensor positions (N, 3) in the first sweep's frame, errors, times."""
    capture = SiteCapture(SiteCaptureConfig(seed=seed, seconds=seconds, columns=columns))
    rotation = track = None
    offset_ns = int(round(capture.suit.clock_offset_s * 1e9))
    if suit:
        odometry = capture.suit_odometry()
        track = SuitTrack(capacity=64)
        track.set_offset(offset_ns)
    if imu:
        pelvis = capture.suit_streams()["pelvis"]
        rotation = PelvisRotation(HipMountPrior().R_M_L, capacity=len(pelvis.stamp_ns))
        for sample in pelvis.samples("mocap_pelvis"):
            rotation.add(sample)
        rotation.set_offset(offset_ns)
    lidar_odometry = LidarOdometry()
    half = capture.lidar.period_ns // 2
    stamps, poses, times, rejected = [], [], [], []
    fed = 0
    for k, frame in capture.frames():
        while track is not None and fed < len(odometry.stamp_ns) \
                and odometry.stamp_ns[fed] <= frame.stamp_ns + 2 * half + offset_ns:  # what has arrived
            track.add(odometry.stamp_ns[fed], odometry.position[fed], odometry.quat[fed])
            fed += 1
        p = frame.points.ravel()
        ok = np.isfinite(p["x"])
        xyz = np.stack([p["x"][ok], p["y"][ok], p["z"][ok]], 1).astype(np.float64)
        t0 = time.perf_counter()
        step = lidar_odometry.register(xyz, frame.stamp_ns + p["t"][ok].astype(np.int64), frame.stamp_ns + half,
                                       rotation, track, None if rotation is None else rotation.vertical_shift,
                                       None if rotation is None else rotation.still)
        times.append(1e3 * (time.perf_counter() - t0))
        rejected.append(bool(step.rejected))
        stamps.append(step.stamp_ns)
        poses.append(step.pose)
        if k % 100 == 0:
            print(f"  seed {seed}: sweep {k}/{capture.num_frames}", flush=True)
    truth = capture.lidar_poses(np.array(stamps))
    truth = np.linalg.inv(truth[0]) @ truth
    poses = np.array(poses)
    err = np.linalg.norm(poses[:, :3, 3] - truth[:, :3, 3], axis=1)
    turn = np.degrees(np.linalg.norm(matrix_to_axis_angle(
        np.einsum("nba,nbc->nac", truth[:, :3, :3], poses[:, :3, :3])), axis=1))
    return {"t": (np.array(stamps) - stamps[0]) * 1e-9, "estimate": poses[:, :3, 3], "truth": truth[:, :3, 3],
            "err": err, "turn": turn, "ms": np.array(times), "rejected": np.array(rejected),
            "path": float(np.sum(np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1)))}


def plot(results: dict[int, dict], out: Path) -> None:
    """Trajectories from above and heights over time, estimate against truth, per capture."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(results), figsize=(5.5 * len(results), 8.5), squeeze=False)
    for col, (seed, r) in enumerate(results.items()):
        # the first sweep's sensor frame looks up 30 deg: show it as is (x forward, y left)
        axes[0, col].plot(r["truth"][:, 0], r["truth"][:, 1], "k-", lw=1.0, label="truth")
        axes[0, col].plot(r["estimate"][:, 0], r["estimate"][:, 1], "r--", lw=1.0, label="odometry")
        axes[0, col].set(aspect="equal", xlabel="x (m)", ylabel="y (m)",
                         title=f"seed {seed}: {r['path']:.0f} m, end error {r['err'][-1]:.2f} m")
        axes[0, col].legend()
        axes[1, col].plot(r["t"], r["err"], "r-", lw=0.8, label="position error (m)")
        axes[1, col].plot(r["t"], r["turn"] / 10.0, "b-", lw=0.8, label="rotation error (deg / 10)")
        axes[1, col].set(xlabel="time (s)", title="error against the truth")
        axes[1, col].legend()
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)


def main() -> None:
    """Command line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 3, 11])
    parser.add_argument("--seconds", type=float, default=90.0)
    parser.add_argument("--columns", type=int, choices=(512, 1024, 2048), default=1024)
    parser.add_argument("--no-imu", action="store_true", help="no pelvis IMU: kiss-icp's constant-velocity rotation")
    parser.add_argument("--no-suit", action="store_true",
                        help="no suit odometry: the constant-velocity translation, no speed rule")
    parser.add_argument("--plot", type=Path, help="write a PNG here")
    args = parser.parse_args()
    results = {}
    for seed in args.seeds:
        r = results[seed] = run(seed, args.seconds, args.columns, not args.no_imu, not args.no_suit)
        print(f"seed {seed}: {len(r['t'])} sweeps, path {r['path']:.1f} m; position error end {r['err'][-1]:.3f} m, "
              f"max {r['err'].max():.3f}, rms {np.sqrt(np.mean(r['err'] ** 2)):.3f}; rotation error end "
              f"{r['turn'][-1]:.2f} deg, max {r['turn'].max():.2f}; register p50 {np.median(r['ms']):.1f} ms, "
              f"p99 {np.percentile(r['ms'], 99):.1f} ms; {int(r['rejected'].sum())} registrations not believed")
    if args.plot:
        plot(results, args.plot)
        print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
