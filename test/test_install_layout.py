"""The package installs with colcon like any ament_python package, and `ros2 run` finds its executables."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros  # DDS traffic or subprocesses

REPO = Path(__file__).resolve().parents[1]
#: Every console script of setup.py (what `ros2 run lip_ros <exe>` must find).
EXECUTABLES = re.findall(r'"(\w+) = [\w.]+:main"', (REPO / "setup.py").read_text(encoding="utf-8"))


def _ros2_run_path(prefix_path: str, package: str, executable: str) -> Path:
    """Resolve an executable exactly as `ros2 run` does (ros2run.api.get_executable_path)."""
    env_before = os.environ.get("AMENT_PREFIX_PATH")
    os.environ["AMENT_PREFIX_PATH"] = prefix_path
    try:
        from ament_index_python.packages import get_package_prefix

        base = Path(get_package_prefix(package)) / "lib" / package
    finally:
        if env_before is None:
            del os.environ["AMENT_PREFIX_PATH"]
        else:
            os.environ["AMENT_PREFIX_PATH"] = env_before
    hits = [p for p in base.rglob(executable) if p.is_file() and os.access(p, os.X_OK)]
    assert len(hits) == 1, f"{executable} not found (or ambiguous) under {base}"
    return hits[0]


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory: pytest.TempPathFactory) -> Path:
    colcon = shutil.which("colcon", path=str(Path(sys.executable).parent)) or shutil.which("colcon")
    assert colcon, "colcon-core and colcon-ros are test dependencies (setup.py extras 'test')"
    work = tmp_path_factory.mktemp("colcon")
    proc = subprocess.run(
        [colcon, "--log-base", str(work / "log"), "build", "--paths", str(REPO),
         "--build-base", str(work / "build"), "--install-base", str(work / "install")],
        cwd=work, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return work / "install" / "lip_ros"


def _env(prefix: Path) -> dict[str, str]:
    site = next(prefix.glob("lib/python3*/site-packages"))
    env = dict(os.environ, AMENT_PREFIX_PATH=str(prefix), PYTHONPATH=str(site))
    return env


def test_colcon_layout(colcon_install: Path) -> None:
    share = colcon_install / "share"
    assert (share / "ament_index" / "resource_index" / "packages" / "lip_ros").is_file()
    assert (share / "lip_ros" / "package.xml").is_file()
    assert (share / "lip_ros" / "params" / "smpl24_skeleton.yaml").is_file()
    assert (share / "lip_ros" / "params" / "smpl24_skeleton.urdf").is_file()
    assert (share / "lip_ros" / "params" / "weights" / "lip_small.pt").is_file()
    assert (share / "lip_ros" / "params" / "weights" / "lip_small.sha256").is_file()
    assert (share / "lip_ros" / "params" / "weights" / "lip_small.json").is_file()
    assert (share / "lip_ros" / "params" / "fastdds_lip.xml").is_file()
    assert (share / "lip_ros" / "launch" / "lip_real_rig.launch.xml").is_file()


@pytest.mark.parametrize("executable", EXECUTABLES)
def test_ros2_run_resolves_and_starts(colcon_install: Path, executable: str) -> None:
    exe = _ros2_run_path(str(colcon_install), "lip_ros", executable)
    proc = subprocess.run([str(exe), "--help"], env=_env(colcon_install), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "usage" in proc.stdout.lower()


def test_installed_package_reads_its_share_directory(colcon_install: Path) -> None:
    code = "import lip_ros, lip_ros.resources as p; print(lip_ros.__file__); print(p.params_dir())"
    proc = subprocess.run([sys.executable, "-c", code], env=_env(colcon_install), capture_output=True, text=True,
                          cwd="/", timeout=60)
    assert proc.returncode == 0, proc.stderr
    module_file, params = proc.stdout.split()
    assert Path(module_file).is_relative_to(colcon_install)
    assert Path(params) == colcon_install / "share" / "lip_ros" / "params"
