"""lip_process_bag IN OUT: run the live graph on a bag and record its outputs.

The bag's topics say which branch runs: a hip LiDAR (``/hip/points``) and the
suit run the HSC4D graph (``fusion_node -p branch:=hsc4d``), the static Ouster
(``/ouster/points``) and the DOTs the LIP graph. Starts ``fusion_node`` (sim
time), ``lip_bag_record OUT`` (the output topics and ``/diagnostics``) and
``lip_bag_play IN --clock`` as separate processes over real DDS, waits until
the graph's nodes have accounted for every LiDAR frame of IN (a pose,
calibrating, or skipped with a reason, or still pending at the end of the bag:
the ``frames ...`` and ``pending`` values of their ``<node>: frames``
diagnostics), stops them and prints a summary: frames in/out/skipped,
latency percentiles, accuracy against the truth when IN has it, and the
wall time from the start of playback to the last pose as a multiple of real
time (``--rate`` plays the bag faster). ``--paced`` plays no faster than the
graph takes and poses the clouds (``lip_bag_play --paced-by``: its poses, and
the count of clouds its LiDAR input reports on /diagnostics, which paces it
before the first pose too, LIP calibrating, HSC4D waiting for the jump), as
processing a recorded bag wants (docs/reliability.md "Bags played paced").
Without it the bag plays as the sensors would, and a graph too slow for them
loses clouds, as it would live. With ``--plot`` it also draws the
trajectory and a few skeleton frames (LIP), or the trajectory from above, its
height over time against the truth and the suit's own odometry, and the map
(HSC4D: :mod:`lip_ros.tools.hsc4d_outputs`).

HSC4D only: ``--refine`` then also runs the offline refinement on IN
(:mod:`lip_ros.hsc4d.refinement`: the whole capture's pose graph, the
scene-aware optimisation on the site's map as each window saw it, the map rebuilt from the
refined trajectory) and records it beside OUT as the bag ``OUT_refined``:
``/hsc4d/refined/odometry``, ``/hsc4d/refined/{joint_states,root_pose,joint_poses}``
and ``/hsc4d/refined/map``; the summary adds its accuracy and its time
against the capture's duration.

LIP only: the calibration the graph solves is written to
``OUT_calibration.yaml`` beside OUT. A file of that name left by an earlier run is never reused silently: the
run refuses to start; ``--calibration FILE`` starts from a calibration on
purpose (the graph then poses from the first frame, without the A/T-pose).
The summary says which calibration the run used.

SIGINT or SIGTERM stop the run early: its processes are stopped as at the
end (SIGINT each), the outputs recorded so far summarised, status 0. Any of
its processes that does not end with status 0 fails the run (status 2). If the
tool itself is killed, they get SIGTERM (:func:`lip_ros.children.start_child`)
and stop rather than go on in the ROS domain.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock

from lip_msgs_py import msg_to_diagnostics, msg_to_pose_array, stamp_to_ns
from lip_msgs_py.stamps import NS_PER_S
from lip_ros.bagio import bag_span, bag_topics, read_messages
from lip_ros.children import start_child
from lip_ros.core import metrics
from lip_ros.core.rotations import quat_to_matrix
from lip_ros.core.skeleton import load_skeleton
from lip_ros.hsc4d.sensors import (
    HIP_LIDAR_TOPIC,
    HSC4D_TOPICS,
    MAP_TOPIC,
    ODOMETRY_TOPIC,
    OPTIMISED_ODOMETRY_TOPIC,
    OPTIMISED_TOPICS,
    SUIT_ODOMETRY_TOPIC,
    suit_imu_topic,
)
from lip_ros.lip.calibration import load_calibration
from lip_ros.lip.sensors import INPUT_TOPICS, LIDAR_TOPIC, LIP_TOPICS
from lip_ros.nodes.base import LOST_IN_TRANSPORT_VALUE, NOT_TAKEN_VALUE, UNKNOWN
from lip_ros.nodes.hsc4d import MOUNT_HIP_VALUE, MOUNT_SPIN_VALUE, OFFSET_VALUE, OPTIMISING_VALUE
from lip_ros.nodes.lip import CALIBRATION_NODE_NAME, DOT_LATENCY_VALUE
from lip_ros.outputs import GT_TOPICS
from lip_ros.tools.bag_play import CLOCK_QOS, CLOCK_TOPIC
from lip_ros.tools.hsc4d_outputs import Hsc4dAccuracy, hsc4d_accuracy, plot_hsc4d
from lip_ros.tools.ros_cli import (
    ArgumentParser,
    ToolError,
    installed_script,
    run_tool,
    start_ros,
    stop_on_signals,
    tool_args,
)

__all__ = ["main", "ProcessSummary", "summarize_outputs", "Branch", "LIP", "HSC4D", "branch_of_bag"]

MATCH_NS = 1_000_000  # an output and a truth pose are the same moment if their stamps are this close
CALIBRATION_FRAMES = f"{CALIBRATION_NODE_NAME}: frames"  # ... with the DOT latencies
CATCH_UP_PREFIX = "catch_up_latency_ms_"  # ... its latency of the sweeps that waited behind the backlog


@dataclass(frozen=True)
class Branch:
    """How one branch's graph runs on a bag: its LiDAR and other inputs, its outputs, the pose topic that marks
    progress, the diagnostic status with the graph's latency, the fusion_node parameters that choose it and
    ``lip_bag_play``'s with ``--paced``."""

    name: str
    lidar: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    pose_topic: str
    latency_status: str
    latency_prefix: str  # of that status's latency percentiles
    latency_of: str  # what the latency runs to from the cloud's receipt
    node_args: tuple[str, ...] = ()
    pacing_args: tuple[str, ...] = ()


