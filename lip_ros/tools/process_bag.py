"""lip_process_bag IN OUT: run the live graph on a bag and record its outputs.

Starts ``fusion_node`` (sim time), ``lip_bag_record OUT`` (the output topics and
``/diagnostics``) and ``lip_bag_play IN --clock`` as separate processes over real
DDS, waits until the node has accounted for every LiDAR frame of IN (a pose,
calibrating, or skipped with a reason, or still pending for IMU data at the
end of the bag), stops them and prints a summary: frames in/out/skipped,
latency percentiles, and accuracy against ``/gt`` when IN has ground truth. With
``--plot`` it also draws the trajectory and a few skeleton frames.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray

from lip_msgs_py import msg_to_diagnostics, msg_to_pose_array
from lip_ros.bagio import bag_topics, read_messages
from lip_ros.core.rotations import geodesic_angle, quat_to_matrix
from lip_ros.outputs import GT_TOPICS, LIP_TOPICS
from lip_ros.tools.ros_cli import ArgumentParser, ToolError, run_tool, start_ros, tool_args

__all__ = ["main", "ProcessSummary", "summarize_outputs"]

INPUTS = ["/ouster/points", "/dot/left_wrist/imu", "/dot/right_wrist/imu", "/dot/left_ankle/imu",
          "/dot/right_ankle/imu"]
OUTPUTS = [LIP_TOPICS.joint_states, LIP_TOPICS.root_pose, LIP_TOPICS.joint_poses, LIP_TOPICS.skeleton,
           "/diagnostics"]
MATCH_NS = 1_000_000  # an output and a truth pose are the same moment if their stamps are this close


def _script(name: str) -> str:
    exe = Path(sys.executable).parent / name
    if not exe.is_file():
        raise ToolError(f"{name} is not installed beside {sys.executable}")
    return str(exe)


@dataclass
class ProcessSummary:
    """What one run produced."""

    frames_in: int
    frames: dict[str, int]  # "pose", "calibrating", "skipped: <reason>", "pending" -> frames
    latency_ms: dict[str, float] = field(default_factory=dict)
    matched: int = 0  # poses with a /gt pose at the same stamp
    translation_cm: float | None = None
    mpjpe_mm: float | None = None  # root-relative, from /lip/joint_poses
    angular_deg: float | None = None  # mean geodesic error of the 24 global joint rotations

    def lines(self) -> list[str]:
        """Human-readable report."""
        out = [f"frames in: {self.frames_in}; " + ", ".join(f"{k} {v}" for k, v in sorted(self.frames.items()))]
        if self.latency_ms:
            out.append("latency (cloud received -> pose published): "
                       + ", ".join(f"{k} {v:.1f} ms" for k, v in self.latency_ms.items()))
        if self.translation_cm is not None:
            out.append(f"accuracy on {self.matched} frames vs /gt: root translation {self.translation_cm:.1f} cm, "
                       f"MPJPE {self.mpjpe_mm:.1f} mm, global angular error {self.angular_deg:.1f} deg")
        return out


def _poses(bag: Path, topic: str) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    out = {}
    for m in read_messages(bag, [topic]):
        p = msg_to_pose_array(m.msg)
        out[p.stamp_ns] = (p.positions, p.quats)
    return out


def summarize_outputs(inputs: Path, outputs: Path) -> ProcessSummary:
    """Frame accounting (last /diagnostics of the node) and accuracy against the inputs' /gt topics."""
    diags = [msg_to_diagnostics(m.msg) for m in read_messages(outputs, ["/diagnostics"])]
    pipeline = [s for d in diags for s in d.statuses if s.name.endswith(": pipeline")]
    if not pipeline:
        raise ToolError(f"{outputs} holds no diagnostics of fusion_node")
    values = pipeline[-1].values
    frames = {k.removeprefix("frames "): int(v) for k, v in values.items() if k.startswith("frames ") and int(v)}
    latency = {k.removeprefix("latency_ms_"): float(v) for k, v in values.items() if k.startswith("latency_ms_")}
    summary = ProcessSummary(bag_topics(inputs)["/ouster/points"].count, frames, latency)
    if GT_TOPICS.joint_poses not in bag_topics(inputs):
        return summary
    truth = _poses(inputs, GT_TOPICS.joint_poses)
    stamps = np.array(sorted(truth), dtype=np.int64)
    trans, mpjpe, angle = [], [], []
    for stamp, (pos, quats) in _poses(outputs, LIP_TOPICS.joint_poses).items():
        k = int(stamps[np.argmin(np.abs(stamps - stamp))])
        if abs(k - stamp) > MATCH_NS:
            continue
        t_pos, t_quats = truth[k]
        trans.append(np.linalg.norm(pos[0] - t_pos[0]))
        mpjpe.append(np.linalg.norm((pos - pos[0]) - (t_pos - t_pos[0]), axis=1).mean())
        angle.append(np.degrees(geodesic_angle(quat_to_matrix(quats), quat_to_matrix(t_quats))).mean())
    if trans:
        summary.matched = len(trans)
        summary.translation_cm = 100 * float(np.mean(trans))
        summary.mpjpe_mm = 1000 * float(np.mean(mpjpe))
        summary.angular_deg = float(np.mean(angle))
    return summary


