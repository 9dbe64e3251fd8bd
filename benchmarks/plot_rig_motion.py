"""Plot the rig's procedural motions: stick-figure frames per scenario and top-view pelvis paths.

    python benchmarks/plot_rig_motion.py [--seed 3] [--out docs/img/rig_motion.png]

Each row shows one scenario: frames over a short window of its activity, each
drawn in the performer's own heading frame (facing right, seen from the front
left, left limbs blue, right limbs red) so that knee and elbow bends and arm
swing are easy to check; the right panel shows the pelvis path from above in
the LiDAR frame, with the capture area and the direction of the LiDAR.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lip_ros.rig.motion import SCENARIOS, make_motion  # noqa: E402

# (offset into the activity, window length) in seconds; mixed shows the whole capture.
WINDOWS = {
    "walk": (5.0, 1.1),
    "run": (5.0, 0.75),
    "jump": (0.3, 2.4),
    "squat": (2.2, 2.6),
    "arms": (0.5, 8.0),
    "martial": (1.0, 5.0),
    "dance": (2.0, 4.0),
}
FRAMES = 10
AZIMUTH, ELEVATION = np.radians(75.0), np.radians(12.0)


def _project(points: np.ndarray) -> np.ndarray:
    """Orthographic view of (..., 3) points from azimuth / elevation: (..., 2)."""
    ex = np.array([-np.sin(AZIMUTH), np.cos(AZIMUTH), 0.0])
    ey = np.array([-np.cos(AZIMUTH) * np.sin(ELEVATION), -np.sin(AZIMUTH) * np.sin(ELEVATION), np.cos(ELEVATION)])
    return np.stack([points @ ex, points @ ey], -1)


def _side_colour(name: str) -> str:
    return "tab:blue" if name.startswith("left") else "tab:red" if name.startswith("right") else "0.15"


def plot_frames(ax: plt.Axes, motion, times: np.ndarray, title: str) -> None:
    """Stick figures at ``times``, each in its own heading frame, side by side."""
    glob, pos = motion.sample(times).global_pose(motion.skeleton)
    skel = motion.skeleton
    ground = -motion.lidar_height
    step = 0.85 * skel.pelvis_height
    for k, (g, p) in enumerate(zip(glob, pos, strict=False)):
        fwd = g[0][:, 2]
        yaw = np.arctan2(fwd[1], fwd[0])
        c, s = np.cos(-yaw), np.sin(-yaw)
        rel = p - np.array([p[0, 0], p[0, 1], ground])
        rel = rel @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
        xy = _project(rel) + np.array([k * step, 0.0])
        for j in range(1, len(skel.names)):
            q = skel.parents[j]
            ax.plot(xy[[q, j], 0], xy[[q, j], 1], color=_side_colour(skel.names[j]), lw=1.4, solid_capstyle="round")
        ax.plot(xy[15, 0], xy[15, 1] + 0.04, "o", ms=4, color="0.15")
        ax.text(k * step, -0.12, f"{times[k]:.2f}s", ha="center", fontsize=6, color="0.4")
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_title(title, fontsize=8, loc="left")
    ax.set_aspect("equal")
    ax.set_xlim(-0.6 * step, (len(times) - 0.4) * step)
    ax.set_ylim(-0.2, 2.3 * skel.pelvis_height)
    ax.axis("off")


def plot_path(ax: plt.Axes, motion) -> None:
    """Top view of the pelvis path (L frame), capture area and LiDAR direction."""
    t = np.linspace(0.0, motion.duration, 2000)
    root = motion.sample(t).root_pos
    ax.plot(root[:, 0], root[:, 1], lw=0.8, color="tab:green")
    ax.plot(root[0, 0], root[0, 1], "k^", ms=4)
    circle = plt.Circle(motion.centre, motion.area_radius, fill=False, ls="--", color="0.5", lw=0.7)
    ax.add_patch(circle)
    to_lidar = -motion.centre / np.linalg.norm(motion.centre)
    ax.annotate(
        "",
        motion.centre + 0.9 * motion.area_radius * to_lidar,
        motion.centre,
        arrowprops={"arrowstyle": "->", "color": "0.5"},
    )
    r = motion.area_radius * 1.1
    ax.set_xlim(motion.centre[0] - r, motion.centre[0] + r)
    ax.set_ylim(motion.centre[1] - r, motion.centre[1] + r)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=6)


def main() -> None:
    """Render the figure."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--duration", type=float, default=40.0)
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "img" / "rig_motion.png")
    args = ap.parse_args()
    centre = np.array([8.0, 3.0, 0.0])
    rows = len(args.scenarios)
    fig, axes = plt.subplots(rows, 2, figsize=(15, 2.5 * rows), gridspec_kw={"width_ratios": [5, 1]}, squeeze=False)
    for row, scenario in enumerate(args.scenarios):
        t0 = time.perf_counter()
        seed = args.seed + SCENARIOS.index(scenario)
        motion = make_motion(scenario, args.duration, seed, centre, lidar_height=1.2)
        if scenario == "mixed":
            times = np.linspace(0.5, motion.duration - 0.5, FRAMES + 4)
        else:
            phase = motion.phase(scenario)
            offset, length = WINDOWS[scenario]
            times = phase.t_start + offset + np.linspace(0.0, length, FRAMES)
        acts = ", ".join(f"{p.name} {p.t_start:.1f}-{p.t_end:.1f}" for p in motion.phases)
        plot_frames(axes[row, 0], motion, times, f"{scenario} (seed {seed}): {acts}")
        plot_path(axes[row, 1], motion)
        print(f"{scenario}: built and plotted in {time.perf_counter() - t0:.2f} s")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