#: LIP, paced: its LiDAR input (segmentation_node's, SensorDataQoS) holds 5 clouds, so the player holds a cloud
#: while 4 sent are not taken (by the received count; 1 s of them, lip_bag_play's default, lost a cloud before the
#: first pose in a make test, session 40), and the nodes report every 0.25 s (2.5 clouds at 10 Hz), not to hold
#: clouds that were taken
LIP = Branch("lip", LIDAR_TOPIC, INPUT_TOPICS,
             (LIP_TOPICS.joint_states, LIP_TOPICS.root_pose, LIP_TOPICS.joint_poses, LIP_TOPICS.skeleton,
              "/diagnostics"), LIP_TOPICS.root_pose, "pose_node: frames", "graph_latency_ms_", "pose published",
             ("-p", "diagnostics_period_s:=0.25"), ("--unreceived", str(qos_profile_sensor_data.depth - 1)))
HSC4D = Branch("hsc4d", HIP_LIDAR_TOPIC,
               (HIP_LIDAR_TOPIC, SUIT_ODOMETRY_TOPIC, *map(suit_imu_topic, load_skeleton().suit_imus)),
               (ODOMETRY_TOPIC, HSC4D_TOPICS.joint_states, HSC4D_TOPICS.root_pose, HSC4D_TOPICS.joint_poses,
                MAP_TOPIC, OPTIMISED_ODOMETRY_TOPIC, OPTIMISED_TOPICS.joint_states, OPTIMISED_TOPICS.root_pose,
                OPTIMISED_TOPICS.joint_poses, "/diagnostics"), HSC4D_TOPICS.root_pose, "hsc4d_trajectory_node: frames",
               "latency_ms_", f"{ODOMETRY_TOPIC} published", ("-p", "branch:=hsc4d", "-p", "diagnostics_period_s:=0.5"))


def rate_of_bag(bag: Path, topic: str) -> float:
    """The rate (Hz) of ``topic`` over the bag's span; ToolError if the bag has too few of its messages."""
    info = bag_topics(bag).get(topic)
    count = 0 if info is None else info.count
    first_ns, last_ns = bag_span(bag)
    if count < 2 or last_ns <= first_ns:
        raise ToolError(f"{bag}: {count} messages on {topic}: no rate")
    return (count - 1) / ((last_ns - first_ns) * 1e-9)


def suit_rate_of_bag(bag: Path) -> float:
    """The rate (Hz) of an HSC4D bag's suit odometry, which sizes the graph's suit buffers (the contract's 100 Hz
    unless the suit runs at another); ToolError if the bag has too few of its messages."""
    return rate_of_bag(bag, SUIT_ODOMETRY_TOPIC)


def branch_of_bag(bag: Path) -> Branch:
    """The branch whose LiDAR the bag has (ToolError if neither)."""
    topics = bag_topics(bag)
    for branch in (HSC4D, LIP):
        if branch.lidar in topics:
            return branch
    raise ToolError(f"{bag} has neither {HIP_LIDAR_TOPIC} (HSC4D) nor {LIDAR_TOPIC} (LIP)")


