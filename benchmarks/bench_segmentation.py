"""Time the performer segmentation per OS1-128 frame (1024 and 2048 columns) on rig captures.

Each capture is a 13 s walk with clutter and a bystander; the performer is
locked by the T-pose rule during the calibration. Frames before the lock
(clustering the whole image) and after it (tracking in a window) are timed
separately; precision and recall of the performer's points after the lock come
along. Only ``PerformerSegmenter.process`` is timed, not the simulation. Run:
``python benchmarks/bench_segmentation.py``.
"""

from __future__ import annotations

import time

import numpy as np

from lip_ros.lip.segmentation import PerformerSegmenter
from lip_ros.rig.capture import CaptureConfig, CaptureSession

DISTANCES = (4.0, 8.0, 12.0, 20.0)


def run(columns: int, distance: float) -> tuple[list[float], list[float], float, float]:
    """Times (ms) before and after the lock, and the mean precision and recall after it."""
    session = CaptureSession(CaptureConfig(scenario="walk", seconds=13.0, seed=1, columns=columns,
                                           distance_m=distance, clutter=True, second_person=True))
    segmenter = PerformerSegmenter()
    before, after, precision, recall = [], [], [], []
    for cf in session.frames():
        locked = segmenter.locked
        t0 = time.perf_counter()
        result = segmenter.process(cf.frame.points, cf.stamp_ns)
        (after if locked else before).append(1e3 * (time.perf_counter() - t0))
        if locked:
            truth = cf.frame.labels == 0
            hits = (result.mask & truth).sum()
            precision.append(hits / max(result.mask.sum(), 1))
            recall.append(hits / max(truth.sum(), 1))
    return before, after, float(np.mean(precision)), float(np.mean(recall))


def main() -> None:
    print("performer segmentation, OS1-128, 13 s walk with clutter and a bystander (ms per frame)")
    print(f"{'columns':>7} {'dist m':>6} | {'before lock: median':>19} {'max':>6} | {'tracking: median':>16} "
          f"{'p90':>6} {'max':>6} | {'precision':>9} {'recall':>6}")
    for columns in (1024, 2048):
        for distance in DISTANCES:
            before, after, precision, recall = run(columns, distance)
            print(f"{columns:>7} {distance:>6.1f} | {np.median(before):>19.2f} {np.max(before):>6.1f} | "
                  f"{np.median(after):>16.2f} {np.percentile(after, 90):>6.2f} {np.max(after):>6.1f} | "
                  f"{precision:>9.4f} {recall:>6.4f}")


if __name__ == "__main__":
    main()
