"""What the package's ROS command-line tools share: one-line errors, ROS start-up, stop signals, progress lines."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

import rclpy
from rclpy.signals import SignalHandlerOptions

from lip_ros.middleware import keep_message_buffers, use_lip_dds_profile
from lip_ros.signals import stop_on_signals

__all__ = ["ToolError", "ArgumentParser", "tool_args", "start_ros", "stop_on_signals", "run_tool", "Progress",
           "installed_script"]


class ToolError(Exception):
    """A problem the tool reports in one line (no traceback) before exiting with status 2."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error message (status 2) instead of the usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def tool_args(argv: list[str]) -> list[str]:
    """The tool's own arguments: ``argv`` without the program name and ROS arguments (``--ros-args ...``)."""
    return rclpy.utilities.remove_ros_args(argv)[1:]


def installed_script(name: str) -> str:
    """Path of the console script ``name`` installed beside the running Python (the package's other tools)."""
    exe = Path(sys.executable).parent / name
    if not exe.is_file():
        raise ToolError(f"{name} is not installed beside {sys.executable}")
    return str(exe)


def start_ros(argv: list[str]) -> None:
    """``rclpy.init`` with the package's DDS profile and message buffers kept (:mod:`lip_ros.middleware`), leaving
    SIGINT and SIGTERM to :func:`stop_on_signals`."""
    keep_message_buffers()
    use_lip_dds_profile()
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)


def run_tool(prog: str, body: Callable[[list[str]], int], argv: list[str]) -> int:
    """Run ``body(argv)``; a ToolError becomes ``<prog>: error: <message>`` on stderr and status 2."""
    try:
        return body(argv)
    except ToolError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    finally:
        rclpy.try_shutdown()


class Progress:
    """A status line on stderr at most once per ``period_s`` (redrawn in place on a terminal)."""

    def __init__(self, prog: str, period_s: float = 1.0) -> None:
        self.prog, self.period_s = prog, period_s
        self._next = 0.0
        self._tty = sys.stderr.isatty()

    def __call__(self, text: str) -> None:
        """Show ``text`` if the period has passed since the last line."""
        now = time.monotonic()
        if now >= self._next:
            self._next = now + self.period_s
            print(f"\r{self.prog}: {text}\033[K" if self._tty else f"{self.prog}: {text}",
                  end="" if self._tty else "\n", file=sys.stderr, flush=True)

    def done(self) -> None:
        """End the in-place line."""
        if self._tty:
            print(file=sys.stderr)