@dataclass
class ProcessSummary:
    """What one run produced."""

    frames_in: int
    frames: dict[str, int]  # "pose", "calibrating", "skipped: <reason>", "pending" -> frames
    received: int | None = None  # clouds the graph's first node took in (the rest never reached it)
    #: of the clouds not taken by that node, by the publisher's sequence numbers: (all, of which DDS said lost in
    #: transport; the rest overwritten in the node's input queue), None if the node did not say
    not_taken: tuple[int, int] | None = None
    latency_ms: dict[str, float] = field(default_factory=dict)
    latency_of: str = "pose published"  # what the latency runs to from the cloud's receipt
    matched: int = 0  # poses with a /gt pose at the same stamp
    translation_cm: float | None = None
    mpjpe_mm: float | None = None  # root-relative, from /lip/joint_poses
    calibration: str = ""  # which calibration the run used
    dot_latency: str = ""  # the DOT latencies taken off at the end, estimated or not
    angular_deg: float | None = None  # mean geodesic error of the 24 global joint rotations
    bag_s: float | None = None  # duration of the input bag
    wall_s: float | None = None  # start of playback to the last pose (or the end of playback, if later)
    rate: float = 1.0  # the player's speed factor
    hsc4d: Hsc4dAccuracy | None = None  # HSC4D: against the rig's truth
    offset_ms: str = ""  # HSC4D: the suit's clock offset the graph found
    mounting: str = ""  # HSC4D: what the checks of the hip LiDAR's mounting at the start found
    catch_up_ms: dict[str, float] = field(default_factory=dict)  # HSC4D: latency of sweeps behind the backlog
    refinement: str = ""  # HSC4D --refine: what and how fast
    optimising: int = 0  # HSC4D: frames still waiting for the scene-aware optimisation when the graph was stopped

    def lines(self) -> list[str]:
        """Human-readable report."""
        unaccounted = self.frames_in - sum(self.frames.values())
        lost = ""
        if self.received is not None:
            lost = (f" (the graph received {self.received} of the {self.frames_in} clouds: {self._not_taken()})"
                    if self.received < self.frames_in else " (every cloud was received)")
        out = [f"frames in: {self.frames_in}; " + ", ".join(f"{k} {v}" for k, v in sorted(self.frames.items()))
               + (f"; not accounted for {unaccounted}{lost}" if unaccounted else "")]
        if self.latency_ms:
            out.append(f"latency (cloud received -> {self.latency_of}): "
                       + ", ".join(f"{k} {v:.1f} ms" for k, v in self.latency_ms.items()))
        if self.catch_up_ms:
            out.append("latency of the sweeps that came while the ones held for the jump were registered: "
                       + ", ".join(f"{k} {v:.1f} ms" for k, v in self.catch_up_ms.items()))
        if self.offset_ms:
            out.append(f"suit clock offset found from the jump: {self.offset_ms} ms")
        if self.mounting:
            out.append(f"hip LiDAR's mounting checked at the start: {self.mounting}")
        if self.optimising:
            out.append(f"scene-aware optimisation: {self.optimising} frames still waiting when the graph was stopped "
                       "(not published; --timeout waits longer for the last window)")
        if self.refinement:
            out.append(self.refinement)
        if self.hsc4d is not None:
            out += self.hsc4d.lines()
        if self.translation_cm is not None:
            out.append(f"accuracy on {self.matched} frames vs /gt: root translation {self.translation_cm:.1f} cm, "
                       f"MPJPE {self.mpjpe_mm:.1f} mm, global angular error {self.angular_deg:.1f} deg")
        if self.calibration:
            out.append(f"calibration: {self.calibration}")
        if self.dot_latency:
            out.append(f"DOT latency taken off (ms): {self.dot_latency}")
        if self.wall_s is not None and self.bag_s is not None:
            out.append(f"wall time (playback start -> last pose): {self.wall_s:.1f} s for {self.bag_s:.1f} s of bag, "
                       f"{self.bag_s / self.wall_s:.2f}x real time (--rate {self.rate:g})")
        return out

    def _not_taken(self) -> str:
        """Where the clouds the graph did not receive went, as far as its input counted them."""
        if self.not_taken is None:
            return "lost in transport or overwritten in its input's queue"
        counted, lost = self.not_taken
        out = (f"its input counted {counted} published and never taken, {lost} lost in transport, {counted - lost} "
               "overwritten in its queue")
        beyond = self.frames_in - self.received - counted  # before the first cloud taken or after the last
        if beyond < 0:  # the count's numbers are every publisher's of the topic: not only this bag's clouds
            return out + f"; {-beyond} more than the bag's clouds it missed (other publishers of the topic?)"
        return out + (f"; {beyond} more before the first cloud it took or after the last" if beyond else "")


