"""Captures shared by the node tests: made and run once per test session."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from helpers import HSC4D_CAPTURE, HSC4D_PLAYBACK, console_script


@pytest.fixture(scope="session")
def hsc4d_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, subprocess.CompletedProcess]:
    """The HSC4D rig capture ``HSC4D_CAPTURE`` and ``lip_process_bag --plot --refine`` on it, played as
    ``HSC4D_PLAYBACK`` says: (bag, outputs, process), the plot and the refinement beside the outputs
    (``<outputs>.png``, ``<outputs>_refined``). The clean run of the faulty captures' tests and the bag the replay's
    tests check."""
    from lip_ros.rig.site_bag import write_site_bag
    from lip_ros.rig.site_capture import SiteCapture, SiteCaptureConfig

    root = tmp_path_factory.mktemp("hsc4d_capture")
    bag, out = root / "clean", root / "clean_outputs"
    write_site_bag(SiteCapture(SiteCaptureConfig(**HSC4D_CAPTURE)), bag, progress=False)
    proc = subprocess.run([console_script("lip_process_bag"), str(bag), str(out), *HSC4D_PLAYBACK, "--plot",
                           str(out.with_suffix(".png")), "--refine"], capture_output=True, text=True, timeout=240)
    return bag, out, proc
