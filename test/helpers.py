"""Shared by the tests that start the package's executables as separate processes."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEMO_BAG = REPO / "bags" / "demo_walk"


def console_script(name: str) -> str:
    """Path of one of the package's console scripts in the running environment."""
    exe = shutil.which(name, path=str(Path(sys.executable).parent))
    assert exe, f"{name} console script not installed in this environment"
    return exe