def _poses(bag: Path, topic: str) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    out = {}
    for m in read_messages(bag, [topic]):
        p = msg_to_pose_array(m.msg)
        out[p.stamp_ns] = (p.positions, p.quats)
    return out


def _percentiles(values: dict[str, str], prefix: str) -> dict[str, float]:
    """The whole run's latency percentiles and maximum (ms) of a status's values ``<prefix>p50`` ... ``max``."""
    return {k: float(values[prefix + k]) for k in ("p50", "p90", "p99", "max") if prefix + k in values}


def summarize_outputs(inputs: Path, outputs: Path, branch: Branch = LIP, refined: Path | None = None
                      ) -> ProcessSummary:
    """Frame accounting (last /diagnostics of the nodes) and accuracy against the inputs' truth (HSC4D: also of
    the offline refinement's bag ``refined``, if given)."""
    last, lidar = {}, {}  # status name -> its last values; ... of the LiDAR's inputs
    for m in read_messages(outputs, ["/diagnostics"]):
        for s in msg_to_diagnostics(m.msg).statuses:
            last[s.name] = s.values
            if s.hardware_id == branch.lidar and "received" in s.values:
                lidar[s.name] = s.values
    first = max(lidar.values(), key=lambda v: int(v["received"]), default=None)  # the node that took the most
    not_taken = None
    if first is not None and first.get(NOT_TAKEN_VALUE, UNKNOWN) != UNKNOWN:
        not_taken = (int(first[NOT_TAKEN_VALUE]), int(first[LOST_IN_TRANSPORT_VALUE]))
    if branch.latency_status not in last:
        raise ToolError(f"{outputs} holds no diagnostics of the {branch.name} graph ({branch.latency_status})")
    frames = {k.removeprefix("frames "): int(v) for name, values in last.items() if name.endswith(": frames")
              for k, v in values.items() if k.startswith("frames ") and int(v)}
    pending = sum(int(values.get("pending", 0)) for name, values in last.items() if name.endswith(": frames"))
    if pending:  # waiting for DOT data past the end of the bag
        frames["pending"] = pending
    latency = _percentiles(last[branch.latency_status], branch.latency_prefix)
    summary = ProcessSummary(bag_topics(inputs)[branch.lidar].count, frames,
                             None if first is None else int(first["received"]), not_taken, latency, branch.latency_of,
                             dot_latency=last.get(CALIBRATION_FRAMES, {}).get(DOT_LATENCY_VALUE, ""))
    if branch is HSC4D:
        offset = next((v.get(OFFSET_VALUE) for v in last.values() if OFFSET_VALUE in v), "")
        summary.offset_ms = "" if offset in ("", "unknown") else offset
        checks = next((v for v in last.values() if MOUNT_SPIN_VALUE in v), {})
        summary.mounting = "; ".join(f"{what} {checks[key]}" for what, key in (("spin:", MOUNT_SPIN_VALUE),
                                                                               ("hip:", MOUNT_HIP_VALUE))
                                     if key in checks)
        summary.catch_up_ms = _percentiles(last[branch.latency_status], CATCH_UP_PREFIX)
        summary.optimising = sum(int(v.get(OPTIMISING_VALUE, 0)) for v in last.values())
        summary.hsc4d = hsc4d_accuracy(inputs, outputs, round(float(offset) * 1e6) if summary.offset_ms else None,
                                       refined)
        return summary
    if GT_TOPICS.joint_poses not in bag_topics(inputs):
        return summary
    truth = _poses(inputs, GT_TOPICS.joint_poses)
    stamps = np.array(sorted(truth), dtype=np.int64)
    pairs = []  # (estimate, truth) of each output matched to a truth pose
    for stamp, estimate in _poses(outputs, LIP_TOPICS.joint_poses).items():
        k = int(stamps[np.argmin(np.abs(stamps - stamp))])
        if abs(k - stamp) <= MATCH_NS:
            pairs.append((estimate, truth[k]))
    if pairs:
        pos, quats = (np.array(a) for a in zip(*(estimate for estimate, _ in pairs)))
        t_pos, t_quats = (np.array(a) for a in zip(*(true for _, true in pairs)))
        summary.matched = len(pairs)
        summary.translation_cm = 100 * float(metrics.translation_error(pos[:, 0], t_pos[:, 0]).mean())
        summary.mpjpe_mm = 1000 * float(metrics.mpjpe(pos, t_pos).mean())
        summary.angular_deg = float(np.degrees(metrics.angular_error(quat_to_matrix(quats),
                                                                     quat_to_matrix(t_quats))).mean())
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


