"""Where a frame's time goes inside fusion_node (LIP): per frame, wall and thread CPU time between its stages.

Runs ``fusion_node`` (the LIP branch) with marks at the boundaries of a frame's
path on the thread it runs on (the segmentation node's cloud callback, which in
the composed graph carries the frame through the calibration and pose nodes by
direct calls): the cloud's callback entered, segmentation done, the calibration
node given the performer's points, the DOT samples taken, the frame's bones
interpolated, its pose estimated (network, surface fit, kinematics), its four
outputs built and published, and the DOT latency's scoring after them. At exit
it writes every posed frame's marks (``time.perf_counter`` and
``time.thread_time``, s) to ``--out`` as JSON; ``--report FILE`` prints the
medians and 90th percentiles of each interval, wall and CPU time (a wall time
well above its CPU time is a wait: for the GIL, a lock or a core).

The marks wrap the nodes' and stages' methods from outside (the graph's code is
not changed); they cost a few microseconds each. Run it as the graph of
``bench_graph.py``, which plays the capture and measures the rest:

  python benchmarks/bench_graph.py --columns 1024 --graph-cmd "python benchmarks/frame_timeline.py
      --out out/timeline.json --ros-args -p use_sim_time:=true -p diagnostics_period_s:=0.5
      -p calibration_file:={calibration_file}"
  python benchmarks/frame_timeline.py --report out/timeline.json
"""

from __future__ import annotations

import argparse
import atexit
import json
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

#: The marks in a frame's order: (name, class path, method, mark before the call or after it). Each is taken the
#: first time in a frame, on the thread of the frame's cloud callback (a frame that another thread completes, a
#: late DOT sample's, is left out).
MARKS = (
    ("cloud", "lip_ros.nodes.lip.segmentation:SegmentationNode", "_on_cloud", "before"),
    ("segmented", "lip_ros.lip.segmentation.segmenter:PerformerSegmenter", "process", "after"),
    ("to calibration", "lip_ros.nodes.lip.calibration:CalibrationNode", "_on_performer", "before"),
    ("DOT samples taken", "lip_ros.nodes.base:GraphNode", "take_polled", "after"),
    ("bones interpolated", "lip_ros.lip.stages:ImuStage", "_process", "after"),
    ("to pose", "lip_ros.nodes.lip.pose:PoseNode", "_estimate", "before"),
    ("pose estimated", "lip_ros.lip.stages:PoseStage", "estimate", "after"),
    ("outputs published", "lip_ros.nodes.lip.pose:PoseNode", "_estimate", "after"),
    ("callback done", "lip_ros.nodes.lip.segmentation:SegmentationNode", "_on_cloud", "after"),
)
#: Frames skipped at the start (the calibration's backlog, the first frames' warm-up).
SKIP_FRAMES = 20


def _instrument(out: Path) -> None:
    """Wrap the methods of MARKS; write the posed frames' marks to ``out`` at exit."""
    import importlib

    frames: list[dict[str, tuple[float, float]]] = []
    current: dict[str, tuple[float, float]] = {}
    frame_thread = [0]

    def mark(name: str) -> None:
        if threading.get_ident() == frame_thread[0] and name not in current:
            current[name] = (time.perf_counter(), time.thread_time())

    def wrapped(method: Callable[..., Any], name: str, when: str) -> Callable[..., Any]:
        def call(*args: Any, **kwargs: Any) -> Any:
            if name == "cloud":
                current.clear()
                frame_thread[0] = threading.get_ident()
            if when == "before":
                mark(name)
            try:
                return method(*args, **kwargs)
            finally:
                if when == "after":
                    mark(name)
                if name == "callback done" and "outputs published" in current:
                    frames.append(dict(current))
        return call

    for name, where, method, when in MARKS:
        module, cls = where.split(":")
        owner = getattr(importlib.import_module(module), cls)
        setattr(owner, method, wrapped(getattr(owner, method), name, when))
    atexit.register(lambda: out.write_text(json.dumps(frames[SKIP_FRAMES:]), encoding="utf-8"))


def report(path: Path) -> None:
    """Print each interval's wall and CPU time (median, p90) over the frames in ``path``."""
    frames = json.loads(path.read_text(encoding="utf-8"))
    names = [m[0] for m in MARKS]
    print(f"{len(frames)} posed frames (after the first {SKIP_FRAMES}); ms, median / p90")
    print(f"{'interval':46s} {'wall':>13s} {'CPU':>13s}")
    rows = list(zip(names[:-1], names[1:])) + [("cloud", "outputs published")]
    for a, b in rows:
        both = [f for f in frames if a in f and b in f]
        if not both:
            continue
        wall = [1e3 * (f[b][0] - f[a][0]) for f in both]
        cpu = [1e3 * (f[b][1] - f[a][1]) for f in both]
        print(f"{a + ' -> ' + b:46s} {np.median(wall):6.2f} / {np.percentile(wall, 90):5.2f} "
              f"{np.median(cpu):6.2f} / {np.percentile(cpu, 90):5.2f}")


def main() -> int:
    """``--report FILE``: print it; otherwise run fusion_node (ROS arguments after --ros-args) with the marks."""
    argv = sys.argv[1:]
    ros = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, help="write the frames' marks here (JSON) when fusion_node ends")
    p.add_argument("--report", type=Path, help="print the intervals of a file written with --out, and exit")
    args = p.parse_args(argv[:ros])
    if args.report:
        report(args.report)
        return 0
    if args.out is None:
        p.error("--out or --report is needed")
    _instrument(args.out)
    from lip_ros.nodes.fusion_node import main as fusion_main

    return fusion_main([sys.argv[0], *argv[ros:]])


if __name__ == "__main__":
    raise SystemExit(main())
