"""The live LIP graph at 10 Hz in separate processes: latency, CPU and memory per cloud width; lip_process_bag speed.

``graph`` (the default): for each ``--columns``, a rig capture (``lip_rig
make-bag``: walk, OS1-128, full 360 degree sweep, scene and clutter, 8 m, 40 s:
the A/T-pose calibration leaves about 350 pose frames, so that a p99 is not
the slowest frame, as it was of the 58 steady frames of the 14 s capture used
until session 60) is played in
real time by ``lip_bag_play --clock`` into the graph (``--graph fusion``:
``fusion_node``; ``split``: ``segmentation_node``, ``calibration_node`` and
``pose_node`` as three processes; or any ``--graph-cmd``), each a process of
its own with ``use_sim_time``, ``diagnostics_period_s:=0.5`` and a fresh
``calibration_file``. This process measures, without subscribing to the clouds:

- graph latency: cloud received -> ``/lip/root_pose`` published, as the graph
  reports it (``graph_latency_ms_*`` on ``/diagnostics``; only a one-process
  graph measures it), with its frame accounting (pose, calibrating, skipped by
  reason, pending) and the clouds and IMU samples it received;
- end to end, per frame: the cloud's publication by the player (its scheduled
  time: the player stamps each ``/clock`` with the bag time of the moment it is
  sent) -> ``/lip/root_pose`` received here (DDS reception timestamp), so the
  transport of the cloud is included; also from WARMUP_S after the first pose,
  when the frames held back during the calibration have been caught up;
- the transport floor, in the same run: ``floor_node.py`` (its own process)
  receives each cloud and answers with a PoseStamped; the same end-to-end
  measure of its answers, over the same window, and the graph's latency above
  it (p50 and p99); the segmentation and pose nodes' own time per frame
  (``latency_ms_p50`` of their frames statuses), to see where the rest goes;
- CPU of each graph process and of the player over playback (first to last
  ``/clock``): % of one core (utime + stime, ``/proc/<pid>/stat``), % waiting
  for a free core (run-queue delay of its threads, ``/proc/<pid>/task/*/schedstat``:
  high on a loaded machine), VmRSS at the end of playback and the VmHWM peak.

``process-bag``: ``lip_process_bag BAG OUT --rate R`` for each ``--rates``
(default: the demo bag at 1, 3 and 4): its summary (frames, latency, accuracy,
wall time as a multiple of real time) and how many of the bag's clouds and IMU
samples the graph received.

DDS stays on loopback (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) in a random
``ROS_DOMAIN_ID`` unless they are set. Progress on stderr, tables on stdout.

Run:
  python benchmarks/bench_graph.py [graph] [--columns 1024 2048] [--graph fusion|split] [--bag-dir DIR]
      [--json out/bench_graph.json] [--plot out/bench_graph.png]
  python benchmarks/bench_graph.py --bag bags/demo_walk --rate 3   # the same measures for a bag played faster
  python benchmarks/bench_graph.py process-bag [--bag bags/demo_walk] [--rates 1 3 4] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from floor_node import FLOOR_TOPIC
from geometry_msgs.msg import PoseStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from lip_msgs_py import Diagnostic, msg_to_diagnostics, read_header, stamp_to_ns
from lip_ros.bagio import bag_span, bag_topics, read_messages
from lip_ros.lip.sensors import INPUT_TOPICS, LIDAR_TOPIC, LIP_TOPICS
from lip_ros.middleware import keep_message_buffers, use_lip_dds_profile
from lip_ros.tools.bag_play import CLOCK_QOS, CLOCK_TOPIC
from lip_ros.tools.ros_cli import Progress, installed_script

REPO = Path(__file__).resolve().parents[1]
GRAPHS = {"fusion": ("fusion_node",), "split": ("segmentation_node", "calibration_node", "pose_node")}
GRAPH_ARGS = ("--ros-args", "-p", "use_sim_time:=true", "-p", "diagnostics_period_s:=0.5",
              "-p", "calibration_file:={calibration_file}")
BAG_SECONDS = 40.0
WARMUP_S = 3.0  # steady state: poses from this long after the first one (the backlog of the calibration is gone)
FLOOR_CMD = [sys.executable, str(Path(__file__).with_name("floor_node.py"))]  # the pass-through, beside the graph
DRAIN_S = 15.0  # after playback, wait at most this long for the graph to account for the last frames
SETTLE_S = 1.2  # then this long for every node's next diagnostics
STOP_S = 20.0  # SIGINT, then this long before SIGKILL
SAMPLE_S = 0.2  # /proc sampling period during playback


def progress(text: str) -> None:
    """A progress line on stderr."""
    print(f"bench_graph: {text}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------------------------------- processes

CLK_TCK = os.sysconf("SC_CLK_TCK")


@dataclass
class ProcUsage:
    """CPU time, time spent waiting for a CPU and resident memory of one process, sampled over time."""

    name: str
    pid: int
    t: list[float] = field(default_factory=list)  # monotonic s
    cpu_s: list[float] = field(default_factory=list)  # utime + stime
    wait_s: list[float] = field(default_factory=list)  # run-queue delay of its threads (runnable, no CPU free)
    rss_kb: list[int] = field(default_factory=list)
    hwm_kb: int = 0  # peak resident set (VmHWM) at the last sample

    def sample(self, now: float) -> None:
        """Read /proc/<pid>/stat, status and the threads' schedstat (nothing if the process has gone)."""
        proc = Path(f"/proc/{self.pid}")
        try:
            stat = (proc / "stat").read_text()
            status = (proc / "status").read_text()
            wait_ns = sum(int((task / "schedstat").read_text().split()[1]) for task in (proc / "task").iterdir())
        except (FileNotFoundError, ProcessLookupError):
            return
        fields = stat.rsplit(")", 1)[1].split()  # after "pid (comm)": field 3 (state) is fields[0]
        mem = {k: int(v.split()[0]) for k, v in (line.split(":", 1) for line in status.splitlines())
               if k in ("VmRSS", "VmHWM")}
        self.t.append(now)
        self.cpu_s.append((int(fields[11]) + int(fields[12])) / CLK_TCK)
        self.wait_s.append(wait_ns / 1e9)
        self.rss_kb.append(mem.get("VmRSS", 0))
        self.hwm_kb = mem.get("VmHWM", self.hwm_kb)

    def summary(self, start: float, end: float) -> dict[str, float]:
        """Over [start, end] (the first and last samples inside): CPU % of one core and % waiting for a CPU;
        RSS at the end and peak RSS (MB)."""
        t = np.array(self.t)
        inside = np.flatnonzero((t >= start) & (t <= end))
        if len(inside) < 2:
            return {"cpu_pct": float("nan"), "wait_pct": float("nan"), "rss_mb": float("nan"),
                    "hwm_mb": self.hwm_kb / 1024}
        i, j = inside[0], inside[-1]
        span = t[j] - t[i]
        return {"cpu_pct": 100 * (self.cpu_s[j] - self.cpu_s[i]) / span,
                "wait_pct": 100 * (self.wait_s[j] - self.wait_s[i]) / span,
                "rss_mb": self.rss_kb[j] / 1024, "hwm_mb": self.hwm_kb / 1024}

    def cpu_timeline(self, start: float, end: float, bin_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """CPU % of one core per ``bin_s`` over [start, end]: (bin centres s from start, %)."""
        t, cpu = np.array(self.t) - start, np.array(self.cpu_s)
        keep = (t >= 0) & (t <= end - start)
        t, cpu = t[keep], cpu[keep]
        if len(t) < 2:
            return np.zeros(0), np.zeros(0)
        edges = np.arange(0.0, t[-1] + 1e-9, bin_s)
        at = np.interp(edges, t, cpu)
        return edges[:-1] + bin_s / 2, 100 * np.diff(at) / bin_s


def start_process(cmd: list[str], log: Path) -> subprocess.Popen:
    """Start ``cmd`` with stdout and stderr to ``log``."""
    with open(log, "w") as f:
        return subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT)