class _Watch:
    """What the tool sees of the running graph: when playback started and ended, the last pose, frames accounted."""

    def __init__(self, bag_start_ns: int, rate: float, pose_topic: str, stop: threading.Event) -> None:
        self.node = rclpy.create_node("lip_process_bag")
        self.stop = stop  # set by SIGINT or SIGTERM: stop waiting, stop the processes, report what was done
        self.bag_start_ns, self.rate = bag_start_ns, rate
        self.started: float | None = None  # monotonic s at which the player's bag time was bag_start_ns
        self.last_clock: float | None = None
        self.last_pose: float | None = None
        self.accounted = 0  # frames with an outcome or pending, per the nodes' last diagnostics
        self.pending = 0  # ... of which pending
        self.optimising = 0  # frames waiting for the HSC4D body node's scene-aware optimisation
        self._counts: dict[str, int] = {}  # "<node>: frames" -> frames accounted for there
        self._pending: dict[str, int] = {}  # ... of which pending
        self.node.create_subscription(Clock, CLOCK_TOPIC, self._on_clock, CLOCK_QOS)
        self.node.create_subscription(PoseStamped, pose_topic, self._on_pose,
                                      QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)

    def _on_clock(self, msg: Clock) -> None:
        now = time.monotonic()
        started = now - (stamp_to_ns(msg.clock) - self.bag_start_ns) / NS_PER_S / self.rate
        self.started = started if self.started is None else min(self.started, started)  # least delayed /clock
        self.last_clock = now

    def _on_pose(self, _msg: PoseStamped) -> None:
        self.last_pose = time.monotonic()

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for s in msg_to_diagnostics(msg).statuses:
            if s.name.endswith(": frames"):
                self._counts[s.name] = sum(int(v) for k, v in s.values.items()
                                           if k.startswith("frames ") or k == "pending")
                self._pending[s.name] = int(s.values.get("pending", 0))
                if OPTIMISING_VALUE in s.values:
                    self.optimising = int(s.values[OPTIMISING_VALUE])
        self.accounted = sum(self._counts.values())
        self.pending = sum(self._pending.values())

    def spin_while(self, busy: Callable[[], bool], timeout_s: float) -> None:
        """Take messages while ``busy()`` and for at most ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while busy() and time.monotonic() < deadline and not self.stop.is_set():
            rclpy.spin_once(self.node, timeout_sec=0.1)

    def wall_s(self) -> float | None:
        """Start of playback to the last pose, or to the end of playback if that came later."""
        if self.started is None or self.last_clock is None:
            return None
        return max(self.last_clock, self.last_pose or 0.0) - self.started


def _stop(procs: list[subprocess.Popen]) -> list[str]:
    """Stop the processes in reverse order of start (the player if still running, the recorder, the node) with
    SIGINT, as a user's Ctrl-C would; each that did not end with status 0 (an abort at exit, a crash, a hang: killed
    after 30 s), said in a few words."""
    failed = []
    for proc in reversed(procs):
        name = Path(str(proc.args[0])).name
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            rc = proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            rc = proc.wait()
            failed.append(f"{name} did not stop within 30 s of SIGINT (killed)")
            continue
        if rc != 0:
            what = f"signal {signal.Signals(-rc).name}" if rc < 0 else f"exit status {rc}"
            failed.append(f"{name} ended with {what}")
    return failed


def _start_calibration(out: Path, given: Path | None) -> None:
    """Prepare the graph's calibration file ``out``: refuse one left by an earlier run; copy ``given`` there."""
    if out.exists():
        raise ToolError(f"{out} exists, left by an earlier run: remove it, or start from it with "
                        f"--calibration {out} (the run writes its own calibration there)")
    if given is None:
        return
    try:
        load_calibration(given)
    except (OSError, ValueError) as exc:
        raise ToolError(f"--calibration {given}: {exc}") from exc
    shutil.copyfile(given, out)


