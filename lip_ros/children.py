"""Child processes that end with their parent, however the parent ends.

A process the package starts (``fusion_node``'s HSC4D body node; the node,
recorder and player of ``lip_process_bag``) outlives a parent that is killed
(``SIGKILL``, the out-of-memory killer, a test's timeout) unless told
otherwise: it goes on publishing and subscribing in the same ROS domain, and
the next run there gets its messages and its ``/clock``. On Linux
:func:`start_child` has the kernel send the child ``SIGTERM`` when its parent
dies (``PR_SET_PDEATHSIG``), which the package's executables take as a clean
stop (:func:`lip_ros.signals.stop_on_signals`); a child whose parent died
before that was set exits at once. Elsewhere it is a plain ``subprocess.Popen``.
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["PARENT_DEATH_SIGNAL", "start_child"]

#: What a child started by :func:`start_child` gets when its parent dies.
PARENT_DEATH_SIGNAL = signal.SIGTERM
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
_prctl = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None


def _die_with(parent_pid: int) -> Callable[[], None]:
    """What the child runs between fork and exec: ask for the signal, and end if the parent is already gone."""
    def preexec() -> None:
        _prctl(_PR_SET_PDEATHSIG, int(PARENT_DEATH_SIGNAL), 0, 0, 0)
        if os.getppid() != parent_pid:  # it died before the request: nobody would send the signal
            os._exit(1)
    return preexec


def start_child(args: Sequence[str], **kwargs: Any) -> subprocess.Popen:
    """``subprocess.Popen(args, **kwargs)`` whose process gets :data:`PARENT_DEATH_SIGNAL` when this one dies.

    Linux sends it when the *thread* that started the child ends: start children from the main thread (or one
    that lives as long as they should).
    """
    if _prctl is None:
        return subprocess.Popen(args, **kwargs)
    return subprocess.Popen(args, preexec_fn=_die_with(os.getpid()), **kwargs)  # noqa: PLW1509
