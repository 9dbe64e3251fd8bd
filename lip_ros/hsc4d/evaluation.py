"""The HSC4D trajectory on rig captures against the truth and the paper's baselines (ROS-free).

:func:`run_capture` plays a :class:`~lip_ros.rig.site_capture.SiteCapture` into
a :class:`~lip_ros.hsc4d.trajectory.TrajectoryPipeline` in arrival order (each
sweep once its last column is in, after the suit samples sent before then) and
collects, per sweep the pipeline output, the pelvis position of

* **Baseline1**, the suit alone (its ``/mocap/odometry``),
* **Baseline2**, the LiDAR odometry alone (the sensor pose through the
  levelled mounting, no fusion),
* the **live** fused trajectory and the **refined** one (the whole graph),

and the truth. :func:`trajectory_metrics` aligns each with yaw and translation
fitted only on the ``fit_s`` seconds after the jump's landing and kept fixed
(drift is not forgiven), then reports the pelvis ATE (RMSE), the vertical
error where the ground under the wearer is not at the start's level (stairs,
ramps, the terrace) and the error at the end.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lip_ros.core.metrics import align_yaw_translation
from lip_ros.hsc4d.trajectory import TrajectoryConfig, TrajectoryPipeline
from lip_ros.rig.site_capture import SiteCapture

__all__ = ["METHODS", "TrajectoryRun", "run_capture", "aligned", "trajectory_metrics"]

#: the trajectories compared, in report order
METHODS = ("baseline1_suit", "baseline2_lidar", "live", "refined")


@dataclass(frozen=True)
class TrajectoryRun:
    """One capture's trajectories at the output sweeps' reference times ``t_s`` (s since the capture began):
    pelvis positions (N, 3) per method and of the truth, the true ground height under the true pelvis (N,), the
    jump's landing (s), the suit clock offset found and the true one (ns), which registrations were not
    believed (N,), the time each sweep took in ``add_sweep`` (ms; the sweeps held until the jump are
    registered together in the call that finds it, each counted at that call's time over their number) and the
    pipeline's counters."""

    seed: int
    t_s: np.ndarray
    positions: dict[str, np.ndarray]
    truth: np.ndarray
    ground: np.ndarray
    landing_s: float
    offset_ns: int
    true_offset_ns: int
    rejected: np.ndarray
    sweep_ms: np.ndarray
    counts: dict[str, int]


def run_capture(capture: SiteCapture, config: TrajectoryConfig | None = None,
                progress: Callable[[int, int], None] | None = None) -> TrajectoryRun:
    """Play ``capture`` through a :class:`TrajectoryPipeline` (``progress(k, n)`` after each sweep)."""
    pipeline = TrajectoryPipeline(config)
    pelvis = list(capture.suit_streams()["pelvis"].samples("mocap_pelvis"))
    odometry = capture.suit_odometry()
    true_offset = int(round(capture.suit.clock_offset_s * 1e9))
    imu_next = odo_next = 0
    steps, sweep_ms = [], []
    n = capture.num_frames
    for k, frame in capture.frames():
        arrival = capture.frame_stamp_ns(k) + capture.lidar.period_ns + true_offset  # on the suit's clock
        while imu_next < len(pelvis) and pelvis[imu_next].stamp_ns <= arrival:
            pipeline.add_pelvis_imu(pelvis[imu_next])
            imu_next += 1
        while odo_next < len(odometry.stamp_ns) and odometry.stamp_ns[odo_next] <= arrival:
            pipeline.add_suit_odometry(int(odometry.stamp_ns[odo_next]), odometry.position[odo_next],
                                       odometry.quat[odo_next])
            odo_next += 1
        p = frame.points.ravel()
        t0 = time.perf_counter()
        out = pipeline.add_sweep(np.stack([p["x"], p["y"], p["z"]], axis=1), frame.stamp_ns + p["t"].astype(np.int64),
                                 frame.stamp_ns)
        ms = 1e3 * (time.perf_counter() - t0)
        steps += out
        sweep_ms += [ms / max(len(out), 1)] * len(out)  # the held sweeps share the call that registers them
        if progress is not None:
            progress(k, n)
    if pipeline.offset_ns is None or not steps:
        raise RuntimeError(f"capture {capture.config.seed}: no trajectory ({pipeline.status})")
    stamps = np.array([s.stamp_ns for s in steps], dtype=np.int64)
    t_s = (stamps - capture.epoch_ns) * 1e-9
    truth = capture.truth(t_s)
    refined_ns, refined = pipeline.refine()
    if not np.array_equal(refined_ns, stamps):
        raise RuntimeError("the refinement's sweeps are not the live ones (record_s too short for the capture?)")
    T_L_M = pipeline.T_L_M
    suit_t = (stamps + pipeline.offset_ns).astype(np.float64)
    suit = np.column_stack([np.interp(suit_t, odometry.stamp_ns.astype(np.float64), odometry.position[:, i])
                            for i in range(3)])
    positions = {
        "baseline1_suit": suit,
        "baseline2_lidar": np.array([(s.lidar @ T_L_M)[:3, 3] for s in steps]),
        "live": np.array([s.pelvis[:3, 3] for s in steps]),
        "refined": refined[:, :3, 3],
    }
    jump = next(end for name, _, end in capture.phases_ns() if name == "jump")
    return TrajectoryRun(capture.config.seed, t_s, positions, truth.pelvis,
                         capture.terrain.surface_height(truth.pelvis[:, :2]), (jump - capture.epoch_ns) * 1e-9,
                         int(pipeline.offset_ns), true_offset, np.array([bool(s.rejected) for s in steps]),
                         np.array(sweep_ms), dict(pipeline.counts))


def _fit_window(run: TrajectoryRun, fit_s: float) -> np.ndarray:
    """(N,) bool: the sweeps in the ``fit_s`` seconds after the landing."""
    fit = (run.t_s >= run.landing_s) & (run.t_s <= run.landing_s + fit_s)
    if fit.sum() < 2:
        raise ValueError(f"fewer than two sweeps in the {fit_s} s after the landing at {run.landing_s:.1f} s")
    return fit


def aligned(run: TrajectoryRun, name: str, fit_s: float = 5.0) -> np.ndarray:
    """(N, 3) method ``name``'s pelvis positions turned about z and shifted onto the truth by the fit over the
    ``fit_s`` s after the landing, kept for the whole capture."""
    T = align_yaw_translation(run.positions[name], run.truth, _fit_window(run, fit_s))
    return run.positions[name] @ T[:3, :3].T + T[:3, 3]


def trajectory_metrics(run: TrajectoryRun, fit_s: float = 5.0, level_m: float = 0.05) -> dict[str, dict[str, float]]:
    """Per method (:data:`METHODS`): ``ate_m`` (pelvis RMSE after the yaw + translation alignment fitted on the
    ``fit_s`` s after the landing), ``vertical_m`` (RMS height error where the true ground is more than
    ``level_m`` off the start's level: stairs, ramps, the terrace), ``final_m`` (error at the end), and the
    alignment's own residual ``fit_m`` (RMSE over the fitted seconds)."""
    fit = _fit_window(run, fit_s)
    off_level = np.abs(run.ground - run.ground[0]) > level_m
    out = {}
    for name in METHODS:
        p = aligned(run, name, fit_s)
        err = np.linalg.norm(p - run.truth, axis=1)
        dz = p[:, 2] - run.truth[:, 2]
        out[name] = {
            "ate_m": float(np.sqrt(np.mean(err**2))),
            "vertical_m": float(np.sqrt(np.mean(dz[off_level] ** 2))) if off_level.any() else float("nan"),
            "final_m": float(err[-1]),
            "fit_m": float(np.sqrt(np.mean(err[fit] ** 2))),
        }
    return out
