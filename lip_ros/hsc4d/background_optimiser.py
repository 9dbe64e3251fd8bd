"""The live scene optimisation with its windows solved on a thread of their own.

A window takes 0.1-0.3 s on one torch thread, the first a second or more, and
many seconds on a loaded machine: solved in a node's callback, it held the node
that long, and the suit's samples beyond its queues' depth were lost (a CI run
lost 8 poses to "suit data missing" after the first window, 2026-12-07).
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

from lip_ros.hsc4d.scene_optimisation import (
    MAX_WAIT_WINDOWS,
    NoGroundYet,
    SceneOptimisationConfig,
    SceneOptimiser,
    WindowResult,
)

__all__ = ["SolvedWindow", "BackgroundOptimiser"]


@dataclass(frozen=True)
class SolvedWindow:
    """A window's solve, done: the records of the frames it optimised (oldest first) and its result; or, with
    ``error``, why not: :class:`~lip_ros.hsc4d.scene_optimisation.NoGroundYet` is the optimiser's refusal (no ground
    under the first window's feet in that map: the frames wait for a later one, no records), anything else a failure
    (the window's frames dropped: their records). The wall time it took (s), and the records of the frames dropped
    as those added meanwhile joined the optimiser (more than it holds, :attr:`SceneOptimiser.capacity`: the oldest
    window, or more than ``MAX_WAIT_WINDOWS`` windows beside it: the oldest of them and those before)."""

    records: list[Any]
    result: WindowResult | None
    error: Exception | None
    seconds: float
    dropped: list[Any] = field(default_factory=list)


class BackgroundOptimiser:
    """A :class:`~lip_ros.hsc4d.scene_optimisation.SceneOptimiser` whose windows are solved on a thread of their
    own, on the latest map given (:attr:`map`). One owner thread calls every method; only the optimiser's
    ``optimise`` runs elsewhere, and nothing else touches the optimiser meanwhile: the frames added wait beside it
    (at most ``MAX_WAIT_WINDOWS`` windows of them) and join it once the window is :meth:`collect` ed. Each frame
    carries a record of the owner's (what it publishes the frame with), given back with the window it was solved in
    or dropped with."""

    def __init__(self, optimiser: SceneOptimiser) -> None:
        self._optimiser = optimiser
        self.map: np.ndarray | None = None  #: the map's points (M, 3) the next window is solved on
        self._refused_on: np.ndarray | None = None  # the map the first window found no ground under its feet in
        self._records: deque[Any] = deque()  # the records of the optimiser's frames, oldest first
        self._beside: deque[tuple[Any, tuple[Any, ...]]] = deque()  # (record, frame) added while a window is solved
        self._dropped_beside: list[Any] = []  # records of frames beside dropped (beyond MAX_WAIT_WINDOWS windows)
        self._thread: threading.Thread | None = None
        self._solving: tuple[int, np.ndarray | None] = (0, None)  # the window being solved: its frames, its map
        self._outcome: tuple[Any, float] | None = None  # (result or exception, seconds), set by the thread
        #: the sole height and the legs' length over the bones as of the last window solved (the optimiser's own
        #: may change under a solve)
        self.sole_m, self.leg_ratio = optimiser.sole_m, optimiser.leg_ratio

    def __len__(self) -> int:
        """Frames waiting: in the optimiser (and in the window being solved) and beside it."""
        return len(self._records) + len(self._beside)

    @property
    def config(self) -> SceneOptimisationConfig:
        """The optimiser's configuration."""
        return self._optimiser.config

    @property
    def beside(self) -> int:
        """Frames added while a window is solved, waiting to join the optimiser."""
        return len(self._beside)

    @property
    def busy(self) -> bool:
        """Whether a window is being solved, or solved and not yet :meth:`collect` ed."""
        return self._thread is not None

    @property
    def waits_for_map(self) -> bool:
        """Whether no window can be solved before a new map comes: none yet, or the first window found no ground
        under its feet in the latest."""
        return self.map is None or self.map is self._refused_on

    def add(self, record: Any, *frame: Any) -> list[Any]:
        """One frame (:meth:`SceneOptimiser.add`'s arguments) and its record; the records of the frames dropped to
        make room (the optimiser holds :attr:`SceneOptimiser.capacity` frames: its oldest window goes)."""
        if self.busy:
            self._beside.append((record, frame))
            while len(self._beside) > MAX_WAIT_WINDOWS * self.config.window:
                self._dropped_beside.append(self._beside.popleft()[0])
            return []
        return self._join(record, frame)

    def _join(self, record: Any, frame: tuple[Any, ...]) -> list[Any]:
        """Give one frame to the optimiser, its oldest window dropped first if it is at capacity; those records."""
        dropped = self.drop(self.config.window) if len(self._optimiser) >= self._optimiser.capacity else []
        self._optimiser.add(*frame)
        self._records.append(record)
        return dropped

    def start(self, flush: bool = False) -> bool:
        """Start solving the oldest window (``flush``: a partial one too) on :attr:`map`, if a whole one is waiting,
        none is being solved and the map is not one the first window was refused on; whether it started."""
        optimiser = self._optimiser
        if self.busy or self.waits_for_map or not (optimiser.full or (flush and len(optimiser))):
            return False
        self._solving, self._outcome = (min(len(optimiser), self.config.window), self.map), None
        thread = threading.Thread(target=self._run, args=(self.map,), name="scene optimisation", daemon=True)
        thread.start()
        self._thread = thread
        return True

    def _run(self, points: np.ndarray) -> None:
        start = time.monotonic()
        outcome: Any = RuntimeError("the solve ended without a result")
        try:
            outcome = self._optimiser.optimise(points)[0]
        except Exception as exc:  # noqa: BLE001 - handed to the owner (SolvedWindow.error)
            outcome = exc
        finally:
            self._outcome = outcome, time.monotonic() - start

    def collect(self, wait: bool = False) -> SolvedWindow | None:
        """The window solved, once (None while it is being solved, unless ``wait``, or when none was started); the
        frames added meanwhile join the optimiser. A solve that failed otherwise than by NoGroundYet drops its
        window's frames (a gap follows) and gives them back as :attr:`SolvedWindow.records` with the error."""
        if self._thread is None or (self._thread.is_alive() and not wait):
            return None
        self._thread.join()
        (outcome, seconds), (n, points) = self._outcome, self._solving
        self._thread, self._outcome = None, None
        records, result, error = [], None, None
        if isinstance(outcome, WindowResult):  # the optimiser let its frames go
            records = [self._records.popleft() for _ in range(n)]
            if len(outcome.t) == n:
                result = outcome
            else:
                error = RuntimeError(f"the window solved has {len(outcome.t)} frames, {n} were given")
        elif isinstance(outcome, NoGroundYet):  # the frames wait for a later map
            error, self._refused_on = outcome, points
        else:
            error, records = outcome, self.drop(n)
        self.sole_m, self.leg_ratio = self._optimiser.sole_m, self._optimiser.leg_ratio
        dropped = []
        if self._dropped_beside:  # a gap among the frames waiting: those before it go too (the optimiser's continuity)
            dropped, self._dropped_beside = self.drop() + self._dropped_beside, []
        while self._beside:
            dropped += self._join(*self._beside.popleft())
        return SolvedWindow(records, result, error, seconds, dropped)

    def drop(self, n: int | None = None) -> list[Any]:
        """Forget the oldest ``n`` frames in the optimiser (None: all; a gap follows): their records. Not while a
        window is being solved (RuntimeError)."""
        if self.busy:
            raise RuntimeError("a window is being solved: collect it first")
        n = self._optimiser.drop(n)
        return [self._records.popleft() for _ in range(n)]

    def close(self, deadline: float) -> None:
        """Wait until ``deadline`` (``time.monotonic()`` s) at most for a window being solved (before the process
        exits: a thread left in torch as the interpreter shuts down may abort it)."""
        if self._thread is not None:
            self._thread.join(max(0.0, deadline - time.monotonic()))
