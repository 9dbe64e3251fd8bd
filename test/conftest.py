"""Test-wide settings: DDS stays on loopback, in a domain of this run's own."""

from __future__ import annotations

import os
import random

import pytest

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


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Free the Fast DDS shared memory of the processes the tests killed (on purpose: a crash) and no one holds."""
    from lip_ros.middleware import remove_stale_shm

    remove_stale_shm(min_age_s=0.0)
