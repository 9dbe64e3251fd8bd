"""How many CPU threads torch computes on (process-wide)."""

from __future__ import annotations

import torch

__all__ = ["set_threads"]


def set_threads(count: int) -> None:
    """Run torch on ``count`` CPU threads. 1 is the fastest for this project's small networks and optimisations on
    a busy machine (``benchmarks/bench_hsc4d_optimisation.py``: beside a process busy on one of two cores, an HSC4D
    optimisation window took 0.125 s on one thread and 0.457 s on two)."""
    torch.set_num_threads(count)