def _run(argv: list[str]) -> int:
    p = ArgumentParser(prog="lip_process_bag", description=__doc__.split("\n\n")[0])
    p.add_argument("inputs", type=Path, help="bag with /ouster/points and /dot/*/imu (LIP) or /hip/points, "
                                             "/mocap/*/imu and /mocap/odometry (HSC4D), and /gt/* if synthetic")
    p.add_argument("outputs", type=Path, help="bag directory to create with the graph's outputs")
    p.add_argument("--rate", type=float, default=1.0,
                   help="playback speed factor (default 1: real time; 3 plays the bag 3x faster; above 1 the LIP "
                        "graph's stages overlap instead of passing each frame along on one thread: direct_inputs "
                        "false)")
    p.add_argument("--paced", action="store_true",
                   help="play no faster than the graph takes and poses the clouds (lip_bag_play --paced-by the pose "
                        "topic: its poses and its LiDAR input's counts on /diagnostics), at most at --rate; without "
                        "it the bag plays as the sensors would, and a graph that falls behind loses clouds")
    p.add_argument("--plot", type=Path, help="write a PNG of the trajectory (and skeleton frames or the map) here")
    p.add_argument("--timeout", type=float, default=30.0,
                   help="seconds to wait for the last frames after playback, and then (HSC4D) for the graph to settle: "
                        "the last sweeps on their way to the body node, its last optimisation window")
    p.add_argument("--refine", action="store_true",
                   help="HSC4D: also run the offline refinement and record it to the bag OUT_refined")
    p.add_argument("--calibration", type=Path,
                   help="LIP: start from this calibration (an earlier run's OUT_calibration.yaml) instead of finding "
                        "one in the bag")
    args = p.parse_args(tool_args(argv))
    if not (args.inputs / "metadata.yaml").is_file():
        raise ToolError(f"{args.inputs} is not a rosbag2 bag directory")
    if args.outputs.exists():
        raise ToolError(f"{args.outputs} exists; choose a new directory")
    branch = branch_of_bag(args.inputs)
    frames_in = bag_topics(args.inputs)[branch.lidar].count
    if not args.rate > 0:
        raise ToolError(f"--rate must be > 0, got {args.rate}")
    node_args = [*branch.node_args, "-p", "use_sim_time:=true"]
    calibration = args.outputs.with_name(args.outputs.name + "_calibration.yaml")
    lidar_hz = rate_of_bag(args.inputs, branch.lidar)
    node_args += ["-p", f"lidar_rate_hz:={lidar_hz:.1f}"]
    if branch is LIP:
        print(f"LiDAR: {lidar_hz:.1f} Hz in the bag (the graph's lidar_rate_hz)", flush=True)
        _start_calibration(calibration, args.calibration)
        node_args += ["-p", f"calibration_file:={calibration}"]
        if args.rate > 1.0:  # throughput before latency: the stages overlap on their own threads
            node_args += ["-p", "direct_inputs:=false"]
    else:
        if args.calibration is not None:
            raise ToolError("--calibration is for LIP bags; the HSC4D graph finds its extrinsics from the data")
        suit_hz = suit_rate_of_bag(args.inputs)
        print(f"suit: {suit_hz:.1f} Hz in the bag (the graph's suit_rate_hz); LiDAR: {lidar_hz:.1f} Hz "
              f"(its lidar_rate_hz)", flush=True)
        node_args += ["-p", f"suit_rate_hz:={suit_hz:.1f}"]
    refined = args.outputs.with_name(args.outputs.name + "_refined") if args.refine else None
    if args.refine and branch is LIP:
        raise ToolError("--refine is for HSC4D bags (the offline refinement of the HSC4D branch)")
    if refined is not None and refined.exists():
        raise ToolError(f"{refined} exists (--refine writes there); choose a new OUT or remove it")
    stop = stop_on_signals()
    start_ros(argv)
    first_ns, last_ns = bag_span(args.inputs)
    watch = _Watch(first_ns, args.rate, branch.pose_topic, stop)
    node = start_child([installed_script("fusion_node"), "--ros-args", *node_args])
    recorder = start_child([installed_script("lip_bag_record"), str(args.outputs), "--topics", *branch.outputs],
                           stdout=subprocess.DEVNULL)
    procs = [node, recorder]
    try:
        pacing = ["--paced-by", branch.pose_topic, *branch.pacing_args] if args.paced else []
        play = start_child([installed_script("lip_bag_play"), str(args.inputs), "--clock",
                            "--wait-for-subscribers", "--rate", str(args.rate), *pacing, "--topics", *branch.inputs])
        procs.append(play)
        watch.spin_while(lambda: play.poll() is None, float("inf"))
        if play.poll() is not None and play.returncode != 0:
            raise ToolError("lip_bag_play failed")
        watch.spin_while(lambda: watch.accounted < frames_in and node.poll() is None, args.timeout)

        def settled() -> bool:  # HSC4D: the last sweep may be pending in one node and on its way to the next
            return watch.optimising == 0 and (branch is LIP or (watch.pending == 0 and watch.accounted >= frames_in))

        # HSC4D: the last sweep waiting for the suit (1 s) in the trajectory node, then on its way to the body node,
        # waiting there (1 s), the partial window flushed (1 s) and optimised (seconds; tens on a starved machine)
        watch.spin_while(lambda: not settled() and node.poll() is None, args.timeout)
        if not stop.is_set():
            time.sleep(1.0)  # one more diagnostics period reaches the recorder
    finally:
        failed = _stop(procs)
        watch.node.destroy_node()
    if failed:
        raise ToolError("not shut down cleanly: " + "; ".join(failed))
    refinement = "" if refined is None else _refine(args.inputs, refined)
    summary = summarize_outputs(args.inputs, args.outputs, branch, refined if refined and refined.exists() else None)
    summary.refinement = refinement
    summary.bag_s, summary.rate = (last_ns - first_ns) / NS_PER_S, args.rate
    summary.wall_s = None if stop.is_set() else watch.wall_s()  # not a speed when cut short
    if branch is LIP:
        summary.calibration = _calibration_used(calibration, args.calibration)
    print("\n".join(summary.lines()))
    if stop.is_set():
        print("interrupted (SIGINT or SIGTERM): the processes were stopped before the end of the bag")
    if args.plot:
        png = (plot_outputs(args.inputs, args.outputs, args.plot) if branch is LIP
               else plot_hsc4d(args.outputs, summary.hsc4d, args.plot))
        print(f"plot: {png}")
    return 0


