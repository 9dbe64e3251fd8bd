"""The whole HSC4D graph: what ``fusion_node -p branch:=hsc4d`` runs.

Runs ``hsc4d_trajectory_node`` in this process and ``hsc4d_body_node`` (both
also executables of their own) in a child process started with the same
arguments, parameters from the shipped ``params/hsc4d.yaml`` and
``--ros-args``. Two processes, not two threads of one as in the LIP graph: the
body node takes 17 suit topics at 100 Hz, and in one Python process its
callbacks and the odometry's registrations take turns on one interpreter lock,
which measured here starved the trajectory node of a third of its suit samples
and put its latency past a second (docs/hsc4d/graph.md). The child is stopped
with this process; if it ends on its own (e.g. a bad parameter), so does the
graph, with its exit status; if this process is killed, the child gets SIGTERM
(:func:`lip_ros.children.start_child`) and stops too. The body node also runs
the scene-aware optimisation, each window on a thread of its own.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading

import rclpy

from lip_ros.children import start_child
from lip_ros.nodes.base import run_nodes
from lip_ros.nodes.hsc4d.body import BodyNode
from lip_ros.nodes.hsc4d.trajectory import TrajectoryNode

__all__ = ["HSC4D_GRAPH", "run_hsc4d_graph"]

#: The nodes of the HSC4D graph, in the order of the data.
HSC4D_GRAPH = (TrajectoryNode, BodyNode)
_STOP_S = 10.0  # the child's time to stop after SIGINT before it is killed


def run_hsc4d_graph(prog: str, description: str, argv: list[str] | None = None) -> int:
    """Run the HSC4D graph until shutdown (the trajectory node here, the body node in a child process); the exit
    status (``prog``, ``description``: the command line's name and help)."""
    argv = list(sys.argv if argv is None else argv)
    if {"-h", "--help"} & set(rclpy.utilities.remove_ros_args(argv)[1:]):
        return run_nodes(prog, description, [TrajectoryNode], HSC4D_GRAPH, argv)
    body = start_child([sys.executable, "-m", BodyNode.__module__, *argv[1:]])

    def watch() -> None:  # the body node ended on its own: end the graph too
        body.wait()
        rclpy.try_shutdown()

    threading.Thread(target=watch, name="hsc4d_body_node watch", daemon=True).start()
    try:
        status = run_nodes(prog, description, [TrajectoryNode], HSC4D_GRAPH, argv)
    finally:
        if body.poll() is None:
            body.send_signal(signal.SIGINT)
            try:
                body.wait(timeout=_STOP_S)
            except subprocess.TimeoutExpired:
                body.kill()
                body.wait()
    return status or (body.returncode if body.returncode and body.returncode > 0 else 0)
