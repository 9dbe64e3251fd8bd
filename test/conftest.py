"""Test-wide settings: DDS stays on loopback, in a domain of this run's own."""

from __future__ import annotations

import os
import random
import signal
import time
from pathlib import Path

import pytest
from helpers import alive, descendants

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 100)))


@pytest.fixture(scope="module")
def one_torch_thread():
    """Small networks run fastest on one thread; on a busy 2-core machine more threads are much slower."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture()
def ros_node():
    """An rclpy node of the test process (its own context for the test), to publish, subscribe and call."""
    import rclpy

    rclpy.init()
    node = rclpy.create_node("lip_ros_test_driver")
    yield node
    node.destroy_node()
    rclpy.shutdown()


_ORPHAN_GRACE_S = 20.0  # a parent's children get SIGTERM when it dies (lip_ros.children): time to stop cleanly


def _started(pid: int) -> int:
    """When process ``pid`` started (clock ticks since boot)."""
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19])


def _orphans() -> list[int]:
    """The processes of this run's ROS domain (by their environment) started after this one (a clock tick later,
    not to take the ``timeout`` or shell that started it) that no longer descend from it: left running by a test,
    their parent gone."""
    ours, me = f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}".encode(), os.getpid()
    mine, since = set(descendants(me)), _started(me)
    found = []
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            pid = int(proc.name)
            if (pid != me and pid not in mine and _started(pid) > since
                    and ours in (proc / "environ").read_bytes().split(b"\0") and alive(pid)):
                found.append(pid)
        except (OSError, ValueError):
            continue
    return found


@pytest.fixture(autouse=True)
def no_process_left_behind(request: pytest.FixtureRequest):
    """After each ``ros`` test: every process it started in the domain has ended or is still its own (a fixture's);
    one left running with its parent gone is killed (it would publish into the next tests) and fails the test."""
    yield
    if request.node.get_closest_marker("ros") is None or not Path("/proc/self/task").is_dir():
        return
    deadline = time.monotonic() + _ORPHAN_GRACE_S
    while (left := _orphans()) and time.monotonic() < deadline:
        time.sleep(0.2)
    lines = []
    for pid in left:
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
            os.kill(pid, signal.SIGKILL)
            lines.append(f"{pid}: {cmdline}")
        except OSError:
            continue
    assert not lines, ("processes left running by this test (or, still stopping then, the one before), their parent "
                       "gone (killed now):\n" + "\n".join(lines))


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Free the Fast DDS shared memory of the processes the tests killed (on purpose: a crash) and no one holds."""
    from lip_ros.middleware import remove_stale_shm

    remove_stale_shm(min_age_s=0.0)