def stop_processes(procs: list[subprocess.Popen]) -> None:
    """SIGINT each, wait, SIGKILL what is left after STOP_S."""
    for p in procs:
        p.send_signal(signal.SIGINT)
    deadline = time.monotonic() + STOP_S
    for p in procs:
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def graph_commands(graph: str, custom: list[str] | None, calibration_file: Path) -> list[list[str]]:
    """The graph's processes: the ``--graph-cmd`` command lines (``{calibration_file}`` filled in), else the
    executables of the ``--graph`` preset, each with GRAPH_ARGS."""
    if custom:
        return [shlex.split(c.format(calibration_file=calibration_file)) for c in custom]
    return [[installed_script(exe), *(a.format(calibration_file=calibration_file) for a in GRAPH_ARGS)]
            for exe in GRAPHS[graph]]


# ------------------------------------------------------------------------------------------------- diagnostics


def accounting(statuses: dict[str, Diagnostic]) -> tuple[dict[str, int], dict[str, float]]:
    """Frames by outcome summed over the graph's ``<node>: frames`` statuses (``frames <what>`` and ``pending``),
    and the graph's cloud-received -> pose-published latency (``graph_latency_ms_<stat>``, ms)."""
    frames: Counter[str] = Counter()
    latency = {}
    for name, s in statuses.items():
        if not name.endswith(": frames"):
            continue
        for k, v in s.values.items():
            if k.startswith("frames ") or k == "pending":
                frames[k.removeprefix("frames ")] += int(v)
            elif k.startswith("graph_latency_ms_"):
                latency[k.removeprefix("graph_latency_ms_")] = float(v)
    return {k: v for k, v in sorted(frames.items()) if v}, latency


