"""Child processes started with ``start_child`` end when their parent is killed (real processes, real signals)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from helpers import alive

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")

_PARENT = textwrap.dedent("""
    import sys, time
    from lip_ros.children import start_child
    child = start_child([sys.executable, "-c", sys.argv[1], sys.argv[2]])
    print(child.pid, flush=True)
    time.sleep(60)
""")
_CHILD = textwrap.dedent("""
    import signal, sys, time
    from pathlib import Path
    signal.signal(signal.SIGTERM, lambda *_: (Path(sys.argv[1]).write_text("SIGTERM"), sys.exit(0)))
    Path(sys.argv[1] + ".ready").touch()
    time.sleep(60)
""")


def test_a_child_gets_sigterm_when_its_parent_is_killed(tmp_path: Path):
    said = tmp_path / "signal"
    parent = subprocess.Popen([sys.executable, "-c", _PARENT, _CHILD, str(said)], stdout=subprocess.PIPE, text=True)
    try:
        child = int(parent.stdout.readline())
        deadline = time.monotonic() + 30.0
        while not Path(f"{said}.ready").exists():
            assert time.monotonic() < deadline, "the child did not start"
            time.sleep(0.05)
        assert alive(child)
        os.kill(parent.pid, signal.SIGKILL)  # no chance to stop its child itself
        parent.wait()
        deadline = time.monotonic() + 10.0
        while alive(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not alive(child)
        assert said.read_text() == "SIGTERM"
    finally:
        if parent.poll() is None:
            parent.kill()
