"""The latency figures every node reports on /diagnostics (``LatencyWindow``): over the whole run and recently."""

from __future__ import annotations

import numpy as np

from lip_ros.nodes.base import LatencyWindow


def test_percentiles_cover_the_whole_run_and_the_recent_window_only_the_last() -> None:
    """5000 latencies, the last 1000 of them ten times longer: the whole run's p50 / p90 / p99 / max as numpy's
    nearest rank to within the histogram's 0.5 %, the recent ones of the last 1000 alone, memory fixed."""
    rng = np.random.default_rng(0)
    early, late = rng.gamma(4.0, 10.0, 4000), rng.gamma(4.0, 100.0, 1000)  # ms
    window = LatencyWindow(size=1000)
    bins = window._counts.size
    for ms in np.concatenate([early, late]):
        window.add(ms * 1e-3)
    values = {k: float(v) for k, v in window.values("latency_ms").items()}
    every = np.concatenate([early, late])
    for q in (50, 90, 99):
        want = np.percentile(every, q, method="inverted_cdf")
        assert abs(values[f"latency_ms_p{q}"] / want - 1.0) < 0.005, (q, values, want)
    assert values["latency_ms_max"] == round(every.max(), 1)
    for q in (50, 99):
        assert abs(values[f"latency_ms_recent_p{q}"] - np.percentile(late, q)) < 0.05
    assert window.count == 5000 and window._counts.size == bins and window._counts.sum() == 5000


def test_no_latency_no_values_and_extremes_stay_in_range() -> None:
    window = LatencyWindow()
    assert window.values("x") == {}
    window.add(1e-9)  # below the histogram's first edge
    window.add(5000.0)  # above its last
    assert window.percentiles([0.1, 100]) == [0.01, 5e6]