def inputs_received(statuses: dict[str, Diagnostic], topics: list[str]) -> dict[str, int]:
    """Messages of each input topic that the graph received (the ``received`` of the status with that
    hardware_id; the largest if several nodes subscribe)."""
    out = dict.fromkeys(topics, 0)
    for s in statuses.values():
        if s.hardware_id in out:
            out[s.hardware_id] = max(out[s.hardware_id], int(s.values.get("received", 0)))
    return out


# ------------------------------------------------------------------------------------------------- graph runs


@dataclass
class GraphRun:
    """One bag through the graph."""

    label: str
    bag: str
    bag_s: float
    rate: float
    commands: list[list[str]]
    sent: dict[str, int]  # input topic -> messages in the bag
    received: dict[str, int]  # input topic -> messages the graph received
    frames: dict[str, int]  # "pose", "calibrating", "skipped: <reason>", "pending" -> frames
    graph_latency_ms: dict[str, float]  # from the graph's diagnostics
    e2e_ms: list[tuple[float, float]]  # (s since playback start, cloud published by the player -> pose received ms)
    floor_e2e_ms: list[tuple[float, float]]  # the same for the pass-through's answer (floor_node.py; [] if not run)
    usage: dict[str, dict[str, float]]  # process -> cpu_pct, wait_pct, rss_mb, hwm_mb
    cpu_timeline: dict[str, tuple[list[float], list[float]]]  # process -> (s since playback start, CPU %)
    bench_cpu_pct: float  # this process over the playback window
    player_max_lag_ms: float | None
    window_s: float  # playback: first to last sample while /clock came
    load: tuple[float, float]  # 1-min load average before and after
    statuses: dict[str, dict[str, str]]  # the graph's last /diagnostics: status name -> values

    @property
    def frames_in(self) -> int:
        """LiDAR frames in the bag."""
        return self.sent[LIDAR_TOPIC]

    def e2e_stats(self, warmup_s: float | None = None, floor: bool = False) -> dict[str, float]:
        """p50, p90, p99, max and count of the end-to-end latencies (``floor``: of the pass-through's); with
        ``warmup_s``, of the clouds published from that long after the graph's first pose on."""
        t, ms = np.array(self.floor_e2e_ms if floor else self.e2e_ms).reshape(-1, 2).T
        if warmup_s is not None and self.e2e_ms:
            ms = ms[t >= self.e2e_ms[0][0] + warmup_s]
        if not len(ms):
            return {"n": 0}
        p50, p90, p99 = np.percentile(ms, [50, 90, 99])
        return {"p50": p50, "p90": p90, "p99": p99, "max": ms.max(), "n": len(ms)}

    def above_floor(self) -> dict[str, float]:
        """Steady end-to-end p50 and p99 of the graph less the pass-through's over the same window (ms)."""
        graph, floor = self.e2e_stats(WARMUP_S), self.e2e_stats(WARMUP_S, floor=True)
        return {k: graph[k] - floor[k] for k in ("p50", "p99") if k in graph and k in floor}


