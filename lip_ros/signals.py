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
_pipe: tuple[int, int] | None = None  # (read, write): the signals' numbers, written by the C-level handler
_reader: threading.Thread | None = None


def _note(signum: int, frame: object) -> None:
    """The Python-level handler: nothing (the signal reached the pipe before it ran)."""


def _read_signals(read_fd: int) -> None:
    """The reader thread: set the current event for every stop signal written to the pipe."""
    stops = {int(s) for s in STOP_SIGNALS}
    while chunk := os.read(read_fd, 64):
        if stops & set(chunk):
            with _lock:
                event = _current
            if event is not None:
                event.set()


def _forget_pipe_in_child() -> None:
    """After a fork: the child's signals must not reach its parent's pipe (and its parent's stop event)."""
    try:
        signal.set_wakeup_fd(-1)
    except ValueError:  # forked from a thread other than the main one: the wakeup fd is the main thread's to set
        pass


def stop_on_signals() -> threading.Event:
    """An event that SIGINT and SIGTERM set from now on (instead of interrupting whatever runs: a callback, a bag
    write); an event this returned earlier is no longer set by them. Only from the main thread (ValueError)."""
    global _current, _pipe, _reader
    if threading.current_thread() is not threading.main_thread():
        raise ValueError("stop_on_signals() must be called from the main thread")
    stop = threading.Event()
    with _lock:
        if _pipe is None:
            _pipe = os.pipe()  # not inherited by exec'd children (PEP 446)
            os.set_blocking(_pipe[1], False)  # the C-level handler must never block
            os.register_at_fork(after_in_child=_forget_pipe_in_child)
        if _reader is None or not _reader.is_alive():
            _reader = threading.Thread(target=_read_signals, args=(_pipe[0],), name="stop signals", daemon=True)
            _reader.start()
        _current = stop
    signal.set_wakeup_fd(_pipe[1], warn_on_full_buffer=False)  # again each time: other code may have set its own
    for sig in STOP_SIGNALS:
        signal.signal(sig, _note)
    return stop
