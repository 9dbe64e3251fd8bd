"""Summarise and plot a capture bag (topics, rates, cloud layout, performer points, IMUs at rest, ground truth), and
plot a scene with height of the HSC4D rig."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from lip_msgs_py import cloud_to_array, msg_to_imu, msg_to_pose_array, read_header
from lip_ros.bagio import TopicInfo, bag_topics, read_messages
from lip_ros.core.rotations import quat_to_matrix
from lip_ros.core.skeleton import load_skeleton
from lip_ros.lip.sensors import LIDAR_TOPIC
from lip_ros.outputs import GT_TOPICS
from lip_ros.rig.bag import LABELS_FILE, TRUTH_FILE
from lip_ros.rig.mesh_raycast import MeshRaycaster
from lip_ros.rig.motion.posture import sole_points
from lip_ros.rig.site_bag import HIP_LIDAR_TOPIC
from lip_ros.rig.terrain import SITE_HALF_M, Terrain
from lip_ros.rig.trajectory import Trajectory

__all__ = ["BagSummary", "summarize_bag", "plot_bag", "plot_terrain"]


@dataclass
class BagSummary:
    """What ``lip_rig inspect`` reports."""

    path: Path
    topics: dict[str, TopicInfo]
    duration_s: float
    rates_hz: dict[str, float]
    cloud_shape: tuple[int, int] | None = None
    valid_fraction: float | None = None
    performer_points: list[int] = field(default_factory=list)
    imu_rest_norm: dict[str, float] = field(default_factory=dict)  # mean |specific force| in the A-pose window
    imu_rest_up: dict[str, float] = field(default_factory=dict)  # mean z of the unit force rotated to I
    truth: dict | None = None

    def lines(self) -> list[str]:
        """Human-readable report."""
        out = [f"bag {self.path}  ({self.duration_s:.1f} s)"]
        for topic, info in sorted(self.topics.items()):
            rate = self.rates_hz.get(topic, 0.0)
            out.append(f"  {topic:28s} {info.msgtype:32s} {info.count:6d} msgs {rate:6.1f} Hz  {info.reliability}")
        if self.cloud_shape:
            out.append(f"  clouds: {self.cloud_shape[0]} x {self.cloud_shape[1]}, "
                       f"{100 * (self.valid_fraction or 0):.1f} % of pixels return")
        if self.performer_points:
            p = np.array(self.performer_points)
            out.append(f"  performer points per frame: median {np.median(p):.0f}, min {p.min()}, max {p.max()}")
        for name, norm in self.imu_rest_norm.items():
            out.append(f"  {name}: |f| at rest {norm:.3f} m/s^2, up-component {self.imu_rest_up[name]:+.3f}")
        if self.truth:
            perf = self.truth["performer"]
            out.append(f"  truth: scenario {perf.get('scenario', 'site walk')}, body scale {perf['body_scale']:.3f}, "
                       f"phases {', '.join(p['name'] for p in self.truth['phases'])}")
        return out


def _load_truth(path: Path) -> dict | None:
    f = path / TRUTH_FILE
    if not f.is_file():
        return None
    with open(f, encoding="utf-8") as fh:
        return yaml.safe_load(fh)


def summarize_bag(path: str | Path) -> BagSummary:
    """Read the whole bag once and summarise it."""
    path = Path(path)
    topics = bag_topics(path)
    truth = _load_truth(path)
    a_pose = next((p for p in truth["phases"] if p["name"] == "a_pose"), None) if truth else None
    suit_offset_ns = int(round(truth.get("suit", {}).get("clock_offset_s", 0.0) * 1e9)) if truth else 0
    stamps: dict[str, list[int]] = {t: [] for t in topics}
    rest: dict[str, list[tuple[float, float]]] = {}
    shape, valid, pixels = None, 0, 0
    for m in read_messages(path):
        stamp, _ = read_header(m.msg)
        stamps[m.topic].append(stamp)
        if m.topic in (LIDAR_TOPIC, HIP_LIDAR_TOPIC):
            pts = cloud_to_array(m.msg, ["x"])
            shape = pts.shape
            valid += int(np.isfinite(pts["x"]).sum())
            pixels += pts.size
        elif topics[m.topic].msgtype == "sensor_msgs/msg/Imu":
            at = stamp - (suit_offset_ns if m.topic.startswith("/mocap/") else 0)  # on the LiDAR's clock
            if a_pose and a_pose["start_ns"] + 300_000_000 <= at <= a_pose["end_ns"] - 300_000_000:
                s = msg_to_imu(m.msg)
                if not np.isfinite(s.accel).all():  # not provided (a bone held for a silent DOT, lip/bones)
                    continue
                up = quat_to_matrix(s.quat) @ s.accel  # the specific force in the sensor's inertial frame
                rest.setdefault(m.topic, []).append((float(np.linalg.norm(s.accel)), float(up[2] / np.linalg.norm(up))))
    all_stamps = [s for v in stamps.values() for s in v]
    duration = (max(all_stamps) - min(all_stamps)) * 1e-9 if all_stamps else 0.0
    rates = {t: (len(v) - 1) / ((v[-1] - v[0]) * 1e-9) for t, v in stamps.items() if len(v) > 1 and v[-1] > v[0]}
    summary = BagSummary(path, topics, duration, rates, shape, valid / pixels if pixels else None, truth=truth)
    labels = path / LABELS_FILE
    if labels.is_file():
        with np.load(labels, allow_pickle=False) as z:
            actor, offsets = z["actor"], z["offsets"]
            summary.performer_points = [int((actor[a:b] == 0).sum()) for a, b in zip(offsets[:-1], offsets[1:])]
    for topic, values in rest.items():
        arr = np.array(values)
        summary.imu_rest_norm[topic] = float(arr[:, 0].mean())
        summary.imu_rest_up[topic] = float(arr[:, 1].mean())
    return summary


def plot_bag(path: str | Path, out_png: str | Path, frame_index: int | None = None) -> Path:
    """A PNG: one frame seen from above and from the LiDAR with the true skeleton, and the true root path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path, out_png = Path(path), Path(out_png)
    skel = load_skeleton()
    clouds = list(read_messages(path, [LIDAR_TOPIC]))
    truth = [msg_to_pose_array(m.msg).positions for m in read_messages(path, [GT_TOPICS.joint_poses])]
    k = len(clouds) * 2 // 3 if frame_index is None else frame_index
    pts = cloud_to_array(clouds[k].msg, ["x", "y", "z"])
    xyz = np.stack([pts["x"].ravel(), pts["y"].ravel(), pts["z"].ravel()], axis=1)
    performer = np.zeros(len(xyz), dtype=bool)
    labels = path / LABELS_FILE
    if labels.is_file():
        with np.load(labels, allow_pickle=False) as z:
            a, b = z["offsets"][k], z["offsets"][k + 1]
            performer[z["pixel"][a:b][z["actor"][a:b] == 0]] = True
    ok = np.isfinite(xyz[:, 0])
    joints = truth[k]
    root_path = np.array([t[0] for t in truth])

    fig, ax = plt.subplots(1, 3, figsize=(16, 5.5))
    ax[0].scatter(xyz[ok & ~performer, 0], xyz[ok & ~performer, 1], s=0.3, c="0.6")
    ax[0].scatter(xyz[performer, 0], xyz[performer, 1], s=2, c="tab:red", label="performer points")
    ax[0].plot(root_path[:, 0], root_path[:, 1], c="tab:blue", lw=1, label="true pelvis path")
    ax[0].plot(0, 0, "k^", ms=8, label="LiDAR")
    ax[0].set(title=f"frame {k}: top view (os_lidar)", xlabel="x (m)", ylabel="y (m)", aspect="equal")
    ax[0].legend(loc="upper left", fontsize=8)
    for a_, (i, j) in ((ax[1], (1, 2)), (ax[2], (0, 2))):
        a_.scatter(xyz[performer, i], xyz[performer, j], s=4, c="tab:red")
        for c, p in enumerate(skel.parents):
            if p >= 0:
                a_.plot(joints[[p, c], i], joints[[p, c], j], c="tab:blue", lw=2)
        a_.set(aspect="equal", xlabel="xyz"[i] + " (m)", ylabel="z (m)")
    ax[1].set_title("performer seen from the LiDAR, true skeleton")
    ax[1].invert_xaxis()
    ax[2].set_title("performer from the side")
    fig.tight_layout()
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png


