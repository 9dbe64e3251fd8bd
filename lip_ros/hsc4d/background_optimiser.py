"""The live scene optimisation with its windows solved on a thread of their own.

A window takes 0.1-0.3 s on one torch thread, the first a second or more, and
several seconds on a loaded machine: solved in a node's callback, it held the
node that long, and the suit's samples beyond its queues' depth were lost (a CI
run lost 8 poses to "suit data missing" after the first window, 2026-12-07).
:class:`BackgroundOptimiser` solves each window on a thread while its owner (a
node's executor) goes on taking its inputs and posing; the frames it adds
meanwhile wait beside the optimiser and join it once the window is solved.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lip_ros.hsc4d.scene_optimisation import MAX_WAIT_WINDOWS, SceneOptimiser, WindowResult

__all__ = ["SolvedWindow", "BackgroundOptimiser"]


@dataclass(frozen=True)
class SolvedWindow:
    """A window's solve, done: the records of the frames it optimised (oldest first) and its result; or, with
    ``error``, why not: a ValueError is the optimiser's refusal (no ground under the first window's feet yet: the
    frames wait on, no records), anything else a failure (the window's frames dropped: their records). The map's
    points it used, the wall time it took (s), and the records of the frames dropped: as those added meanwhile joined
    the optimiser (``dropped``: beyond its capacity, the oldest window), or for want of room beside it while it
    solved (``fell_behind``: more than ``MAX_WAIT_WINDOWS`` windows came, the oldest of them and those before)."""

    records: list[Any]
    result: WindowResult | None
    error: Exception | None
    points: np.ndarray
    seconds: float
    dropped: list[Any] = field(default_factory=list)
    fell_behind: list[Any] = field(default_factory=list)


class BackgroundOptimiser:
    """A :class:`~lip_ros.hsc4d.scene_optimisation.SceneOptimiser` whose windows are solved on a thread of their
    own. One owner thread calls every method; only the optimiser's ``optimise`` runs elsewhere, and nothing else
    touches the optimiser meanwhile: the frames added wait beside it (at most ``MAX_WAIT_WINDOWS`` windows of
    them: beyond, the oldest are dropped, and the frames before them once the solve is done). Each frame carries a
    record of the owner's (what it publishes the frame with), given back with the window it was solved in or
    dropped with."""

    def __init__(self, optimiser: SceneOptimiser) -> None:
        self.optimiser = optimiser
        self._records: deque[Any] = deque()  # the records of the optimiser's frames, oldest first
        self._beside: deque[tuple[Any, tuple[Any, ...]]] = deque()  # (record, frame) added while a window is solved
        self._dropped_beside: list[Any] = []  # records of frames beside dropped (beyond MAX_WAIT_WINDOWS windows)
        self._thread: threading.Thread | None = None
        self._solve: tuple[np.ndarray, int, float] | None = None  # the map, frames and start of the solve running
        self._outcome: tuple[Any, float] | None = None  # (result or exception, seconds), set by the thread
        #: the sole height and the legs' length over the bones as of the last window solved (the optimiser's own
        #: may change under a solve)
        self.sole_m, self.leg_ratio = optimiser.sole_m, optimiser.leg_ratio

    def __len__(self) -> int:
        """Frames waiting: in the optimiser (and in the window being solved) and beside it."""
        return len(self._records) + len(self._beside)

    @property
    def busy(self) -> bool:
        """Whether a window is being solved, or solved and not yet :meth:`collect` ed."""
        return self._thread is not None

    def add(self, record: Any, *frame: Any) -> list[Any]:
        """One frame (:meth:`SceneOptimiser.add`'s arguments) and its record; the records of the frames dropped to
        make room (a window waited in vain as long as the optimiser lets it, or, while one is solved, more than
        ``MAX_WAIT_WINDOWS`` windows came)."""
        if self.busy:
            self._beside.append((record, frame))
            while len(self._beside) > MAX_WAIT_WINDOWS * self.optimiser.config.window:
                self._dropped_beside.append(self._beside.popleft()[0])
            return []
        return self._join(record, frame)

    def _join(self, record: Any, frame: tuple[Any, ...]) -> list[Any]:
        """Give one frame to the optimiser, its oldest window dropped first if it is at capacity; those records."""
        dropped = self.drop(self.optimiser.config.window) if len(self.optimiser) >= self.optimiser.capacity else []
        self.optimiser.add(*frame)
        self._records.append(record)
        return dropped

    def start(self, points: np.ndarray, flush: bool = False) -> bool:
        """Start solving the oldest window (``flush``: a partial one too) on the map's ``points`` (M, 3), if a whole
        one is waiting and none is being solved; whether it started."""
        optimiser = self.optimiser
        if self.busy or not (optimiser.full or (flush and len(optimiser))):
            return False
        self._solve = points, min(len(optimiser), optimiser.config.window), time.monotonic()
        self._outcome = None
        self._thread = threading.Thread(target=self._run, args=(points,), name="scene optimisation", daemon=True)
        self._thread.start()
        return True

    def _run(self, points: np.ndarray) -> None:
        start = time.monotonic()
        try:
            outcome: Any = self.optimiser.optimise(points)[0]
        except Exception as exc:  # noqa: BLE001 - handed to the owner (SolvedWindow.error)
            outcome = exc
        self._outcome = outcome, time.monotonic() - start

    def collect(self, wait: bool = False) -> SolvedWindow | None:
        """The window solved, once (None while it is being solved, unless ``wait``, or when none was started); the
        frames added meanwhile join the optimiser. A solve that failed otherwise than by ValueError drops its
        window's frames (a gap follows) and gives them back as :attr:`SolvedWindow.records` with the error."""
        if self._thread is None or (self._thread.is_alive() and not wait):
            return None
        self._thread.join()
        (outcome, seconds), (points, n, _) = self._outcome, self._solve
        self._thread = self._solve = self._outcome = None
        records, result, error = [], None, None
        if isinstance(outcome, Exception):
            error = outcome
            if not isinstance(outcome, ValueError):
                records = self.drop(n)
        else:
            if len(outcome.t) != n:
                raise RuntimeError(f"the window solved has {len(outcome.t)} frames, {n} were given")
            records, result = [self._records.popleft() for _ in range(n)], outcome
        self.sole_m, self.leg_ratio = self.optimiser.sole_m, self.optimiser.leg_ratio
        behind, dropped = [], []
        if self._dropped_beside:  # a gap among the frames waiting: those before it go too (the optimiser's continuity)
            behind, self._dropped_beside = self.drop() + self._dropped_beside, []
        while self._beside:
            dropped += self._join(*self._beside.popleft())
        return SolvedWindow(records, result, error, points, seconds, dropped, behind)

    def drop(self, n: int | None = None) -> list[Any]:
        """Forget the oldest ``n`` frames in the optimiser (None: all; a gap follows): their records. Not while a
        window is being solved (RuntimeError)."""
        if self.busy:
            raise RuntimeError("a window is being solved: collect it first")
        n = self.optimiser.drop(n)
        return [self._records.popleft() for _ in range(n)]
