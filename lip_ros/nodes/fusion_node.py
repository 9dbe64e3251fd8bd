"""fusion_node: the capture graph in one process, the LIP branch (default) or the HSC4D branch.

``ros2 run lip_ros fusion_node`` is the one command users run. It starts the
LIP graph (:mod:`lip_ros.nodes.lip.graph`: segmentation, calibration and pose
nodes in one process); ``ros2 run lip_ros fusion_node --ros-args -p
branch:=hsc4d`` starts the HSC4D graph instead (:mod:`lip_ros.nodes.hsc4d.graph`:
trajectory and body nodes). The other parameters are the chosen branch's
(``params/lip.yaml`` or ``params/hsc4d.yaml``).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

from lip_ros.nodes.hsc4d.graph import run_hsc4d_graph
from lip_ros.nodes.lip.graph import run_lip_graph

__all__ = ["BRANCHES", "branch_of", "main"]

#: The graphs fusion_node runs, by the value of its ``branch`` parameter (the first is the default).
BRANCHES: dict[str, Callable[[str, str, list[str] | None], int]] = {"lip": run_lip_graph, "hsc4d": run_hsc4d_graph}


def branch_of(argv: Sequence[str]) -> tuple[str, list[str]]:
    """The ``branch`` set by ``-p branch:=NAME`` (or ``--param``) among the ROS arguments (default: the first of
    :data:`BRANCHES`), and ``argv`` without it; ValueError for an unknown branch."""
    branch, out, ros, skip = next(iter(BRANCHES)), [], False, False
    for i, arg in enumerate(argv):
        if skip:
            skip = False
            continue
        if arg == "--ros-args":
            ros = True
        elif arg == "--" and ros:
            ros = False
        elif ros and arg in ("-p", "--param") and i + 1 < len(argv) and argv[i + 1].startswith("branch:="):
            branch, skip = argv[i + 1].removeprefix("branch:="), True
            continue
        out.append(arg)
    if branch not in BRANCHES:
        raise ValueError(f"branch must be one of {', '.join(BRANCHES)}, got {branch!r}")
    return branch, out


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros fusion_node``."""
    try:
        branch, argv = branch_of(sys.argv if argv is None else argv)
    except ValueError as exc:
        print(f"fusion_node: parameter error: {exc}", file=sys.stderr)
        return 2
    return BRANCHES[branch]("fusion_node", __doc__.split("\n\n")[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