def plot_terrain(terrain: Terrain, out_png: str | Path, resolution_m: float = 0.1,
                 motion: Trajectory | None = None) -> Path:
    """A PNG: the site from above (height of what a ray from the sky hits first; walkable surfaces in colour,
    obstacles in grey), and the height profiles along the stair flight and the ramp; with a ``motion`` (in the
    site's frame) also its pelvis path from above and the heights of the pelvis and the lowest sole point of
    each foot over time, against the surface under them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_png = Path(out_png)
    sx, sy = SITE_HALF_M
    x, y = np.meshgrid(np.arange(-sx, sx, resolution_m) + 0.5 * resolution_m,
                       np.arange(-sy, sy, resolution_m) + 0.5 * resolution_m)
    top = 50.0
    dist, tri = MeshRaycaster(terrain.triangles()).cast(np.stack([x.ravel(), y.ravel(), np.full(x.size, top)], 1),
                                                        np.array([0.0, 0.0, -1.0]))
    height = np.where(tri >= 0, top - dist, np.nan).reshape(x.shape)  # nothing hit: off the site
    obstacle = ((tri >= 0) & ~terrain.blocks.walkable[np.maximum(tri, 0) // 12]).reshape(x.shape)
    lay = terrain.layout
    panels = 3 if motion is not None else 2
    fig, axes = plt.subplots(1, panels, figsize=(7.5 * panels, 5.5), gridspec_kw={"width_ratios": [1.6] + [1] * (
        panels - 1)})
    image = axes[0].imshow(np.ma.masked_where(obstacle, height), origin="lower", extent=(-sx, sx, -sy, sy),
                           cmap="viridis")
    axes[0].imshow(np.ma.masked_where(~obstacle, obstacle), origin="lower", extent=(-sx, sx, -sy, sy), cmap="gray",
                   vmin=0, vmax=2)
    fig.colorbar(image, ax=axes[0], label="surface height (m)")
    axes[0].set(xlabel="x (m)", ylabel="y (m)", title="site from above (grey: obstacles)")
    for name, band, run in (("stairs", lay["stair_y_m"], (lay["risers"] - 1) * lay["tread_m"]),
                            ("ramp", lay["ramp_y_m"], lay["ramp_run_m"])):
        px = np.linspace(lay["terrace_x_m"] - run - 2.0, lay["terrace_x_m"] + 2.0, 400)
        pz = terrain.surface_height(np.stack([px, np.full(px.size, np.mean(band))], 1))
        axes[1].plot(px, pz, label=name)
    axes[1].set(xlabel="x (m)", ylabel="height (m)", title=(
        f"{lay['risers']} risers of {100 * lay['riser_m']:.1f} cm, ramp {lay['ramp_deg']:.1f} deg"))
    axes[1].legend()
    if motion is not None:
        t = np.arange(0.0, motion.duration, 0.02)
        pose = motion.sample(t)
        glob, joints = pose.global_pose(motion.skeleton)
        soles = sole_points(motion.skeleton, glob, joints).reshape(len(t), 3, 2, 3)
        lowest = np.take_along_axis(soles, np.argmin(soles[..., 2], axis=1)[:, None, :, None], axis=1)[:, 0]
        axes[0].plot(pose.root_pos[:, 0], pose.root_pos[:, 1], "r-", lw=0.8, label="pelvis")
        axes[0].legend(loc="upper right")
        axes[2].plot(t, pose.root_pos[:, 2], "k-", lw=0.8, label="pelvis")
        for side, colour in ((0, "tab:blue"), (1, "tab:orange")):
            axes[2].plot(t, lowest[:, side, 2], "-", color=colour, lw=0.6, label=("left", "right")[side] + " sole")
        axes[2].plot(t, terrain.surface_height(pose.root_pos[:, :2]), "g--", lw=0.8, label="surface under pelvis")
        axes[2].set(xlabel="time (s)", ylabel="height (m)", title="the walk: pelvis and feet")
        axes[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out_png, dpi=80)
    plt.close(fig)
    return out_png
