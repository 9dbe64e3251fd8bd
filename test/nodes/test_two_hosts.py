"""The LIP graph split over two hosts: two network namespaces on this machine joined by a veth pair, DDS discovery by
unicast peers only (``ROS_STATIC_PEERS``; no multicast), as docs/deployment.md describes for two computers.

Host A, beside the sensors: the player (the Ouster and the DOTs), ``segmentation_node`` and ``calibration_node``.
Host B: ``pose_node`` (the network and the outputs) and the recorder. Only the performer's points, the calibrated
bones, /clock and /diagnostics cross between them. The outputs must be those of the one-process graph: every frame
accounted for, and the poses those of the batch core (as ``test_fusion_replay`` requires of the one-process run).

Needs root (or CAP_SYS_ADMIN and CAP_NET_ADMIN) to create the namespaces; where it cannot, the test is skipped
with the reason.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from helpers import DEMO_BAG, assert_poses_match_the_batch_core, console_script

from lip_ros.bagio import bag_topics, read_raw
from lip_ros.lip.sensors import INPUT_TOPICS, LIDAR_TOPIC, LIP_TOPICS
from lip_ros.tools.process_bag import LIP, summarize_outputs

pytestmark = pytest.mark.ros  # DDS traffic and subprocesses

SUBNET = "10.213.0"  # the two hosts' addresses: SUBNET.1 (A) and SUBNET.2 (B), /24, only inside the namespaces


@dataclass(frozen=True)
class Host:
    """One end of the pair: its namespace, veth interface and address."""

    netns: str
    veth: str
    address: str

    def run(self, cmd: list[str], peer: Host, log: Path) -> subprocess.Popen:
        """Start ``cmd`` in this namespace, discovering ``peer`` by unicast; output to ``log``."""
        env = {**os.environ, "ROS_STATIC_PEERS": peer.address}
        with open(log, "w") as f:
            return subprocess.Popen(["ip", "netns", "exec", self.netns, *cmd], env=env, stdout=f,
                                    stderr=subprocess.STDOUT)

    def sent_bytes(self) -> int:
        """Bytes this host has sent over the veth."""
        out = subprocess.run(["ip", "netns", "exec", self.netns, "cat", f"/sys/class/net/{self.veth}/statistics/"
                              "tx_bytes"], capture_output=True, text=True, check=True).stdout
        return int(out)


def _ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True)


@pytest.fixture()
def hosts() -> Iterator[tuple[Host, Host]]:
    """Two namespaces of this test run, joined by a veth pair (MTU 1500, as a plain Ethernet link), loopback up."""
    if shutil.which("ip") is None:
        pytest.skip("two hosts: the ip command (iproute2) is not installed here")
    tag = f"lip{os.getpid() % 100000}"
    a, b = Host(f"{tag}a", f"{tag}a", f"{SUBNET}.1"), Host(f"{tag}b", f"{tag}b", f"{SUBNET}.2")
    made = _ip("netns", "add", a.netns)
    if made.returncode != 0:
        pytest.skip(f"two hosts: this machine does not let the tests create network namespaces "
                    f"(ip netns add: {made.stderr.strip()})")
    try:
        steps = [("netns", "add", b.netns), ("link", "add", a.veth, "type", "veth", "peer", "name", b.veth)]
        for h in (a, b):
            steps += [("link", "set", h.veth, "netns", h.netns), ("-n", h.netns, "addr", "add", f"{h.address}/24",
                                                                   "dev", h.veth),
                      ("-n", h.netns, "link", "set", "lo", "up"), ("-n", h.netns, "link", "set", h.veth, "up")]
        for step in steps:
            done = _ip(*step)
            assert done.returncode == 0, f"ip {' '.join(step)}: {done.stderr}"
        yield a, b
    finally:
        for h in (a, b):
            _ip("netns", "del", h.netns)  # takes its end of the veth pair with it


def _stop(procs: list[subprocess.Popen]) -> list[int]:
    """SIGINT each (last started first), as a user's Ctrl-C; their exit statuses (killed after 30 s: -9)."""
    codes = []
    for proc in reversed(procs):
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            codes.append(proc.wait(timeout=30))
        except subprocess.TimeoutExpired:
            proc.kill()
            codes.append(proc.wait())
    return codes


def test_the_graph_split_over_two_hosts_gives_the_one_process_outputs(hosts: tuple[Host, Host],
                                                                      tmp_path: Path) -> None:
    a, b = hosts
    out = tmp_path / "outputs"
    node_args = ["--ros-args", "-p", "use_sim_time:=true", *LIP.node_args]  # paced as lip_process_bag paces LIP
    procs = []
    try:
        # host B first: its participants are there when A's announce themselves
        procs.append(b.run([console_script("lip_bag_record"), str(out), "--topics", *LIP.outputs,
                            "--ros-args", "-p", "use_sim_time:=true"], a, tmp_path / "record.log"))
        procs.append(b.run([console_script("pose_node"), *node_args], a, tmp_path / "pose.log"))
        procs.append(a.run([console_script("segmentation_node"), *node_args], b, tmp_path / "segmentation.log"))
        procs.append(a.run([console_script("calibration_node"), *node_args, "-p",
                            f"calibration_file:={tmp_path / 'calibration.yaml'}"], b, tmp_path / "calibration.log"))
        sent_before = a.sent_bytes()
        player = a.run([console_script("lip_bag_play"), str(DEMO_BAG), "--clock", "--wait-for-subscribers",
                        "--paced-by", LIP_TOPICS.root_pose, *LIP.pacing_args, "--topics", *INPUT_TOPICS], b,
                       tmp_path / "play.log")
        procs.append(player)  # stopped with the others if it does not end by itself
        assert player.wait(timeout=120) == 0, (tmp_path / "play.log").read_text()[-2000:]
        time.sleep(3.0)  # the last frames through B and their diagnostics recorded
        crossed = a.sent_bytes() - sent_before
    finally:
        codes = _stop(procs)
    logs = {p.name: p.read_text() for p in tmp_path.glob("*.log")}
    assert codes == [0] * len(procs), (codes, {k: v[-1500:] for k, v in logs.items()})
    assert not any("Traceback" in v for v in logs.values()), logs

    # what crossed: the performer's points, the bones, /clock and /diagnostics, not the clouds
    clouds = sum(len(m.data) for m in read_raw(DEMO_BAG, [LIDAR_TOPIC]))
    assert 100_000 < crossed < 0.1 * clouds, (crossed, clouds)

    summary = summarize_outputs(DEMO_BAG, out)
    assert summary.received == summary.frames_in == bag_topics(DEMO_BAG)[LIDAR_TOPIC].count
    pending = summary.frames.get("pending", 0)
    assert pending <= 1  # the last frame may wait for DOT data the bag does not have
    assert sum(summary.frames.values()) == summary.frames_in, summary.frames
    assert summary.frames["pose"] == bag_topics(out)[LIP_TOPICS.root_pose].count > summary.frames_in / 2
    assert_poses_match_the_batch_core(out)
