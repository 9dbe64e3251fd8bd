"""Where the package's data files (``params/``: YAML, skeleton, URDF) live.

On a colcon install they are in ``share/lip_ros/params`` of the package's
prefix (found through the ament index, as ``ros2 run`` finds executables); on
a pip install in ``<prefix>/share/lip_ros/params``; in a source checkout in
``params/`` beside the package.
"""

from __future__ import annotations

import sys
from functools import lru_cache
from pathlib import Path

PACKAGE = "lip_ros"


def _ament_share() -> Path | None:
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        return None
    try:
        return Path(get_package_share_directory(PACKAGE))
    except (PackageNotFoundError, OSError, ValueError, LookupError):
        return None


@lru_cache(maxsize=1)
def params_dir() -> Path:
    """The directory holding the package's parameter and model files."""
    source = Path(__file__).resolve().parent.parent / "params"
    candidates = [source, Path(sys.prefix) / "share" / PACKAGE / "params"]
    share = _ament_share()
    if share is not None:
        candidates.insert(0, share / "params")
    for c in candidates:
        if (c / "smpl24_skeleton.yaml").is_file():
            return c
    raise FileNotFoundError("lip_ros params/ not found; looked in: " + ", ".join(map(str, candidates)))


def params_path(name: str) -> Path:
    """Path of one file in the package's ``params/`` directory."""
    return params_dir() / name
