"""The live HSC4D graph on rig captures: latency, real-time factor, accuracy, CPU and memory, at 10 and 20 Hz.

For each ``--rates`` (LiDAR Hz), an HSC4D rig capture (``lip_rig site-bag``,
OS1-64 x 1024, ``--seconds`` long, ``--seed``; made once into ``--bag-dir`` and
reused) goes through ``lip_process_bag`` (player, ``fusion_node -p
branch:=hsc4d`` with its body-node child, recorder: separate processes over
DDS, in real time). Printed per rate: its summary (frames accounted for, cloud
received -> ``/hsc4d/odometry`` published p50/p90/p99/max as the trajectory node
reports it, the wall time as a multiple of real time, ATE and MPJPE against the
rig's truth) and, sampled from /proc every 0.2 s while it runs, the CPU (% of
one core) and RSS (start of playback, end, peak) of the trajectory node's
process and of the body node's, and with ``--plot PNG`` their RSS over time
(a long ``--seconds`` shows whether memory stays flat).

A loaded machine: ``--busy N`` runs N busy loops beside the graph, ``--body-nice
N`` gives the body node's threads that niceness (a body node starved of CPU:
its optimisation windows take many seconds), ``--paced`` plays as the node tests
do (``lip_process_bag --paced``: no faster than the trajectory node poses).
Printed then too: the body node's time per optimisation window (its
/diagnostics) and the poses it lost.

DDS stays on loopback in a random ``ROS_DOMAIN_ID`` unless set. Progress on
stderr, a table on stdout.

Run:
  python benchmarks/bench_hsc4d_graph.py [--rates 10 20] [--seconds 30] [--seed 3] [--bag-dir out/bench_hsc4d]
      [--json out/bench_hsc4d_graph.json] [--plot out/bench_hsc4d_rss.png]
  a starved body node: --rates 10 --seconds 20 --seed 5 --paced --busy 4 --body-nice 5
  the 10-minute memory run: --rates 10 --seconds 600 --plot out/bench_hsc4d_rss_600s.png
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_graph import SAMPLE_S, ProcUsage, save_png  # noqa: E402

BIN = Path(sys.executable).parent
_FIGURES = {
    "frames": r"frames in: (\d+); pose (\d+)",
    "latency_ms": r"published\): p50 ([\d.]+) ms, p90 ([\d.]+) ms, p99 ([\d.]+) ms, max ([\d.]+) ms",
    "real_time_x": r", ([\d.]+)x real time",
    "ate_cm": r"pelvis ATE ([\d.]+) cm",
    "mpjpe_mm": r"MPJPE ([\d.]+) mm",
}


def progress(text: str) -> None:
    """A progress line on stderr."""
    print(f"bench_hsc4d_graph: {text}", file=sys.stderr, flush=True)


def capture(bag_dir: Path, seed: int, seconds: float, rate: int) -> Path:
    """The rig capture for one LiDAR rate (made on first use)."""
    bag = bag_dir / f"site_{seed}_{int(seconds)}s_{rate}hz"
    if not (bag / "metadata.yaml").is_file():
        progress(f"making {bag} (about {seconds * rate * 0.18:.0f} s)")
        subprocess.run([BIN / "lip_rig", "site-bag", "--seed", str(seed), "--seconds", str(seconds), "--rate",
                        str(float(rate)), "--out", str(bag), "--quiet"], check=True)
    return bag


def _graph_pids() -> dict[str, int]:
    """The trajectory node's process (fusion_node -p branch:=hsc4d) and the body node's (its child)."""
    out = {}
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            cmd = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if "fusion_node" in cmd and "branch:=hsc4d" in cmd and "lip_ros.nodes.hsc4d.body" not in cmd:
            out["trajectory (fusion_node)"] = int(proc.name)
        elif "lip_ros.nodes.hsc4d.body" in cmd:
            out["body (child)"] = int(proc.name)
    return out


def _renice(pid: int, nice: int) -> None:
    """Give every thread of process ``pid`` the niceness ``nice`` (Linux's is per thread)."""
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, int(task.name), nice)


def _optimisation_ms(out: Path) -> dict[str, str]:
    """The body node's last ``optimisation_ms_*`` values on /diagnostics in the outputs bag ``out``."""
    from lip_msgs_py import msg_to_diagnostics
    from lip_ros.bagio import read_messages

    values: dict[str, str] = {}
    for m in read_messages(out, ["/diagnostics"]):
        for status in msg_to_diagnostics(m.msg).statuses:
            if status.name == "hsc4d_body_node: frames":
                values.update((k, v) for k, v in status.values.items() if k.startswith("optimisation_ms_"))
    return values


