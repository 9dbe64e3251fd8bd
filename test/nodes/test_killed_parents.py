"""Processes the package starts do not outlive a parent that is killed: they would go on publishing in the ROS
domain (their clock too) into whatever runs there next. Real processes, real signals, real DDS."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import rclpy
from helpers import DEMO_BAG, alive, console_script, descendants

pytestmark = [pytest.mark.ros, pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads /proc")]


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _wait_for(done, timeout_s: float, what: str, node=None) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        if node is None:
            time.sleep(0.1)
        else:
            rclpy.spin_once(node, timeout_sec=0.1)


def _kill_and_wait(parent: subprocess.Popen, children: list[int], timeout_s: float) -> list[str]:
    """SIGKILL ``parent`` alone; the command lines of ``children`` still running after ``timeout_s``."""
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + timeout_s
    while any(map(alive, children)) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [_cmdline(p) for p in children if alive(p)]
    for pid in children:  # not to leak them into the tests after this one
        if alive(pid):
            os.kill(pid, signal.SIGKILL)
    return left


def test_a_killed_hsc4d_graph_takes_its_body_node_along(ros_node, tmp_path: Path):
    """Killed once the body node is ready (its name is on the graph before its start-up is done, and a body node
    told to stop during its start-up ends only once that is done). It outlived the 15 s allowed here twice under a
    whole suite's load: in stop 50's CI its signal handler waited for ever on the stop event's lock, as a loop of
    this test under load showed (``test/test_signals.py``); session 42's was likely the same."""
    log = tmp_path / "graph.log"
    with log.open("w") as stderr:
        graph = subprocess.Popen([console_script("fusion_node"), "--ros-args", "-p", "branch:=hsc4d"],
                                 stdout=subprocess.DEVNULL, stderr=stderr)
    try:
        _wait_for(lambda: "hsc4d_body_node" in ros_node.get_node_names(), 60.0, "the body node", ros_node)
        _wait_for(lambda: "[hsc4d_body_node]: ready;" in log.read_text(), 120.0, "the body node's start-up")
        children = descendants(graph.pid)
        assert any("lip_ros.nodes.hsc4d.body" in _cmdline(p) for p in children), list(map(_cmdline, children))
        assert _kill_and_wait(graph, children, 15.0) == []
    finally:
        if graph.poll() is None:
            graph.kill()
            graph.wait()


def test_a_killed_lip_process_bag_takes_its_processes_along(tmp_path: Path):
    out = tmp_path / "outputs"
    tool = subprocess.Popen([console_script("lip_process_bag"), str(DEMO_BAG), str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        names = ("fusion_node", "lip_bag_record", "lip_bag_play")
        _wait_for(lambda: all(any(n in _cmdline(p) for p in descendants(tool.pid)) for n in names), 60.0,
                  "the node, the recorder and the player")
        time.sleep(3.0)  # the player under way
        children = descendants(tool.pid)
        assert _kill_and_wait(tool, children, 30.0) == []
        assert (out / "metadata.yaml").is_file()  # the recorder stopped cleanly: the bag was closed
    finally:
        if tool.poll() is None:
            tool.kill()
            tool.wait()