def _refine(inputs: Path, out: Path) -> str:
    """Refine the HSC4D capture ``inputs`` offline and record it to the bag ``out``; what the summary says of it."""
    from lip_ros.hsc4d.batch import refine_bag, write_refinement_bag  # torch: only when asked for

    frames = bag_topics(inputs)[HIP_LIDAR_TOPIC].count

    def progress(k: int) -> None:
        if k % 100 == 0:
            print(f"  sweep {k}/{frames}", flush=True)

    print(f"offline refinement of {frames} sweeps ...", flush=True)
    start = time.monotonic()
    try:
        refiner, refinement, skipped = refine_bag(inputs, progress=progress)
    except ValueError as exc:  # nothing posed, or no ground under the feet anywhere
        return f"offline refinement: none ({exc}); {out} not written"
    counts = write_refinement_bag(refinement, refiner.body.skeleton, out)
    wall_s = time.monotonic() - start
    capture_s = (refinement.stamps_ns[-1] - refinement.stamps_ns[0]) * 1e-9
    left_out = dict(skipped) | dict(refiner.counts) | {k: v for k, v in refiner.pipeline.counts.items()
                                                       if "dropped" in k}
    return (f"offline refinement: {len(refinement.stamps_ns)} poses of {frames} sweeps, the site's map rebuilt from "
            f"them {len(refinement.map)} points, in {wall_s:.1f} s for a {capture_s:.1f} s capture "
            f"({wall_s / max(capture_s, 1e-9):.2f} x its duration), left out: {left_out or 'nothing'}; "
            f"{sum(counts.values())} messages written to {out}")


def _calibration_used(calibration: Path, given: Path | None) -> str:
    """What the LIP run's summary says of its calibration."""
    if given is not None:
        return f"loaded from {given} (copied to {calibration})"
    if calibration.is_file():
        headings = load_calibration(calibration).headings
        return f"solved from the bag's A-pose and T-pose (DOT headings: {headings}), saved to {calibration}"
    return "none: no A-pose / T-pose calibration was found in the bag"


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``lip_process_bag``."""
    return run_tool("lip_process_bag", _run, sys.argv if argv is None else argv)


if __name__ == "__main__":
    raise SystemExit(main())
