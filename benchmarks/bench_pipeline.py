"""Speed of the LIP pipeline on full OS1-128 frames: per frame (live) and over a whole bag (batch).

Per frame: from one Ouster frame (the decoded (128, W) ``original`` array)
plus the IMU samples received so far to joints and translation, i.e.
``LipPipeline.add_cloud`` and the ``poll`` right after it, for the frames after
the calibration; median and p99 (targets 20 / 40 ms), with the median of each
stage (``FrameResult.timing``) and the PointCloud2 decoding
(``cloud_to_array``) beside it. Batch: ``lip_ros.lip.batch.process_bag_batch`` (the fast
path: read-ahead thread, CDR decoding without message objects, batched
network) over the same bag, reading and decompressing included, as a multiple
of real time (target 20x), beside ``replay_bag`` (the streaming reference) and
the CPU time behind it: the caller's thread (pipeline stages, decoding, IMU
buffering) and the read-ahead thread (reading and decompressing the bag,
also timed alone). Medians of ``--repeat`` runs, fast and streaming
alternating. The bag is a held-out 1024-column rig capture recorded to a
temporary directory (``--bag`` takes an existing one, e.g. ``bags/demo_walk``).
Weights: ``--weights``, else the shipped ones, else an untrained network of the
default size (speed does not depend on the values). Run:
``python benchmarks/bench_pipeline.py``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lip_msgs_py import MalformedMessageError, cloud_to_array, msg_to_imu, read_header
from lip_ros.bagio import bag_span, read_messages
from lip_ros.bagstream import stream_raw
from lip_ros.lip.batch import POSE_BATCH, process_bag_batch, replay_bag
from lip_ros.lip.nets.config import LipConfig
from lip_ros.lip.nets.lip_model import SHIPPED_WEIGHTS, LipModel
from lip_ros.lip.nets.models import LipNet
from lip_ros.lip.pipeline import FrameResult, LipPipeline, Outcome, StageTimes
from lip_ros.lip.sensors import IMU_TOPICS, LIDAR_TOPIC
from lip_ros.lip.train.rigdata import EVAL_SEED_MIN
from lip_ros.resources import params_dir
from lip_ros.rig.bag import write_capture_bag
from lip_ros.rig.capture import CaptureConfig, CaptureSession


def _model(weights: Path | None) -> tuple[LipModel, str]:
    path = weights or params_dir() / "weights" / SHIPPED_WEIGHTS
    if path.with_suffix(".pt").is_file():
        return LipModel.load(path), str(path)
    return LipModel(LipNet(LipConfig())), "untrained LipNet (default config; no weights found)"


def _per_frame(model: LipModel, bag: Path) -> tuple[np.ndarray, np.ndarray, list[StageTimes], int]:
    """Per post-calibration frame: add_cloud + poll time (s), decode time (s), stage times; frames that came
    out of a later poll (not timed)."""
    pipeline = LipPipeline(model)
    imu_of_topic = {t: n for n, t in IMU_TOPICS.items()}
    total, decode, stages, late = [], [], [], 0
    for m in read_messages(bag, [LIDAR_TOPIC, *imu_of_topic]):
        if m.topic != LIDAR_TOPIC:
            try:
                pipeline.add_imu(imu_of_topic[m.topic], msg_to_imu(m.msg))
            except MalformedMessageError:
                pass
            pipeline.poll()
            continue
        t0 = time.perf_counter()
        points = cloud_to_array(m.msg)
        t1 = time.perf_counter()
        calibrated = pipeline.calibrated
        stamp = read_header(m.msg)[0]
        results = pipeline.add_cloud(points, stamp) + pipeline.poll()
        t2 = time.perf_counter()
        mine = [r for r in results if r.frame_stamp_ns == stamp]
        if calibrated and mine and mine[0].outcome == Outcome.POSE:
            total.append(t2 - t1)
            decode.append(t1 - t0)
            stages.append(mine[0].timing)
        elif calibrated and not mine:
            late += 1
    return np.array(total), np.array(decode), stages, late


@dataclass(frozen=True)
class _BatchRun:
    wall: float  # seconds
    cpu: float  # CPU seconds of the process (all threads)
    main_cpu: float  # CPU seconds of the calling thread
    results: list[FrameResult]


def _batch(model: LipModel, bag: Path, fast: bool) -> _BatchRun:
    """The whole bag through process_bag_batch (``fast``) or replay_bag."""
    pipeline = LipPipeline(model, pose_batch=POSE_BATCH if fast else 1)
    wall, cpu, main_cpu = time.perf_counter(), time.process_time(), time.thread_time()
    results = list((process_bag_batch if fast else replay_bag)(pipeline, bag))
    return _BatchRun(time.perf_counter() - wall, time.process_time() - cpu, time.thread_time() - main_cpu, results)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--weights", type=Path, help="<path> of <path>.pt/.json")
    p.add_argument("--bag", type=Path, help="an existing rig bag (default: record a 20 s capture)")
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--repeat", type=int, default=3, help="batch runs of each kind")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    model, weights = _model(args.weights)
    print(f"weights: {weights}; torch threads {args.threads}; load average at start "
          f"{' '.join(f'{v:.2f}' for v in os.getloadavg())} ({os.cpu_count()} CPUs)")
    with tempfile.TemporaryDirectory() as tmp:
        bag = args.bag
        if bag is None:
            bag = Path(tmp) / "bench"
            config = CaptureConfig(scenario="walk", seconds=20.0, seed=EVAL_SEED_MIN + 900, distance_m=10.0,
                                   columns=1024)
            write_capture_bag(CaptureSession(config), bag, progress=False)
        total, decode, stages, late = _per_frame(model, bag)
        ms = 1e3 * total
        print(f"per frame (add_cloud + poll, {len(ms)} frames after calibration): "
              f"median {np.median(ms):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms, max {ms.max():.1f} ms "
              f"(targets 20 / 40 ms); {late} frames came out of a later poll")
        for name in StageTimes.__dataclass_fields__:
            print(f"  {name:17s} median {1e3 * np.median([getattr(s, name) for s in stages]):6.2f} ms")
        print(f"  (decoding the PointCloud2 before it: median {1e3 * np.median(decode):.2f} ms)")

        start, end = bag_span(bag)
        seconds = (end - start) * 1e-9
        runs: dict[bool, list[_BatchRun]] = {True: [], False: []}
        for _ in range(args.repeat):
            for fast in (True, False):
                runs[fast].append(_batch(model, bag, fast))
        fast, streaming = (sorted(runs[k], key=lambda r: r.wall)[len(runs[k]) // 2] for k in (True, False))
        t0 = time.perf_counter()
        for _ in stream_raw(bag, [LIDAR_TOPIC, *IMU_TOPICS.values()]):
            pass
        reading = time.perf_counter() - t0
        stage_s = {k: sum(getattr(r.timing, k) for r in fast.results) for k in StageTimes.__dataclass_fields__}
        stages = sum(stage_s.values())
        print(f"batch over the bag ({seconds:.1f} s, {len(fast.results)} frames; medians of {args.repeat} runs): "
              f"process_bag_batch {fast.wall:.2f} s = {seconds / fast.wall:.1f}x real time (target 20x); "
              f"replay_bag (streaming) {streaming.wall:.2f} s = {seconds / streaming.wall:.1f}x; "
              f"fast / streaming {streaming.wall / fast.wall:.1f}x")
        print(f"  its CPU: {fast.cpu:.2f} s in {fast.wall:.2f} s ({fast.cpu / fast.wall:.2f} cores busy); "
              f"calling thread {fast.main_cpu:.2f} s, read-ahead thread {fast.cpu - fast.main_cpu:.2f} s")
        print(f"  calling thread: pipeline stages {stages:.2f} s ("
              + ", ".join(f"{k} {v:.2f}" for k, v in stage_s.items())
              + f"), the rest (decoding, IMU buffering, polling, waiting for the read-ahead) "
                f"{fast.wall - stages:.2f} s")
        print(f"  read-ahead alone (stream_raw: reading and decompressing the bag): {reading:.2f} s = "
              f"{seconds / reading:.1f}x real time")
    print(f"load average at end {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
