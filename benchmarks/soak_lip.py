"""A long capture through the LIP graph at 10 Hz in separate processes: memory, latency and frames over time.

A rig capture (``lip_rig make-bag``: walk, OS1-128, full sweep, ``--columns``,
30 s, as bench_graph.py makes it) is played by ``lip_bag_play --loop
--time-goes-on --clock`` for ``--minutes``: each pass goes on from where the
last one ended (/clock and every header stamp move on), as one long capture
would; the performer, back at the capture's start, is found again by the
T-pose. ``fusion_node`` (``use_sim_time``, its own calibration file) and the
player are processes of their own; this process samples their resident
memory and CPU (``/proc``) and reads the graph's /diagnostics: its latency
over the most recent frames (cloud received -> ``/lip/root_pose`` published,
``graph_latency_ms_recent_*``), the clouds it received, its frame accounting
and the frames waiting in it.

Printed: a row per ``--every`` minutes, then the growth after the warm-up
(``--warmup`` minutes: the medians of the graph's RSS and of its recent p50 and
p99 latency over the last row against those over the first row after the
warm-up; target: under 5 %), the clouds the player sent against those the graph
received (a last sample after the player stopped), the most frames that ever
waited. ``--plot PNG``: RSS, latency and CPU over time.

Run (about ``--minutes`` + 2 minutes; DDS on loopback in a random domain):
  python benchmarks/soak_lip.py [--minutes 60] [--columns 2048] [--bag-dir DIR] [--plot out/soak_lip.png]
      [--json out/soak_lip.json]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import rclpy
from bench_graph import (
    GRAPH_ARGS,
    ProcUsage,
    accounting,
    inputs_received,
    rig_bag,
    save_png,
    start_process,
    stop_processes,
)
from diagnostic_msgs.msg import DiagnosticArray

from lip_msgs_py import msg_to_diagnostics
from lip_ros.lip.sensors import INPUT_TOPICS, LIDAR_TOPIC
from lip_ros.middleware import use_lip_dds_profile
from lip_ros.tools.ros_cli import installed_script

SAMPLE_S = 10.0  # /proc sampling period
BAG_SECONDS = 30.0
LATENCY_STATUS = "pose_node: frames"


@dataclass
class Sample:
    """The graph at one moment (every SAMPLE_S)."""

    t_s: float  # since playback started
    rss_mb: dict[str, float]  # process -> resident memory
    cpu_s: dict[str, float]  # process -> CPU seconds so far
    p50_ms: float | None  # graph latency over its most recent frames
    p99_ms: float | None
    received: int  # clouds the graph received so far
    accounted: int  # frames accounted for so far (pose, calibrating, skipped; pending not counted)
    posed: int
    waiting: int  # frames waiting in the graph now (calibration_node pending + pose_node waiting stamps)


@dataclass
class Soak:
    """A whole run."""

    minutes: float
    columns: int
    samples: list[Sample] = field(default_factory=list)
    sent: int | None = None  # clouds the player published
    player: str = ""  # its summary line


def progress(text: str) -> None:
    """A progress line on stderr."""
    print(f"soak_lip: {text}", file=sys.stderr, flush=True)


def run(bag: Path, minutes: float, columns: int, work: Path) -> Soak:
    """Loop ``bag`` through fusion_node for ``minutes``, sampling every SAMPLE_S."""
    soak = Soak(minutes, columns)
    graph = start_process([installed_script("fusion_node"),
                           *(a.format(calibration_file=work / "calibration.yaml") for a in GRAPH_ARGS)],
                          work / "fusion_node.log")
    player = start_process([installed_script("lip_bag_play"), str(bag), "--loop", "--time-goes-on", "--clock",
                            "--wait-for-subscribers", "--topics", *INPUT_TOPICS], work / "lip_bag_play.log")
    usage = {"fusion_node": ProcUsage("fusion_node", graph.pid), "lip_bag_play": ProcUsage("lip_bag_play",
                                                                                          player.pid)}
    node = rclpy.create_node("soak_lip")
    statuses: dict = {}
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda m: statuses.update((s.name, s) for s in msg_to_diagnostics(m).statuses), 100)
    try:
        while LATENCY_STATUS not in statuses or not int(statuses[LATENCY_STATUS].values.get("frames pose", 0)):
            rclpy.spin_once(node, timeout_sec=0.1)  # until the first pose: start-up and calibration
            if graph.poll() is not None or player.poll() is not None:
                raise RuntimeError(f"a process ended during start-up; logs in {work}")
        start = time.monotonic()
        next_sample = start
        while (now := time.monotonic()) < start + 60.0 * minutes:
            rclpy.spin_once(node, timeout_sec=0.1)
            if graph.poll() is not None:
                raise RuntimeError(f"fusion_node ended with {graph.returncode}; log {work / 'fusion_node.log'}")
            if now >= next_sample:
                next_sample += SAMPLE_S
                soak.samples.append(_sample(now - start, usage, statuses))
                s = soak.samples[-1]
                progress(f"{s.t_s / 60:5.1f} / {minutes:g} min: fusion_node {s.rss_mb['fusion_node']:.0f} MB, "
                         f"latency p50 {s.p50_ms} p99 {s.p99_ms} ms, {s.received} clouds received, "
                         f"{s.accounted} accounted, {s.waiting} waiting")
        stop_processes([player])
        end = time.monotonic() + 3.0  # the last frames through the graph, its next diagnostics
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
        soak.samples.append(_sample(time.monotonic() - start, usage, statuses))
    finally:
        stop_processes([player, graph])
        node.destroy_node()
    soak.player = (work / "lip_bag_play.log").read_text().strip().splitlines()[-1]
    sent = re.search(re.escape(LIDAR_TOPIC) + r" (\d+)", soak.player)
    soak.sent = int(sent.group(1)) if sent else None
    return soak


def _sample(t_s: float, usage: dict[str, ProcUsage], statuses: dict) -> Sample:
    now = time.monotonic()
    for u in usage.values():
        u.sample(now)
    frames, _ = accounting(statuses)
    latency = statuses.get(LATENCY_STATUS)
    values = latency.values if latency is not None else {}
    waiting = sum(int(s.values.get(k, 0)) for s in statuses.values() for k in ("pending", "waiting stamps")
                  if s.name.endswith(": frames"))

    def ms(key: str) -> float | None:
        return float(values[key]) if key in values else None

    return Sample(t_s, {n: u.rss_kb[-1] / 1024 if u.rss_kb else float("nan") for n, u in usage.items()},
                  {n: u.cpu_s[-1] if u.cpu_s else float("nan") for n, u in usage.items()},
                  ms("graph_latency_ms_recent_p50"), ms("graph_latency_ms_recent_p99"),
                  inputs_received(statuses, [LIDAR_TOPIC])[LIDAR_TOPIC],
                  sum(v for k, v in frames.items() if k != "pending"), frames.get("pose", 0), waiting)


def _bins(soak: Soak, every_min: float) -> list[list[Sample]]:
    edges = np.arange(0.0, soak.minutes + 1e-9, every_min) * 60.0
    return [[s for s in soak.samples if a <= s.t_s < b] for a, b in zip(edges[:-1], edges[1:])]


def _median(values: list[float | None]) -> float:
    known = [v for v in values if v is not None]
    return float(np.median(known)) if known else float("nan")


def report(soak: Soak, every_min: float, warmup_min: float) -> dict[str, float]:
    """Print the table and the growth figures; return the figures."""
    print(f"{'minutes':>9} {'RSS MB':>8} {'p50 ms':>7} {'p99 ms':>7} {'CPU %':>6} {'clouds':>8} {'posed':>7} "
          f"{'waiting':>8}")
    prev = None
    for b in _bins(soak, every_min):
        if not b:
            continue
        last = b[-1]
        cpu = (100 * (last.cpu_s["fusion_node"] - prev.cpu_s["fusion_node"]) / (last.t_s - prev.t_s)
               if prev else float("nan"))
        print(f"{b[0].t_s / 60:4.0f}-{last.t_s / 60:<4.0f} {last.rss_mb['fusion_node']:8.0f} "
              f"{_median([s.p50_ms for s in b]):7.1f} {_median([s.p99_ms for s in b]):7.1f} {cpu:6.0f} "
              f"{last.received:8d} {last.posed:7d} {max(s.waiting for s in b):8d}")
        prev = last
    steady = [s for s in soak.samples if s.t_s >= 60.0 * warmup_min]
    first = [s for s in steady if s.t_s < 60.0 * (warmup_min + every_min)]
    end = [s for s in steady if s.t_s >= 60.0 * (soak.minutes - every_min)]
    figures = {"rss_growth_pct": 100 * (_median([s.rss_mb["fusion_node"] for s in end])
                                        / _median([s.rss_mb["fusion_node"] for s in first]) - 1)
               if first and end else float("nan"),
               "p50_growth_pct": 100 * (_median([s.p50_ms for s in end]) / _median([s.p50_ms for s in first]) - 1)
               if first and end else float("nan"),
               "p99_growth_pct": 100 * (_median([s.p99_ms for s in end]) / _median([s.p99_ms for s in first]) - 1)
               if first and end else float("nan"),
               "max_waiting": max((s.waiting for s in soak.samples), default=0)}
    last = soak.samples[-1]
    print(f"after the {warmup_min:g} min warm-up, last {every_min:g} min against the first: fusion_node RSS "
          f"{figures['rss_growth_pct']:+.1f} %, latency p50 {figures['p50_growth_pct']:+.1f} %, p99 "
          f"{figures['p99_growth_pct']:+.1f} % (target: under 5 %)")
    print(f"clouds: the player sent {soak.sent}, the graph received {last.received} and accounted for "
          f"{last.accounted} ({last.posed} posed); at most {figures['max_waiting']} frames waited in the graph")
    print(f"player: {soak.player}")
    return figures


def plot(soak: Soak, png: Path) -> None:
    """RSS, recent latency and CPU of the graph over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array([s.t_s for s in soak.samples]) / 60.0
    fig, (mem, lat, cpu) = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    for name in soak.samples[0].rss_mb:
        mem.plot(t, [s.rss_mb[name] for s in soak.samples], label=name)
    mem.set(ylabel="RSS (MB)", title=f"LIP graph, {soak.columns}-column clouds at 10 Hz, {soak.minutes:g} min")
    mem.legend(fontsize=8)
    for key, label in (("p50_ms", "p50"), ("p99_ms", "p99")):
        lat.plot(t, [getattr(s, key) if getattr(s, key) is not None else np.nan for s in soak.samples], label=label)
    lat.set(ylabel="cloud received -> pose\npublished (ms, recent)")
    lat.legend(fontsize=8)
    for name in soak.samples[0].cpu_s:
        c = np.array([s.cpu_s[name] for s in soak.samples])
        cpu.plot(t[1:], 100 * np.diff(c) / np.diff(t * 60.0), label=name)
    cpu.set(xlabel="minutes", ylabel="CPU (% of one core)")
    cpu.legend(fontsize=8)
    save_png(fig, png)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--minutes", type=float, default=60.0, help="how long to play (after the first pose)")
    p.add_argument("--columns", type=int, choices=(1024, 2048), default=2048)
    p.add_argument("--bag-dir", type=Path, help="keep (and reuse) the rig capture here")
    p.add_argument("--every", type=float, default=5.0, help="minutes per row of the table")
    p.add_argument("--warmup", type=float, default=5.0, help="minutes left out of the growth figures")
    p.add_argument("--plot", type=Path, help="write a PNG of memory, latency and CPU over time here")
    p.add_argument("--json", type=Path, help="write the samples and figures here")
    args = p.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 100)))
    use_lip_dds_profile()
    rclpy.init()
    try:
        with tempfile.TemporaryDirectory(prefix="soak_lip_") as tmp:
            bag_dir = args.bag_dir or Path(tmp)
            bag_dir.mkdir(parents=True, exist_ok=True)
            soak = run(rig_bag(args.columns, bag_dir, BAG_SECONDS), args.minutes, args.columns, Path(tmp))
    finally:
        rclpy.try_shutdown()
    figures = report(soak, args.every, args.warmup)
    if args.plot:
        plot(soak, args.plot)
        print(f"plot: {args.plot}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"figures": figures, **asdict(soak)}, indent=1, default=float))
        print(f"json: {args.json}")


if __name__ == "__main__":
    main()