def run(bag: Path, out: Path, paced: bool = False, busy: int = 0, body_nice: int = 0) -> dict:
    """``lip_process_bag`` on ``bag`` (``paced``: ``--paced``), beside ``busy`` busy loops, the body node's threads
    at niceness ``body_nice``; its figures, the body node's time per optimisation window and the graph processes'
    CPU and memory."""
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    try:
        proc = subprocess.Popen([BIN / "lip_process_bag", str(bag), str(out), *(["--paced"] if paced else [])],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        usage: dict[str, ProcUsage] = {}
        start = time.monotonic()
        while proc.poll() is None:
            for name, pid in _graph_pids().items():
                usage.setdefault(name, ProcUsage(name, pid)).sample(time.monotonic())
                if body_nice and name == "body (child)":
                    _renice(pid, body_nice)
            time.sleep(SAMPLE_S)
    finally:
        for spinner in spinners:
            spinner.kill()
            spinner.wait()
    stdout = proc.stdout.read()
    if proc.returncode != 0:
        raise RuntimeError(f"lip_process_bag failed:\n{stdout}")
    figures: dict = {"summary": stdout.strip().splitlines()}
    for key, pattern in _FIGURES.items():
        m = re.search(pattern, stdout)
        figures[key] = [float(g) for g in m.groups()] if m else None
    figures["optimisation_ms"] = _optimisation_ms(out)
    for name, u in usage.items():
        s = u.summary(start, time.monotonic())
        minutes = np.arange(0.0, u.t[-1] - u.t[0], 60.0)  # RSS once a minute of the run
        at = np.searchsorted(np.array(u.t) - u.t[0], minutes)
        figures[name] = {"cpu_pct": round(s["cpu_pct"], 1), "rss_first_mb": round(u.rss_kb[0] / 1024, 1),
                         "rss_last_mb": round(u.rss_kb[-1] / 1024, 1), "peak_mb": round(s["hwm_mb"], 1),
                         "rss_per_minute_mb": [round(u.rss_kb[k] / 1024, 1) for k in at],
                         "rss_curve": ([round(x - u.t[0], 1) for x in u.t], [round(r / 1024, 1) for r in u.rss_kb])}
    return figures


def _plot(results: dict, png: Path) -> None:
    """RSS over time of the graph's processes, per rate."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    for rate, r in results.items():
        for name in ("trajectory (fusion_node)", "body (child)"):
            if name in r:
                t, rss = r[name]["rss_curve"]
                ax.plot(np.array(t) / 60.0, rss, label=f"{rate} Hz: {name}")
    ax.set(xlabel="time since playback started (min)", ylabel="RSS (MB)", title="HSC4D graph: resident memory")
    ax.set_ylim(bottom=0)
    ax.legend()
    save_png(fig, png, dpi=90)


def main() -> int:
    """Command line."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rates", type=int, nargs="+", default=[10, 20], choices=[10, 20])
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--seed", type=int, default=3)
    p.add_argument("--bag-dir", type=Path, default=Path("out/bench_hsc4d"))
    p.add_argument("--json", type=Path)
    p.add_argument("--plot", type=Path, help="PNG of the graph processes' RSS over time")
    p.add_argument("--paced", action="store_true", help="lip_process_bag --paced (as the node tests play)")
    p.add_argument("--busy", type=int, default=0, help="busy loops running beside the graph")
    p.add_argument("--body-nice", type=int, default=0, help="the body node's threads' niceness (0-19)")
    args = p.parse_args()
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 100)))
    args.bag_dir.mkdir(parents=True, exist_ok=True)
    results = {}
    for rate in args.rates:
        bag = capture(args.bag_dir, args.seed, args.seconds, rate)
        out = args.bag_dir / f"outputs_{rate}hz_{int(time.time())}"
        progress(f"{rate} Hz: lip_process_bag {bag.name} (real time, {args.seconds:.0f} s)")
        results[rate] = run(bag, out, args.paced, args.busy, args.body_nice)
    print(f"load average (1 min) at the end: {os.getloadavg()[0]:.1f}")
    for rate, r in results.items():
        print(f"--- {rate} Hz, {args.seconds:.0f} s, seed {args.seed}" + (", paced" if args.paced else "")
              + (f", {args.busy} busy loops beside" if args.busy else "")
              + (f", the body node at nice {args.body_nice}" if args.body_nice else ""))
        print("\n".join(f"  {line}" for line in r["summary"] if not line.startswith("plot")))
        ms = r["optimisation_ms"]
        if ms:
            print(f"  body node, time per optimisation window: p50 {ms.get('optimisation_ms_p50')} ms, max "
                  f"{ms.get('optimisation_ms_max')} ms")
        for name in ("trajectory (fusion_node)", "body (child)"):
            if name in r:
                u = r[name]
                print(f"  {name}: CPU {u['cpu_pct']:.0f} % of a core, RSS {u['rss_first_mb']:.0f} -> "
                      f"{u['rss_last_mb']:.0f} MB (peak {u['peak_mb']:.0f} MB); once a minute: "
                      + " ".join(f"{m:.0f}" for m in u["rss_per_minute_mb"]))
    if args.plot:
        _plot(results, args.plot)
        print(f"plot: {args.plot}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