def plot_outputs(inputs: Path, outputs: Path, png: Path) -> Path:
    """Top view of the estimated and true pelvis paths, and four skeleton frames side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lip_ros.core.skeleton import load_skeleton

    parents = load_skeleton().parents
    est = _poses(outputs, LIP_TOPICS.joint_poses)
    truth = _poses(inputs, GT_TOPICS.joint_poses) if GT_TOPICS.joint_poses in bag_topics(inputs) else {}
    if not est:
        raise ToolError("no poses to plot")
    fig = plt.figure(figsize=(15, 5))
    top = fig.add_subplot(1, 5, 1)
    for poses, style, label in ((truth, "k-", "truth"), (est, "r-", "lip_ros")):
        if poses:
            path = np.array([poses[s][0][0] for s in sorted(poses)])
            top.plot(path[:, 0], path[:, 1], style, lw=1, label=label)
    top.set(title="pelvis path (top view, os_lidar)", xlabel="x (m)", ylabel="y (m)", aspect="equal")
    top.legend(fontsize=8)
    stamps = sorted(est)
    for i, s in enumerate(stamps[:: max(1, len(stamps) // 4)][:4]):
        ax = fig.add_subplot(1, 5, i + 2)
        for poses, colour in ((truth, "k"), (est, "tab:red")):
            near = [t for t in poses if abs(t - s) <= MATCH_NS]
            if near:
                pos = poses[near[0]][0]
                for c, p in enumerate(parents):
                    if p >= 0:
                        ax.plot(pos[[p, c], 1], pos[[p, c], 2], c=colour, lw=2)
        ax.set(title=f"t = {(s - stamps[0]) * 1e-9:.1f} s", xlabel="y (m)", aspect="equal")
        ax.invert_xaxis()
    fig.suptitle("lip_ros (red) vs truth (black), seen from the LiDAR")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=100)
    plt.close(fig)
    return png


def _wait_accounted(node: subprocess.Popen, frames_in: int, timeout_s: float) -> None:
    """Wait until the node's diagnostics account for every input frame (they are recorded as they come)."""
    node_ros = rclpy.create_node("lip_process_bag")
    seen: list[int] = [0]

    def on_diag(msg: DiagnosticArray) -> None:
        for s in msg_to_diagnostics(msg).statuses:
            if s.name.endswith(": pipeline"):
                seen[0] = sum(int(v) for k, v in s.values.items() if k.startswith("frames "))

    node_ros.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    deadline = time.monotonic() + timeout_s
    while seen[0] < frames_in and time.monotonic() < deadline and node.poll() is None:
        rclpy.spin_once(node_ros, timeout_sec=0.2)
    node_ros.destroy_node()


def _run(argv: list[str]) -> int:
    p = ArgumentParser(prog="lip_process_bag", description=__doc__.split("\n\n")[0])
    p.add_argument("inputs", type=Path, help="bag with /ouster/points and /dot/*/imu (and /gt/* if synthetic)")
    p.add_argument("outputs", type=Path, help="bag directory to create with the graph's outputs")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor")
    p.add_argument("--plot", type=Path, help="write a PNG of the trajectory and skeleton frames here")
    p.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for the last frames after playback")
    args = p.parse_args(tool_args(argv))
    if not (args.inputs / "metadata.yaml").is_file():
        raise ToolError(f"{args.inputs} is not a rosbag2 bag directory")
    if args.outputs.exists():
        raise ToolError(f"{args.outputs} exists; choose a new directory")
    frames_in = bag_topics(args.inputs).get("/ouster/points")
    if frames_in is None:
        raise ToolError(f"{args.inputs} has no /ouster/points")
    start_ros(argv)
    calibration = args.outputs.with_name(args.outputs.name + "_calibration.yaml")
    node = subprocess.Popen([_script("fusion_node"), "--ros-args", "-p", "use_sim_time:=true",
                             "-p", "diagnostics_period_s:=0.5", "-p", f"calibration_file:={calibration}"])
    recorder = subprocess.Popen([_script("lip_bag_record"), str(args.outputs), "--topics", *OUTPUTS],
                                stdout=subprocess.DEVNULL)
    try:
        play = subprocess.run([_script("lip_bag_play"), str(args.inputs), "--clock", "--wait-for-subscribers",
                               "--rate", str(args.rate), "--topics", *INPUTS])
        if play.returncode != 0:
            raise ToolError("lip_bag_play failed")
        _wait_accounted(node, frames_in.count, args.timeout)
        time.sleep(1.0)  # one more diagnostics period reaches the recorder
    finally:
        for proc in (recorder, node):
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=30)
    summary = summarize_outputs(args.inputs, args.outputs)
    print("\n".join(summary.lines()))
    if args.plot:
        print(f"plot: {plot_outputs(args.inputs, args.outputs, args.plot)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``lip_process_bag``."""
    return run_tool("lip_process_bag", _run, sys.argv if argv is None else argv)


if __name__ == "__main__":
    raise SystemExit(main())
