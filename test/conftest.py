"""Test-wide settings: DDS stays on loopback, in a domain of this run's own (each pytest-xdist worker's own); under
xdist, each module's tests on one worker, the slowest first."""

from __future__ import annotations

import os
import random
import signal
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from helpers import alive, descendants

if TYPE_CHECKING:
    from xdist.scheduler import LoadScopeScheduling

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 100)))
_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")  # "gw0", "gw1", ... under pytest-xdist (make test: -n 2)
if _WORKER:  # each worker in a domain of its own, the run's for the first
    os.environ["ROS_DOMAIN_ID"] = str((int(os.environ["ROS_DOMAIN_ID"]) - 1 + 37 * int(_WORKER[2:])) % 100 + 1)

#: the test modules that share the session's HSC4D run (``nodes/conftest.py``: ``hsc4d_run``), run on one worker
_SHARING_THE_HSC4D_RUN = ("test/nodes/test_hsc4d_faulty_captures.py", "test/nodes/test_hsc4d_replay.py")
#: the slowest groups of tests (measured, session 38), run first under xdist so that the last to finish is a short one
_SLOWEST_FIRST = ("hsc4d_run", "test/nodes/test_lip_faults.py", "test/lip/test_sensor_variants.py",
                  "test/hsc4d/test_trajectory.py", "test/lip/test_segmentation.py", "test/nodes/test_hsc4d_restart.py",
                  "test/nodes/test_graph_nodes.py", "test/lip/test_dot_latency.py", "test/nodes/test_fusion_replay.py")


def _group(nodeid: str) -> str:
    """The tests that run on one worker: a module's (its module fixtures made once), or those sharing the HSC4D run."""
    module = nodeid.split("::")[0]
    return "hsc4d_run" if module in _SHARING_THE_HSC4D_RUN else module


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> LoadScopeScheduling:
    """Under pytest-xdist (make test: ``-n 2``), whole groups (:func:`_group`) to each worker, in collection order."""
    from xdist.scheduler import LoadScopeScheduling

    class GroupScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _group(nodeid)

    config.option.loadscopereorder = False  # the order of pytest_collection_modifyitems, the slowest first
    return GroupScheduling(config, log)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The slowest groups first (:data:`_SLOWEST_FIRST`), the rest in their order."""
    rank = {group: k for k, group in enumerate(_SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(_group(item.nodeid), len(rank)))


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
    their parent gone. Under xdist, from the workers' parent (the workers' own environments hold the run's domain,
    the first worker's)."""
    ours, me = f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}".encode(), os.getpid()
    mine, since = set(descendants(os.getppid() if _WORKER else me)), _started(me)
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
    """Free the Fast DDS shared memory of the processes the tests killed (on purpose: a crash) and no one holds; under
    xdist, once every worker has finished."""
    if _WORKER:
        return
    from lip_ros.middleware import remove_stale_shm

    remove_stale_shm(min_age_s=0.0)
