#!/usr/bin/env python3
"""Benchmark of lip_msgs_py's PointCloud2 paths on Ouster ``original`` scans.

Prints median and p99 wall time of
- cloud -> (N, 3) float32 valid points (``cloud_to_xyz``) and with per-point ``t``
  (``cloud_to_xyz_time``), for rclpy and rosbags messages as a subscriber / bag
  reader gets them (deserialized from CDR);
- structured array -> PointCloud2 (``array_to_cloud``) for both backends.

Scans are 128 x 2048 and 128 x 1024 with about half the points no-return (NaN).
Usage: python benchmarks/bench_msgs.py [--repeat N]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from functools import partial

import numpy as np

from lip_msgs_py import (
    OUSTER_ORIGINAL_DTYPE,
    RclpyBackend,
    RosbagsBackend,
    array_to_cloud,
    cloud_to_xyz,
    cloud_to_xyz_time,
)

CLOUD = "sensor_msgs/msg/PointCloud2"


def ouster_scan(width: int, rng: np.random.Generator) -> np.ndarray:
    """A 128 x ``width`` scan: a ring of returns with about half the points no-return."""
    scan = np.zeros((128, width), OUSTER_ORIGINAL_DTYPE)
    theta = np.pi - 2 * np.pi * np.arange(width) / width
    phi = np.deg2rad(np.linspace(22.5, -22.5, 128))[:, None]
    r = rng.uniform(1.0, 30.0, scan.shape)
    scan["x"], scan["y"], scan["z"] = r * np.cos(phi) * np.cos(theta), r * np.cos(phi) * np.sin(theta), r * np.sin(phi)
    scan["t"] = np.arange(width) * (100_000_000 // width)
    scan["range"] = (r * 1000).astype(np.uint32)
    miss = rng.random(scan.shape) < 0.5
    for c in "xyz":
        scan[c][miss] = np.nan
    scan["range"][miss] = 0
    return scan


def timing(fn: Callable[[], object], repeat: int) -> tuple[float, float]:
    """(median, p99) milliseconds of ``fn()`` over ``repeat`` runs after a warm-up."""
    fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    ms = np.array(times) * 1e3
    return float(np.median(ms)), float(np.percentile(ms, 99))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=200, help="runs per measurement")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    backends = {"rclpy": RclpyBackend(), "rosbags": RosbagsBackend()}
    rows = []
    for width in (2048, 1024):
        scan = ouster_scan(width, rng)
        size = f"128x{width}"
        for name, backend in backends.items():
            msg = backend.deserialize(backend.serialize(array_to_cloud(backend, scan, 0, "os_lidar"), CLOUD), CLOUD)
            valid = len(cloud_to_xyz(msg))
            rows.append(("cloud_to_xyz", size, name, valid, *timing(partial(cloud_to_xyz, msg), args.repeat)))
            rows.append(("cloud_to_xyz_time", size, name, valid, *timing(partial(cloud_to_xyz_time, msg), args.repeat)))
        for name, backend in backends.items():
            build = partial(array_to_cloud, backend, scan, 0, "os_lidar")
            rows.append(("array_to_cloud", size, name, scan.size, *timing(build, args.repeat)))
    print(f"{'operation':<18} {'cloud':<9} {'backend':<8} {'points':>7} {'median ms':>10} {'p99 ms':>8}")
    for op, size, name, points, median, p99 in rows:
        print(f"{op:<18} {size:<9} {name:<8} {points:>7} {median:>10.3f} {p99:>8.3f}")


if __name__ == "__main__":
    main()
