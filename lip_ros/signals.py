"""SIGINT and SIGTERM as an event that any thread can wait on, set without a lock in the signal handler.

Python runs a signal handler in the main thread between two of its bytecodes,
which may be inside the lock of the very event the handler would set (the
main thread waiting in ``Event.wait``): ``Event.set`` there waits for that
lock forever. It did, in 2 of 8 HSC4D body nodes whose parent was killed
under load (the kernel's ``SIGTERM``, :mod:`lip_ros.children`). So the
handler does nothing itself: the interpreter's C-level handler writes the
signal's number to a pipe (:func:`signal.set_wakeup_fd`), and a thread of
this module reads it and sets the event.
"""

from __future__ import annotations

import os
import signal
import threading

__all__ = ["STOP_SIGNALS", "stop_on_signals"]

#: The signals that stop the package's executables cleanly.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

_lock = threading.Lock()
_current: threading.Event | None = None  # what the next stop signal sets
_watching = False  # the pipe and its reader are set up (once per process)


def _note(signum: int, frame: object) -> None:
    """The Python-level handler: nothing (the signal reached the pipe before it ran)."""


def _read_signals(read_fd: int) -> None:
    """The watcher thread: set the current event for every stop signal written to the pipe."""
    stops = {int(s) for s in STOP_SIGNALS}
    while chunk := os.read(read_fd, 64):
        if stops & set(chunk):
            with _lock:
                event = _current
            if event is not None:
                event.set()


def stop_on_signals() -> threading.Event:
    """An event that SIGINT and SIGTERM set from now on (instead of interrupting whatever runs: a callback, a bag
    write); an event this returned earlier is no longer set by them. Call it from the main thread."""
    global _current, _watching
    stop = threading.Event()
    with _lock:
        _current = stop
        if not _watching:
            read_fd, write_fd = os.pipe()
            os.set_blocking(write_fd, False)  # the C handler must never block
            signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
            threading.Thread(target=_read_signals, args=(read_fd,), name="stop signals", daemon=True).start()
            _watching = True
    for sig in STOP_SIGNALS:
        signal.signal(sig, _note)
    return stop
