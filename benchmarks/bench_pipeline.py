"""Speed of the LIP pipeline on full OS1-128 x 1024 frames: per frame (live) and over a whole bag (batch).

Per frame: from one Ouster frame (the decoded (128, 1024) ``original``
array) plus the IMU samples received so far to joints and translation, i.e.
``LipPipeline.add_cloud`` and the ``poll`` right after it, for the frames after
the calibration; median and p99 (targets 20 / 40 ms), with the median of each
stage (``FrameResult.timing``) and the PointCloud2 decoding
(``cloud_to_array``) beside it. Batch: ``lip_ros.batch.replay_bag`` over the
same bag (reading and deserialising included), as a multiple of real time
(target 20x). The bag is a held-out rig capture recorded to a temporary
directory (``--bag`` takes an existing one). Weights: ``--weights``, else the
shipped ones, else an untrained network of the default size (speed does not
depend on the values). Run: ``python benchmarks/bench_pipeline.py``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from lip_msgs_py import MalformedMessageError, cloud_to_array, msg_to_imu, read_header
from lip_ros.bagio import bag_span, read_messages
from lip_ros.batch import DEFAULT_IMU_TOPICS, DEFAULT_LIDAR_TOPIC, replay_bag
from lip_ros.nets.config import LipConfig
from lip_ros.nets.lip_model import SHIPPED_WEIGHTS, LipModel
from lip_ros.nets.models import LipNet
from lip_ros.params import params_dir
from lip_ros.pipeline import LipPipeline, Outcome, StageTimes
from lip_ros.rig.bag import write_capture_bag
from lip_ros.rig.capture import CaptureConfig, CaptureSession
from lip_ros.train.rigdata import EVAL_SEED_MIN


def _model(weights: Path | None) -> tuple[LipModel, str]:
    path = weights or params_dir() / "weights" / SHIPPED_WEIGHTS
    if path.with_suffix(".pt").is_file():
        return LipModel.load(path), str(path)
    return LipModel(LipNet(LipConfig())), "untrained LipNet (default config; no weights found)"


def _per_frame(model: LipModel, bag: Path) -> tuple[np.ndarray, np.ndarray, list[StageTimes], int]:
    """Per post-calibration frame: add_cloud + poll time (s), decode time (s), stage times; frames that came
    out of a later poll (not timed)."""
    pipeline = LipPipeline(model)
    imu_of_topic = {t: n for n, t in DEFAULT_IMU_TOPICS.items()}
    total, decode, stages, late = [], [], [], 0
    for m in read_messages(bag, [DEFAULT_LIDAR_TOPIC, *imu_of_topic]):
        if m.topic != DEFAULT_LIDAR_TOPIC:
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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--weights", type=Path, help="<path> of <path>.pt/.json")
    p.add_argument("--bag", type=Path, help="an existing rig bag (default: record a 20 s capture)")
    p.add_argument("--threads", type=int, default=1, help="torch threads")
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
        print(f"per frame (add_cloud + poll, {len(ms)} frames after calibration, 128 x 1024): "
              f"median {np.median(ms):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms, max {ms.max():.1f} ms "
              f"(targets 20 / 40 ms); {late} frames came out of a later poll")
        for name in StageTimes.__dataclass_fields__:
            print(f"  {name:17s} median {1e3 * np.median([getattr(s, name) for s in stages]):6.2f} ms")
        print(f"  (decoding the PointCloud2 before it: median {1e3 * np.median(decode):.2f} ms)")

        start, end = bag_span(bag)
        t0 = time.perf_counter()
        results = list(replay_bag(LipPipeline(model), bag))
        wall = time.perf_counter() - t0
        t0 = time.perf_counter()
        for _ in read_messages(bag, [DEFAULT_LIDAR_TOPIC, *DEFAULT_IMU_TOPICS.values()]):
            pass
        reading = time.perf_counter() - t0
        seconds = (end - start) * 1e-9
        stages = sum(r.timing.total for r in results)
        print(f"batch: {len(results)} frames, {seconds:.1f} s of bag in {wall:.2f} s = {seconds / wall:.1f}x real "
              f"time (target 20x): reading and deserialising the bag {reading:.2f} s, pipeline stages "
              f"{stages:.2f} s, the rest (message conversion, IMU buffering, polling) {wall - reading - stages:.2f} s")
    print(f"load average at end {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
