#!/usr/bin/env python3
"""Benchmark of 128 x 2048 Ouster clouds between two processes over DDS, with and without lip_ros's Fast DDS profile.

A publisher process sends ``original`` clouds (point_step 48, 12.6 MB) at 10 Hz
best effort (SensorDataQoS) for ``--seconds``; a subscriber process
(SensorDataQoS) counts arrivals and their latency (receive time minus
header.stamp, which the publisher sets just before publishing). Run once under
Fast DDS's defaults (``FASTRTPS_DEFAULT_PROFILES_FILE`` empty) and once with
``params/fastdds_lip.xml``; prints the delivery ratio and latency percentiles of
each. DDS stays on loopback (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) in a
random ``ROS_DOMAIN_ID`` unless one is set.

Usage: python benchmarks/bench_dds_clouds.py [--seconds 20] [--rate 10] [--columns 2048]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

TOPIC = "/bench/points"
DONE_TOPIC = "/bench/done"  # reliable, transient local: how many clouds were sent
RESULT = "RESULT"  # prefix of a child's report line (Fast DDS logs to stdout too)
DRAIN_S = 2.0  # the subscriber keeps listening this long after the publisher is done


def _subscriber(args: argparse.Namespace) -> None:
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import UInt32

    from lip_msgs_py import read_header
    from lip_ros.middleware import keep_message_buffers, use_lip_dds_profile

    keep_message_buffers()  # as the package's executables
    use_lip_dds_profile()
    rclpy.init()
    node = rclpy.create_node("bench_dds_clouds_sub")
    latencies_ms: list[float] = []
    sent: list[int] = []

    def on_cloud(msg: PointCloud2) -> None:
        latencies_ms.append((time.time_ns() - read_header(msg)[0]) * 1e-6)

    node.create_subscription(PointCloud2, TOPIC, on_cloud, qos_profile_sensor_data)
    done_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(UInt32, DONE_TOPIC, lambda m: sent.append(m.data), done_qos)
    deadline = time.monotonic() + args.seconds + 60.0
    while not sent and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    drain_end = time.monotonic() + DRAIN_S
    while time.monotonic() < drain_end:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(RESULT, json.dumps({"sent": sent[0] if sent else None, "latencies_ms": latencies_ms}))
    node.destroy_node()
    rclpy.shutdown()


def _publisher(args: argparse.Namespace) -> None:
    import rclpy
    from bench_msgs import ouster_scan
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import UInt32

    from lip_msgs_py import RclpyBackend, array_to_cloud, ns_to_sec_nanosec
    from lip_ros.middleware import keep_message_buffers, use_lip_dds_profile

    keep_message_buffers()  # as the package's executables
    use_lip_dds_profile()
    rclpy.init()
    node = rclpy.create_node("bench_dds_clouds_pub")
    pub = node.create_publisher(PointCloud2, TOPIC, qos_profile_sensor_data)
    done_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    done = node.create_publisher(UInt32, DONE_TOPIC, done_qos)
    cloud = array_to_cloud(RclpyBackend(), ouster_scan(args.columns, np.random.default_rng(0)), 0, "os_lidar")
    deadline = time.monotonic() + 60.0
    while pub.get_subscription_count() == 0:
        if time.monotonic() > deadline:
            raise SystemExit("bench_dds_clouds: no subscriber matched within 60 s")
        rclpy.spin_once(node, timeout_sec=0.1)
    time.sleep(1.0)  # let the subscriber's side of discovery finish too
    count = int(args.seconds * args.rate)
    publish_ms = []
    start = time.monotonic()
    for k in range(count):
        while (wait := start + k / args.rate - time.monotonic()) > 0:
            time.sleep(wait)
        cloud.header.stamp.sec, cloud.header.stamp.nanosec = ns_to_sec_nanosec(time.time_ns())
        t0 = time.perf_counter()
        pub.publish(cloud)
        publish_ms.append((time.perf_counter() - t0) * 1e3)
    done.publish(UInt32(data=count))
    end = time.monotonic() + DRAIN_S
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(RESULT, json.dumps({"bytes": len(cloud.data), "publish_ms": publish_ms}))
    node.destroy_node()
    rclpy.shutdown()


def _run_pair(args: argparse.Namespace, profile: str) -> dict:
    """Run a subscriber and a publisher process with ``FASTRTPS_DEFAULT_PROFILES_FILE=profile``; their reports."""
    from lip_ros.middleware import PROFILE_ENV

    env = dict(os.environ, **{PROFILE_ENV: profile})
    common = [sys.executable, __file__, "--seconds", str(args.seconds), "--rate", str(args.rate),
              "--columns", str(args.columns), "--role"]
    sub = subprocess.Popen([*common, "sub"], env=env, stdout=subprocess.PIPE, text=True)
    pub = subprocess.Popen([*common, "pub"], env=env, stdout=subprocess.PIPE, text=True)
    reports = [_report(p.communicate(timeout=args.seconds + 120)[0]) for p in (pub, sub)]
    return {**reports[0], **reports[1]}


def _report(stdout: str) -> dict:
    lines = [line for line in stdout.splitlines() if line.startswith(RESULT)]
    if not lines:
        raise SystemExit(f"bench_dds_clouds: a child process failed:\n{stdout}")
    return json.loads(lines[-1][len(RESULT):])


def _row(name: str, r: dict) -> str:
    lat = np.array(r["latencies_ms"])
    pct = np.percentile(lat, [50, 90, 99]) if len(lat) else [np.nan] * 3
    ratio = 100.0 * len(lat) / r["sent"]
    return (f"{name:<22} {r['sent']:>5} {len(lat):>8} {ratio:>7.1f} % {pct[0]:>8.1f} {pct[1]:>8.1f} {pct[2]:>8.1f}"
            f" {lat.max() if len(lat) else np.nan:>8.1f} {np.median(r['publish_ms']):>10.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="publishing time per run")
    parser.add_argument("--rate", type=float, default=10.0, help="clouds per second")
    parser.add_argument("--columns", type=int, default=2048, help="Ouster columns (128 rows)")
    parser.add_argument("--profile", type=Path, help="Fast DDS profile to compare (default: params/fastdds_lip.xml)")
    parser.add_argument("--role", choices=("pub", "sub"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == "sub":
        return _subscriber(args)
    if args.role == "pub":
        return _publisher(args)

    from lip_ros.middleware import PROFILE_FILE
    from lip_ros.resources import params_path

    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 100)))
    profile = args.profile or params_path(PROFILE_FILE)
    runs = {"Fast DDS defaults": "", profile.name: str(profile.resolve())}
    load_before = os.getloadavg()[0]
    results = {name: _run_pair(args, profile) for name, profile in runs.items()}
    size = next(iter(results.values()))["bytes"] / 1e6
    print(f"128x{args.columns} Ouster original clouds ({size:.1f} MB), {args.rate:g} Hz best effort for "
          f"{args.seconds:g} s, two processes, ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, "
          f"load {load_before:.1f} -> {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'profile':<22} {'sent':>5} {'received':>8} {'ratio':>9} {'p50 ms':>8} {'p90 ms':>8} {'p99 ms':>8}"
          f" {'max ms':>8} {'publish ms':>10}")
    for name, r in results.items():
        print(_row(name, r))


if __name__ == "__main__":
    main()
