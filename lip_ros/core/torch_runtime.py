"""How many CPU threads torch computes on (process-wide)."""

from __future__ import annotations

import torch

__all__ = ["set_threads"]


def set_threads(count: int) -> None:
    """Run torch on ``count`` CPU threads. 1 is the fastest for this project's small networks and optimisations on
    a busy machine: with a second process on one of two cores, an HSC4D optimisation window took 0.18-0.29 s on
    one thread and 1.3-2.7 s on two."""
    torch.set_num_threads(count)
