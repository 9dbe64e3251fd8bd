"""fusion_node: the capture graph in one process (today the LIP branch; HSC4D will be chosen by a parameter).

``ros2 run lip_ros fusion_node`` is the one command users run. It starts the
LIP graph (:mod:`lip_ros.nodes.lip.graph`: segmentation, calibration and pose
nodes in one process); the HSC4D branch, when it lands, is started by the same
command with a parameter that names the branch.
"""

from __future__ import annotations

from lip_ros.nodes.lip.graph import run_lip_graph

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ros2 run lip_ros fusion_node``."""
    return run_lip_graph("fusion_node", __doc__.split("\n\n")[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