class Watch:
    """This process's view of a run: /clock, /lip/root_pose arrivals, /diagnostics, process usage."""

    def __init__(self, usage: dict[str, ProcUsage]) -> None:
        self.node = rclpy.create_node("bench_graph")
        self.usage = usage
        self.clock: list[tuple[int, int]] = []  # (source timestamp ns, bag time ns) of each /clock
        self.bench_cpu: list[float] = []  # this process's CPU s at each sample
        self.sample_t: list[float] = []  # monotonic s of each /proc sample (every SAMPLE_S while /clock comes)
        self.poses: list[tuple[int, int]] = []  # (stamp ns, reception timestamp ns)
        self.floor_poses: list[tuple[int, int]] = []  # ... of the pass-through's answers
        self.statuses: dict[str, Diagnostic] = {}  # status name -> the last one
        self.node.create_subscription(Clock, CLOCK_TOPIC, self._on_clock, CLOCK_QOS)
        self.node.create_subscription(PoseStamped, LIP_TOPICS.root_pose, self._on_pose,
                                      QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self.node.create_subscription(PoseStamped, FLOOR_TOPIC,
                                      lambda msg, info: self.floor_poses.append((read_header(msg)[0],
                                                                                  info["received_timestamp"])),
                                      QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 100)

    def _on_clock(self, msg: Clock, info: dict[str, Any]) -> None:
        now = time.monotonic()
        self.clock.append((info["source_timestamp"], stamp_to_ns(msg.clock)))
        if not self.sample_t or now - self.sample_t[-1] >= SAMPLE_S:
            self.sample_t.append(now)
            self.bench_cpu.append(time.process_time())
            for u in self.usage.values():
                u.sample(now)

    def _on_pose(self, msg: PoseStamped, info: dict[str, Any]) -> None:
        self.poses.append((read_header(msg)[0], info["received_timestamp"]))

    def _on_diag(self, msg: DiagnosticArray) -> None:
        self.statuses.update((s.name, s) for s in msg_to_diagnostics(msg).statuses)

    def spin_while(self, busy: Callable[[], bool], timeout_s: float, status: Callable[[], str]) -> None:
        """Take messages while ``busy()``, for at most ``timeout_s``, showing ``status()`` now and then."""
        deadline, show = time.monotonic() + timeout_s, Progress("bench_graph", period_s=3.0)
        while busy() and time.monotonic() < deadline:
            rclpy.spin_once(self.node, timeout_sec=0.05)
            show(status())
        show.done()


def cloud_times(bag: Path) -> tuple[np.ndarray, np.ndarray]:
    """Header stamps and log times (ns) of the bag's LiDAR clouds, in log order."""
    rows = [(read_header(m.msg)[0], m.log_ns) for m in read_messages(bag, [LIDAR_TOPIC])]
    stamps, logs = np.array(rows, dtype=np.int64).T
    return stamps, logs


def end_to_end(watch: Watch, poses: list[tuple[int, int]], stamps: np.ndarray, logs: np.ndarray, first_ns: int,
               rate: float) -> list[tuple[float, float]]:
    """Per pose of ``poses`` ((stamp, reception) ns): (s from the start of playback to its cloud's publication, ms
    from there to the pose's reception).

    The player publishes the message logged at ``log`` at ``wall0 + (log - first_ns) / rate`` and stamps
    each /clock with the bag time of the moment it is sent; the least delayed /clock gives ``wall0``.
    """
    if not watch.clock:
        return []
    src, bag_ns = np.array(watch.clock, dtype=np.int64).T
    wall0 = int(np.min(src - (bag_ns - first_ns) / rate))
    order = np.argsort(stamps)
    out = []
    for stamp, received in poses:
        i = np.searchsorted(stamps[order], stamp, side="right") - 1  # the cloud scanned at the pose time
        if i < 0:
            continue
        k = order[i]
        published = wall0 + (logs[k] - first_ns) / rate
        out.append(((logs[k] - first_ns) / 1e9 / rate, (received - published) / 1e6))
    return sorted(out)


def run_graph(bag: Path, label: str, commands: list[list[str]], rate: float, work: Path,
              floor: bool = True) -> GraphRun:
    """Play ``bag`` into the graph ``commands`` (and, with ``floor``, the pass-through floor_node.py beside it) and
    measure it (the graph is stopped at the end)."""
    first_ns, last_ns = bag_span(bag)
    sent = {t: bag_topics(bag)[t].count for t in INPUT_TOPICS}
    progress(f"{label}: reading the cloud stamps of {bag}")
    stamps, logs = cloud_times(bag)
    load0 = os.getloadavg()[0]
    procs: list[subprocess.Popen] = []
    usage: dict[str, ProcUsage] = {}
    watch: Watch | None = None
    try:
        for i, cmd in enumerate(commands):
            name = Path(cmd[0]).name if len(commands) == 1 else f"{i}:{Path(cmd[0]).name}"
            procs.append(start_process(cmd, work / f"{label}_{Path(cmd[0]).name}_{i}.log"))
            usage[name] = ProcUsage(name, procs[-1].pid)
        graph = list(procs)
        if floor:
            procs.append(start_process(FLOOR_CMD, work / f"{label}_floor_node.log"))
            usage["floor_node"] = ProcUsage("floor_node", procs[-1].pid)
        watch = Watch(usage)
        player_log = work / f"{label}_lip_bag_play.log"
        player = start_process([installed_script("lip_bag_play"), str(bag), "--clock", "--wait-for-subscribers",
                                "--rate", str(rate), "--topics", *INPUT_TOPICS], player_log)
        procs.append(player)
        usage["lip_bag_play"] = ProcUsage("lip_bag_play", player.pid)

        def status() -> str:
            frames, _ = accounting(watch.statuses)
            bag_t = (watch.clock[-1][1] - first_ns) / 1e9 if watch.clock else 0.0
            return (f"{label}: bag {bag_t:5.1f} / {(last_ns - first_ns) / 1e9:.1f} s, {len(watch.poses)} poses, "
                    f"{sum(frames.values())} / {len(stamps)} frames accounted")

        def graph_alive() -> bool:
            dead = [p for p in graph if p.poll() is not None]
            if dead:
                raise RuntimeError(f"graph process {dead[0].args[0]} exited with {dead[0].returncode}; "
                                   f"see the logs in {work}")
            return True

        watch.spin_while(lambda: graph_alive() and player.poll() is None, float("inf"), status)
        if player.returncode != 0:
            raise RuntimeError(f"lip_bag_play failed:\n{player_log.read_text()[-2000:]}")
        watch.spin_while(lambda: graph_alive() and sum(accounting(watch.statuses)[0].values()) < len(stamps),
                         DRAIN_S, status)
        watch.spin_while(graph_alive, SETTLE_S, status)
        for u in usage.values():
            if u.name != "lip_bag_play":
                u.sample(time.monotonic())  # the peak RSS so far
    finally:
        stop_processes(procs)
        if watch is not None:
            watch.node.destroy_node()
    if len(watch.sample_t) < 2:
        raise RuntimeError(f"{label}: no /clock received from the player")
    start, end = watch.sample_t[0], watch.sample_t[-1]  # the player's first /clock is sent as playback starts
    frames, graph_latency = accounting(watch.statuses)
    lag = re.search(r"max lag ([\d.]+) ms", player_log.read_text())
    return GraphRun(
        label=label, bag=str(bag), bag_s=(last_ns - first_ns) / 1e9, rate=rate, commands=commands, sent=sent,
        received=inputs_received(watch.statuses, INPUT_TOPICS), frames=frames, graph_latency_ms=graph_latency,
        e2e_ms=end_to_end(watch, watch.poses, stamps, logs, first_ns, rate),
        floor_e2e_ms=end_to_end(watch, watch.floor_poses, stamps, logs, first_ns, rate),
        usage={n: u.summary(start, end) for n, u in usage.items()},
        cpu_timeline={n: tuple(a.tolist() for a in u.cpu_timeline(start, end)) for n, u in usage.items()},
        bench_cpu_pct=100 * (watch.bench_cpu[-1] - watch.bench_cpu[0]) / max(end - start, 1e-9),
        player_max_lag_ms=float(lag.group(1)) if lag else None, window_s=end - start,
        load=(load0, os.getloadavg()[0]), statuses={n: s.values for n, s in sorted(watch.statuses.items())})


def rig_bag(columns: int, bag_dir: Path, seconds: float) -> Path:
    """The rig capture for ``columns`` in ``bag_dir`` (made with lip_rig make-bag unless it is there)."""
    bag = bag_dir / f"walk_{columns}_{seconds:g}s"
    if not (bag / "metadata.yaml").is_file():
        progress(f"making {bag} (lip_rig make-bag, {seconds:g} s, 128 x {columns})")
        subprocess.run([installed_script("lip_rig"), "make-bag", "--scenario", "walk", "--seconds", str(seconds),
                        "--seed", "0", "--columns", str(columns), "--quiet", "--out", str(bag)], check=True)
    return bag


def _fmt(values: dict[str, float]) -> str:
    """p50 / p90 / p99 / max (ms), and the count if given."""
    if "p50" not in values:
        return "n/a"
    return " / ".join(f"{values[k]:.0f}" for k in ("p50", "p90", "p99", "max")) + (
        f" (n={values['n']})" if "n" in values else "")


def print_graph_table(runs: list[GraphRun]) -> None:
    """Rows are measures, columns are runs."""
    rows: list[tuple[str, list[str]]] = [
        ("bag (s) at rate", [f"{r.bag_s:.1f} at {r.rate:g}x" for r in runs]),
        ("clouds received / in bag", [f"{r.received[LIDAR_TOPIC]} / {r.frames_in}" for r in runs]),
        ("IMU samples received / in bag", [f"{sum(v for t, v in r.received.items() if t != LIDAR_TOPIC)} / "
                                           f"{sum(v for t, v in r.sent.items() if t != LIDAR_TOPIC)}"
                                           for r in runs]),
        ("frames: pose", [str(r.frames.get("pose", 0)) if r.frames else "n/a" for r in runs]),
        ("frames: calibrating", [str(r.frames.get("calibrating", 0)) if r.frames else "n/a" for r in runs]),
        ("frames: skipped (reasons)", [", ".join(f"{k[9:]} {v}" for k, v in r.frames.items()
                                                 if k.startswith("skipped: ")) or ("0" if r.frames else "n/a")
                                       for r in runs]),
        ("frames: pending / not accounted", [f"{r.frames.get('pending', 0)} / {r.frames_in - sum(r.frames.values())}"
                                             if r.frames else "n/a" for r in runs]),
        ("graph latency ms p50/p90/p99/max", [_fmt(r.graph_latency_ms) for r in runs]),
        ("end-to-end ms p50/p90/p99/max", [_fmt(r.e2e_stats()) for r in runs]),
        (f"  same, from {WARMUP_S:g} s after 1st pose", [_fmt(r.e2e_stats(WARMUP_S)) for r in runs]),
        ("floor (pass-through) end-to-end, same window", [_fmt(r.e2e_stats(WARMUP_S, floor=True)) for r in runs]),
        ("graph above the floor ms p50 / p99", [" / ".join(f"{v:.1f}" for v in r.above_floor().values()) or "n/a"
                                                for r in runs]),
        ("stages ms p50: segmentation / pose", [" / ".join(r.statuses.get(f"{node}: frames", {}).get(
            "latency_ms_p50", "-") for node in ("segmentation_node", "pose_node")) for r in runs]),
    ]
    for name in dict.fromkeys(n for r in runs for n in r.usage):
        rows.append((f"{name} CPU % / wait % / RSS / peak MB",
                     [f"{u['cpu_pct']:.0f} / {u['wait_pct']:.0f} / {u['rss_mb']:.0f} / {u['hwm_mb']:.0f}"
                      if (u := r.usage.get(name)) else "-" for r in runs]))
    rows += [("player max lag ms", [f"{r.player_max_lag_ms}" for r in runs]),
             ("this process CPU %", [f"{r.bench_cpu_pct:.1f}" for r in runs]),
             ("load (1 min) before -> after", [f"{r.load[0]:.1f} -> {r.load[1]:.1f}" for r in runs])]
    width = max(len(n) for n, _ in rows)
    cols = [max(len(r.label), *(len(v[i]) for _, v in rows)) for i, r in enumerate(runs)]
    print(f"{'':<{width}}  " + "  ".join(f"{r.label:>{c}}" for r, c in zip(runs, cols)))
    for name, values in rows:
        print(f"{name:<{width}}  " + "  ".join(f"{v:>{c}}" for v, c in zip(values, cols)))


def save_png(fig: Any, png: Path, dpi: int = 100) -> None:
    """Lay out a matplotlib figure, write it to ``png`` (its folder made if needed) and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=dpi)
    plt.close(fig)


def plot_graph(runs: list[GraphRun], png: Path) -> None:
    """End-to-end latency per frame and the graph's CPU over the bag's time, one colour per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (lat, cpu) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    for i, r in enumerate(runs):
        colour = f"C{i}"
        if r.e2e_ms:
            t, ms = np.array(r.e2e_ms).T
            lat.plot(t, ms, ".-", c=colour, lw=0.8, ms=3, label=f"{r.label}: end to end (player -> pose received)")
        for key, style in (("p50", "--"), ("p99", ":")):
            if key in r.graph_latency_ms:
                lat.axhline(r.graph_latency_ms[key], c=colour, ls=style, lw=1,
                            label=f"{r.label}: graph {key} (cloud received -> published)")
        graph = [n for n in r.cpu_timeline if n != "lip_bag_play"]
        t = np.array(r.cpu_timeline[graph[0]][0]) if graph else np.zeros(0)
        if len(t):
            total = sum(np.array(r.cpu_timeline[n][1])[: len(t)] for n in graph)
            cpu.step(t, total, where="mid", c=colour, label=f"{r.label}: graph")
        pt, pc = r.cpu_timeline.get("lip_bag_play", ([], []))
        cpu.step(pt, pc, where="mid", c=colour, ls=":", label=f"{r.label}: lip_bag_play")
    lat.axhline(30, c="k", lw=0.6)
    lat.axhline(60, c="k", lw=0.6)
    lat.set(ylabel="latency (ms)", title="LIP graph at 10 Hz (targets: median 30 ms, p99 60 ms, black lines)")
    lat.legend(fontsize=7)
    cpu.set(xlabel="time since playback start (s)", ylabel="CPU (% of one core, 1 s bins)")
    cpu.legend(fontsize=7)
    save_png(fig, png)


# ----------------------------------------------------------------------------------------- lip_process_bag runs


@dataclass
class ProcessBagRun:
    """One ``lip_process_bag --rate`` run."""

    rate: float
    summary: list[str]  # its summary lines
    sent: dict[str, int]
    received: dict[str, int]  # input topic -> messages the graph received (its last diagnostics)
    wall_s: float | None
    real_time_x: float | None
    load: tuple[float, float]


def run_process_bag(bag: Path, rate: float, work: Path) -> ProcessBagRun:
    """``lip_process_bag bag <work>/rate_<rate> --rate rate``: summary and input delivery."""
    out = work / f"rate_{rate:g}"
    load0 = os.getloadavg()[0]
    progress(f"lip_process_bag {bag} --rate {rate:g}")
    proc = subprocess.run([installed_script("lip_process_bag"), str(bag), str(out), "--rate", str(rate)],
                          check=False, capture_output=True, text=True)
    (work / f"rate_{rate:g}.log").write_text(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        raise RuntimeError(f"lip_process_bag failed:\n{proc.stderr[-2000:]}")
    summary = [line for line in proc.stdout.splitlines()
               if line.startswith(("frames in", "latency", "accuracy", "wall time"))]
    statuses = {s.name: s for m in read_messages(out, ["/diagnostics"]) for s in msg_to_diagnostics(m.msg).statuses}
    wall = re.search(r"wall time .*?: ([\d.]+) s for ([\d.]+) s of bag", proc.stdout)
    return ProcessBagRun(rate, summary, {t: bag_topics(bag)[t].count for t in INPUT_TOPICS},
                         inputs_received(statuses, INPUT_TOPICS), float(wall.group(1)) if wall else None,
                         float(wall.group(2)) / float(wall.group(1)) if wall else None,
                         (load0, os.getloadavg()[0]))


def print_process_bag(runs: list[ProcessBagRun]) -> None:
    """Each run's summary and what the graph received."""
    for r in runs:
        print(f"--rate {r.rate:g} (load {r.load[0]:.1f} -> {r.load[1]:.1f}):")
        for line in r.summary:
            print(f"  {line}")
        print("  received by the graph / in the bag: " + ", ".join(
            f"{t.split('/')[-2] if t.endswith('/imu') else 'clouds'} {r.received[t]}/{r.sent[t]}" for t in r.sent))


# ------------------------------------------------------------------------------------------------------- main


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("mode", nargs="?", choices=("graph", "process-bag"), default="graph")
    p.add_argument("--columns", type=int, nargs="+", default=[1024, 2048], help="graph: Ouster widths to run")
    p.add_argument("--seconds", type=float, default=BAG_SECONDS, help="graph: length of the rig captures")
    p.add_argument("--bag-dir", type=Path, help="graph: keep (and reuse) the rig captures here")
    p.add_argument("--graph", choices=sorted(GRAPHS), default="fusion", help="graph: the executables to start")
    p.add_argument("--graph-cmd", action="append", metavar="CMD",
                   help="graph: a process of the graph as a command line (repeat for several; replaces --graph; "
                        "{calibration_file} is filled in)")
    p.add_argument("--bag", type=Path, action="append",
                   help="graph: play these bags instead of rig captures; process-bag: the bag (default demo_walk)")
    p.add_argument("--rate", type=float, default=1.0, help="graph: playback speed factor")
    p.add_argument("--no-floor", action="store_true", help="graph: without the pass-through floor_node.py beside it")
    p.add_argument("--rates", type=float, nargs="+", default=[1.0, 3.0, 4.0], help="process-bag: speed factors")
    p.add_argument("--json", type=Path, help="write the results here")
    p.add_argument("--plot", type=Path, help="graph: write a PNG of latency and CPU over time here")
    args = p.parse_args()

    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 100)))
    version = subprocess.run(["git", "-C", str(REPO), "describe", "--always", "--dirty"], check=False,
                             capture_output=True, text=True).stdout.strip()
    header = (f"lip_ros {version or '(not a git checkout)'}, ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, "
              f"discovery {os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']}, {os.cpu_count()} cores, "
              f"load average {' '.join(f'{v:.2f}' for v in os.getloadavg())} at start, message buffers "
              f"{'kept' if keep_message_buffers() else 'NOT kept (malloc options set by the user, or not glibc)'}")
    with tempfile.TemporaryDirectory(prefix="bench_graph_") as tmp:
        work = Path(tmp)
        if args.mode == "process-bag":
            bag = args.bag[0] if args.bag else REPO / "bags" / "demo_walk"
            runs = [run_process_bag(bag, rate, work) for rate in args.rates]
            print(f"lip_process_bag {bag}; {header}")
            print_process_bag(runs)
            results: dict[str, Any] = {"bag": str(bag), "runs": [asdict(r) for r in runs]}
        else:
            use_lip_dds_profile()
            rclpy.init()
            try:
                bag_dir = args.bag_dir or work
                bag_dir.mkdir(parents=True, exist_ok=True)
                bags = ({b.name: b for b in args.bag} if args.bag else
                        {f"{c} columns": rig_bag(c, bag_dir, args.seconds) for c in args.columns})
                runs = []
                for label, bag in bags.items():
                    calibration = work / f"{label.replace(' ', '_')}_calibration.yaml"
                    runs.append(run_graph(bag, label, graph_commands(args.graph, args.graph_cmd, calibration),
                                          args.rate, work, floor=not args.no_floor))
            finally:
                rclpy.try_shutdown()
            graph = " | ".join(shlex.join(c) for c in runs[0].commands) if args.graph_cmd else " + ".join(
                Path(c[0]).name for c in runs[0].commands)
            print(f"graph: {graph} ({len(runs[0].commands)} process(es)), lip_bag_play --clock at {args.rate:g}x; "
                  f"{header}")
            print_graph_table(runs)
            if args.plot:
                plot_graph(runs, args.plot)
                print(f"plot: {args.plot}")
            results = {"header": header, "runs": [{**asdict(r), "e2e_stats": r.e2e_stats(),
                                                   "e2e_stats_steady": r.e2e_stats(WARMUP_S),
                                                   "floor_stats_steady": r.e2e_stats(WARMUP_S, floor=True),
                                                   "above_floor": r.above_floor()} for r in runs]}
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=1, default=float))
        print(f"json: {args.json}")


if __name__ == "__main__":
    main()
