"""Write the skeleton URDF shipped in ``params/`` (``python -m lip_ros.tools.make_urdf``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from lip_ros.core.skeleton import load_skeleton
from lip_ros.core.urdf import URDF_FILE, skeleton_urdf
from lip_ros.resources import params_path


def main(argv: list[str] | None = None) -> int:
    """Generate the URDF from the skeleton YAML and write it."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=params_path(URDF_FILE), help="output file")
    args = parser.parse_args(argv)
    args.out.write_text(skeleton_urdf(load_skeleton()), encoding="utf-8")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
