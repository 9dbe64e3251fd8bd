"""How a graph's spinning threads tell a shutdown from a failure (rclpy in this process, no traffic)."""

from __future__ import annotations

import pytest
import rclpy
from rclpy._rclpy_pybind11 import RCLError

from lip_ros.nodes.base import _spin_each

pytestmark = pytest.mark.ros


def _spin_one_callback(callback) -> list[BaseException]:
    rclpy.init()
    node = rclpy.create_node("lip_ros_test_spin")
    node.create_timer(0.01, callback)
    try:
        return _spin_each([node])
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def test_a_signal_during_the_wait_set_is_a_clean_shutdown() -> None:
    """A SIGTERM that shuts the context down while spin_once builds its wait set raises RCLError inside
    rclpy (seen in CI as a traceback at the end of a run): the same as a shutdown, nothing to report."""
    def signal_then_wait_set() -> None:
        rclpy.try_shutdown()  # what rclpy's signal handler does
        raise RCLError("failed to initialize wait set: the given context is not valid")

    assert _spin_one_callback(signal_then_wait_set) == []


def test_a_failing_callback_is_reported_and_stops_the_graph() -> None:
    def fail() -> None:
        raise RuntimeError("a bug")

    errors = _spin_one_callback(fail)
    assert [str(e) for e in errors] == ["a bug"]
    assert not rclpy.ok()
