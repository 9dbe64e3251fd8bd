"""The HSC4D trajectory on rig captures against the truth and the paper's baselines (ROS-free).

:func:`run_capture` plays a :class:`~lip_ros.rig.site_capture.SiteCapture` into
a :class:`~lip_ros.hsc4d.refinement.CaptureRefiner` (the live
:class:`~lip_ros.hsc4d.trajectory.TrajectoryPipeline` and the suit's body) in
arrival order (each sweep once its last column is in, after the suit samples
sent before then) and collects, per sweep the pipeline output, the pelvis of

* **Baseline1**, the suit alone (its ``/mocap/odometry``),
* **Baseline2**, LiDAR-only odometry: kiss-icp as it ships
  (:class:`~lip_ros.hsc4d.lidar_odometry.KissIcpAlone`, the wearer's returns
  removed), its sensor poses through the mounting as the live pipeline had it
  at each sweep, anchored on the live trajectory's first sweep; no IMU, no
  suit, no graph,
* the **LiDAR odometry with the suit**: the live pipeline's own odometry (the
  pelvis IMU's rotation and the suit's motion in deskew, initial guess and
  speed rule) before the pose graph, through the mounting as it then stood,
* the **live** fused trajectory, and the **live optimised** one: after the
  scene-aware optimisation (:mod:`~lip_ros.hsc4d.scene_optimisation`) window by
  window, each on the live site map (``/hsc4d/map``) as it stood when the
  window's last sweep came out,
* the offline refinement (:mod:`~lip_ros.hsc4d.refinement`): the **refined
  graph** (the whole capture's graph solved at once) and the **refined**
  trajectory (that graph optimised, each window on the site's map as it stood then), also with each
  loss term left out in turn (the ablation),

and the truth. :func:`trajectory_metrics` aligns each with yaw and translation
fitted only on the ``fit_s`` seconds after the jump's landing and kept fixed
(drift is not forgiven), then reports the pelvis ATE (RMSE), the vertical
error where the ground under the wearer is not at the start's level (stairs,
ramps, the terrace) and the error at the end.

The body: the suit's joints (:class:`~lip_ros.hsc4d.suit_body.SuitBody`) on each
method's pelvis, scaled to the first fused pelvis height as the body node does;
the live graph's, as the body node publishes it, at the legs' length from the
walk from the frame after the window that first believes it on; the optimised
and refined bodies' at the walk's too; the standing feet of all three held
(:mod:`lip_ros.hsc4d.foot_lock`), as the body node and the refinement hold
them.
:func:`body_metrics` reports, against the truth and under the same alignment,
the checkpoint error (the foot joint at the middle of each true stance), the
foot contact error (a standing foot's height above the true surface under it
against the truth's), foot sliding per frame and the root-relative MPJPE;
:func:`map_metrics` each map's distance to the true scene surface (the whole
site's from the live odometry, S_live, and from the refined trajectory, S_opt).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from lip_ros.core.metrics import align_yaw_translation, mpjpe
from lip_ros.core.skeleton import load_skeleton
from lip_ros.hsc4d.foot_lock import FOOT_LOCK, FootLockConfig, locked_bodies
from lip_ros.hsc4d.lidar_odometry import NOT_REGISTERED, KissIcpAlone
from lip_ros.hsc4d.refinement import CaptureRefiner, RefinementConfig
from lip_ros.hsc4d.scene_optimisation import TERMS, SceneOptimisationConfig, optimise_sequence, without
from lip_ros.hsc4d.suit_body import FEET, bent_legs, leg_chains, moved_body, resized_body
from lip_ros.hsc4d.trajectory import TrajectoryConfig
from lip_ros.rig.mesh_raycast import MeshRaycaster
from lip_ros.rig.site_capture import SiteCapture
from lip_ros.rig.terrain import Terrain

__all__ = ["METHODS", "ABLATIONS", "MAPS", "TrajectoryRun", "CaptureLost", "capture_sweeps", "run_capture", "aligned",
           "trajectory_metrics", "body_metrics", "map_metrics"]


class CaptureLost(RuntimeError):
    """The live pipeline gave no trajectory for a capture, or not for every sweep (the jump not synced, ...)."""


#: the trajectories compared, in report order
METHODS = ("baseline1_suit", "baseline2_lidar", "lidar_with_suit", "live", "live_optimised", "refined_graph", "refined")
#: the refinement with one loss term left out, per term
ABLATIONS = tuple(f"refined_without_{term}" for term in TERMS)
#: the maps measured, each under the alignment of the trajectory that placed it: the whole site's from the live
#: odometry as the live graph ends it (S_live, ``/hsc4d/map``), and from the refined trajectory (S_opt)
MAPS = {"live": "live", "refined": "refined"}


@dataclass(frozen=True)
class TrajectoryRun:
    """One capture's trajectories at the output sweeps' reference times ``t_s`` (s since the capture began):
    pelvis positions (N, 3) and joints (N, 24, 3) per method (:data:`METHODS`, :data:`ABLATIONS`) and of the
    truth, the true ground height under the true pelvis (N,), which foot truly stands (N, 2), the jump's landing
    (s), the suit clock offset found and the true one (ns), which registrations were not believed (N,; False for
    the sweeps the odometry's rate cap posed by the suit), the time
    each sweep took in ``add_sweep`` (ms; the sweeps held until the jump are registered together in the call that
    finds it, each counted at that call's time over their number), the refinement's optimisation time per window
    (s) and the sole height it measured (m), the pipeline's counters, the maps (M, 3) in ``map`` (:data:`MAPS`), the
    wall time of the whole offline refinement (s), and the mounting T_M_L (4, 4: the sensor in the pelvis frame)
    the pipeline ended with, its nominal value and the truth, its rotation R_M_L (3, 3) by the walk's turns
    (None if they did not give it), and what the checks of the mounting at the start found."""

    seed: int
    t_s: np.ndarray
    positions: dict[str, np.ndarray]
    joints: dict[str, np.ndarray]
    truth: np.ndarray
    true_joints: np.ndarray
    ground: np.ndarray
    true_stance: np.ndarray
    landing_s: float
    offset_ns: int
    true_offset_ns: int
    rejected: np.ndarray
    sweep_ms: np.ndarray
    window_s: np.ndarray
    sole_m: float
    counts: dict[str, int]
    maps: dict[str, np.ndarray]
    refine_s: float
    mount: np.ndarray
    nominal_mount: np.ndarray
    true_mount: np.ndarray
    hand_eye: np.ndarray | None
    mount_checks: str
    body_scales: dict[str, float]  #: the body's size over the contract's: "height" (the standing pelvis height's),
    #: "live" (the live graph's at the last frame), "live_optimised" (its last window's), "refined", "truth"


def capture_sweeps(capture: SiteCapture, refiner: CaptureRefiner) -> Iterator[tuple[int, int, np.ndarray, np.ndarray]]:
    """The capture's sweeps in arrival order, each once the suit's samples and odometry sent before it (on the
    suit's clock) went to ``refiner``: (index, stamp ns, points (N, 3) in L, their times ns (N,)); the caller
    gives each sweep to the refiner (or its pipeline)."""
    streams = {name: list(s.samples(f"mocap_{name}")) for name, s in capture.suit_streams().items()}
    odometry = capture.suit_odometry()
    true_offset = int(round(capture.suit.clock_offset_s * 1e9))
    imu_next = dict.fromkeys(streams, 0)
    odo_next = 0
    for k, frame in capture.frames():
        arrival = capture.frame_stamp_ns(k) + capture.lidar.period_ns + true_offset  # on the suit's clock
        for name, samples in streams.items():
            stop = imu_next[name]
            while stop < len(samples) and samples[stop].stamp_ns <= arrival:
                stop += 1
            refiner.add_suit_imu(name, samples[imu_next[name]:stop])
            imu_next[name] = stop
        while odo_next < len(odometry.stamp_ns) and odometry.stamp_ns[odo_next] <= arrival:
            refiner.add_suit_odometry(int(odometry.stamp_ns[odo_next]), odometry.position[odo_next],
                                      odometry.quat[odo_next])
            odo_next += 1
        p = frame.points.ravel()
        yield k, frame.stamp_ns, np.stack([p["x"], p["y"], p["z"]], axis=1), frame.stamp_ns + p["t"].astype(np.int64)


def run_capture(capture: SiteCapture, config: TrajectoryConfig | None = None,
                progress: Callable[[int, int], None] | None = None,
                scene: SceneOptimisationConfig | None = None,
                foot_lock: FootLockConfig | None = FOOT_LOCK) -> TrajectoryRun:
    """Play ``capture`` through a :class:`CaptureRefiner` (``progress(k, n)`` after each sweep), pose the body on
    each method's trajectory and optimise the live one and refine the capture with ``scene``, the standing feet of
    the live graph's, live optimised and refined bodies held by ``foot_lock`` (None: not held); :class:`CaptureLost`
    if a sweep was not posed or the capture cannot be refined."""
    scene = scene or SceneOptimisationConfig()
    refiner = CaptureRefiner(RefinementConfig(trajectory=config or TrajectoryConfig(), scene=scene,
                                              foot_lock=foot_lock))
    pipeline = refiner.pipeline
    steps, sweep_ms = 0, []
    kiss, lidar_only = KissIcpAlone(), {}  # Baseline2's sensor pose per sweep stamp
    maps: list[tuple[int, np.ndarray]] = []  # (the newest step's index, the live site map then), once per window
    n = capture.num_frames
    for k, stamp_ns, points, point_ns in capture_sweeps(capture, refiner):
        finite = np.isfinite(points).all(axis=1)
        lidar_only[stamp_ns] = kiss.register(points[finite], point_ns[finite])
        t0 = time.perf_counter()
        out = pipeline.add_sweep(points, point_ns, stamp_ns)
        ms = 1e3 * (time.perf_counter() - t0)
        refiner.keep(out)
        steps += len(out)
        sweep_ms += [ms / max(len(out), 1)] * len(out)  # the held sweeps share the call that registers them
        if steps and steps // scene.window > len(maps):
            maps.append((steps - 1, pipeline.map_points()))
        if progress is not None:
            progress(k, n)
    if pipeline.offset_ns is None or not steps:
        raise CaptureLost(f"capture {capture.config.seed}: no trajectory ({pipeline.status})")
    if refiner.counts:
        raise CaptureLost(f"capture {capture.config.seed}: sweeps not kept: {dict(refiner.counts)}")
    maps.append((steps - 1, pipeline.map_points()))
    live = refiner.record
    t_s = (live.stamps_ns - capture.epoch_ns) * 1e-9
    truth = capture.truth(t_s)
    try:
        refined = refiner.refine()
    except ValueError as error:  # no ground mapped under the feet anywhere: a capture the method lost
        raise CaptureLost(f"capture {capture.config.seed}: no refinement: {error}") from error
    kiss_poses = np.array([lidar_only[ns] for ns in live.sweeps_ns])
    anchor = live.lidar[0] @ np.linalg.inv(kiss_poses[0])  # T_map_O of kiss-icp's odometry frame
    T_L_M = np.linalg.inv(live.lidar) @ live.lidar_pelvis  # the mounting as each sweep had it
    poses = {
        "baseline1_suit": live.suit_pelvis,
        "baseline2_lidar": anchor @ kiss_poses @ T_L_M,
        "lidar_with_suit": live.lidar_pelvis,
        "live": live.pelvis,
        "refined_graph": refined.graph,
        "refined": refined.pelvis,
    }
    joints = {name: moved_body(live.body, live.pelvis, T).joints for name, T in poses.items()}
    joints["baseline1_suit"], joints["refined"] = live.suit_joints, refined.body.joints
    feet = [load_skeleton().index(f) for f in FEET]
    skeleton = refiner.body.skeleton
    result = optimise_sequence(t_s, live.pelvis, *leg_chains(skeleton, live.body.local_rot),
                               live.suit_pelvis[:, :3, 3], live.suit_joints[:, feet],
                               lambda k: next(m for last, m in maps if last >= k), scene)
    # the fused body as the body node publishes it: at the legs' length from the walk as of the windows solved
    # before the frame came (less the half second a window takes to solve there), its standing feet held
    fused = resized_body(live.body, result.arrival_leg_ratio)
    if foot_lock is not None:
        fused = locked_bodies(skeleton, t_s, fused, live.suit_joints[:, feet], foot_lock)
    joints["live"] = fused.joints
    poses["live_optimised"] = result.pelvis
    optimised = resized_body(bent_legs(moved_body(live.body, live.pelvis, result.pelvis), skeleton, result.legs),
                             result.leg_ratio)
    if foot_lock is not None:
        optimised = locked_bodies(skeleton, t_s, optimised, live.suit_joints[:, feet], foot_lock)
    joints["live_optimised"] = optimised.joints
    for term, name in zip(TERMS, ABLATIONS, strict=True):
        ablated = refiner.refine(without(scene, term), refined.sole_m)
        poses[name], joints[name] = ablated.pelvis, ablated.body.joints
    true_offset = int(round(capture.suit.clock_offset_s * 1e9))
    jump = next(end for name, _, end in capture.phases_ns() if name == "jump")
    return TrajectoryRun(capture.config.seed, t_s, {k: v[:, :3, 3] for k, v in poses.items()}, joints,
                         truth.pelvis, truth.joints, capture.terrain.surface_height(truth.pelvis[:, :2]),
                         truth.contacts.stance, (jump - capture.epoch_ns) * 1e-9, int(pipeline.offset_ns),
                         true_offset, np.array([bool(r) and r != NOT_REGISTERED for r in live.rejected]),
                         np.array(sweep_ms),
                         refined.window_s, refined.sole_m, dict(pipeline.counts),
                         {"live": maps[-1][1], "refined": refined.map},
                         refined.seconds, np.linalg.inv(pipeline.T_L_M), pipeline.config.mount.T_M_L,
                         capture.mount.T_M_L, pipeline.hand_eye.R_M_L,
                         f"spin: {pipeline.spin.status}; hip: {pipeline.side.status}",
                         {"height": skeleton.scale, "live": skeleton.scale * float(result.arrival_leg_ratio[-1]),
                          "live_optimised": skeleton.scale * float(result.leg_ratio[-1]),
                          "refined": skeleton.scale * refined.leg_ratio, "truth": capture.motion.skeleton.scale})


def _fit_window(run: TrajectoryRun, fit_s: float) -> np.ndarray:
    """(N,) bool: the sweeps in the ``fit_s`` seconds after the landing."""
    fit = (run.t_s >= run.landing_s) & (run.t_s <= run.landing_s + fit_s)
    if fit.sum() < 2:
        raise ValueError(f"fewer than two sweeps in the {fit_s} s after the landing at {run.landing_s:.1f} s")
    return fit


def _alignment(run: TrajectoryRun, name: str, fit_s: float) -> np.ndarray:
    """T (4, 4): method ``name``'s pelvis turned about z and shifted onto the truth by the fit over the ``fit_s`` s
    after the landing."""
    return align_yaw_translation(run.positions[name], run.truth, _fit_window(run, fit_s))


def _shape_alignment(run: TrajectoryRun, name: str) -> np.ndarray:
    """T (4, 4): method ``name``'s pelvis turned about z and shifted onto the truth by the fit over the whole
    capture after the landing (drift forgiven)."""
    return align_yaw_translation(run.positions[name], run.truth, run.t_s >= run.landing_s)


def aligned(run: TrajectoryRun, name: str, fit_s: float = 5.0) -> np.ndarray:
    """(N, 3) method ``name``'s pelvis positions turned about z and shifted onto the truth by the fit over the
    ``fit_s`` s after the landing, kept for the whole capture."""
    T = _alignment(run, name, fit_s)
    return run.positions[name] @ T[:3, :3].T + T[:3, 3]


def trajectory_metrics(run: TrajectoryRun, fit_s: float = 5.0, level_m: float = 0.05) -> dict[str, dict[str, float]]:
    """Per method (:data:`METHODS`, :data:`ABLATIONS`): ``ate_m`` (pelvis RMSE after the yaw + translation
    alignment fitted on the ``fit_s`` s after the landing), ``vertical_m`` (RMS height error where the true
    ground is more than ``level_m`` off the start's level: stairs, ramps, the terrace), ``final_m`` (error at the
    end), the alignment's own residual ``fit_m`` (RMSE over the fitted seconds) and, as a diagnostic beside the
    ATE, ``shape_m``: the RMSE after a yaw + translation alignment fitted on the whole capture after the landing
    (drift forgiven: the trajectory's shape alone). The fitted seconds are a few metres of a straight walk, so a
    centimetre across them turns the whole trajectory by a few tenths of a degree: ``shape_m`` shows how much of
    a difference in ATE is that."""
    fit = _fit_window(run, fit_s)
    after = run.t_s >= run.landing_s
    off_level = np.abs(run.ground - run.ground[0]) > level_m
    out = {}
    for name in run.positions:
        p = aligned(run, name, fit_s)
        err = np.linalg.norm(p - run.truth, axis=1)
        dz = p[:, 2] - run.truth[:, 2]
        T = _shape_alignment(run, name)
        shape = np.linalg.norm(run.positions[name] @ T[:3, :3].T + T[:3, 3] - run.truth, axis=1)[after]
        out[name] = {
            "ate_m": float(np.sqrt(np.mean(err**2))),
            "vertical_m": float(np.sqrt(np.mean(dz[off_level] ** 2))) if off_level.any() else float("nan"),
            "final_m": float(err[-1]),
            "fit_m": float(np.sqrt(np.mean(err[fit] ** 2))),
            "shape_m": float(np.sqrt(np.mean(shape**2))),
        }
    return out


def body_metrics(run: TrajectoryRun, terrain: Terrain, fit_s: float = 5.0) -> dict[str, dict[str, float]]:
    """Per method, and ``truth`` for the sliding the true motion has itself, after the landing and under the
    pelvis's alignment: ``checkpoint_m`` (the foot joint against the true one at the middle of each true
    stance), ``contact_m`` (mean absolute difference of a truly standing foot joint's height above the true
    surface under it from the truth's), ``sliding_m`` (mean motion of a truly standing foot joint from one frame
    to the next, while it stands in both) and ``mpjpe_mm`` (root-relative)."""
    feet = [load_skeleton().index(f) for f in FEET]
    after = run.t_s >= run.landing_s
    stance = run.true_stance & after[:, None]
    checkpoints = []
    for foot in range(2):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], stance[:, foot].astype(np.int8), [0]])))
        checkpoints += [((start + stop - 1) // 2, foot) for start, stop in zip(edges[::2], edges[1::2], strict=True)]
    rows, cols = np.array(checkpoints).T if checkpoints else (np.zeros(0, int), np.zeros(0, int))
    true_feet = run.true_joints[:, feet]

    def height(f: np.ndarray) -> np.ndarray:
        return f[..., 2] - terrain.surface_height(f[..., :2].reshape(-1, 2)).reshape(f.shape[:-1])

    both = stance[1:] & stance[:-1]
    out = {"truth": {"sliding_m": float(np.linalg.norm(np.diff(true_feet, axis=0)[both], axis=-1).mean())}}
    for name in run.joints:
        T = _alignment(run, name, fit_s)
        joints = run.joints[name] @ T[:3, :3].T + T[:3, 3]
        f = joints[:, feet]
        out[name] = {
            "checkpoint_m": float(np.linalg.norm(f[rows, cols] - true_feet[rows, cols], axis=-1).mean()),
            "contact_m": float(np.abs(height(f) - height(true_feet))[stance].mean()),
            "sliding_m": float(np.linalg.norm(np.diff(f, axis=0)[both], axis=-1).mean()),
            "mpjpe_mm": 1000.0 * float(mpjpe(joints[after], run.true_joints[after]).mean()),
        }
    return out


def map_metrics(run: TrajectoryRun, terrain: Terrain, fit_s: float = 5.0, max_m: float = 1.0,
                max_points: int = 200_000) -> dict[str, dict[str, float]]:
    """Per map of :data:`MAPS`, against the true scene under the alignment of the trajectory that placed it (the
    ATE's, fitted on the ``fit_s`` s after the landing): the median and 90th percentile distance of its points (at
    most ``max_points`` of them, drawn at random) to the scene's surface (m; :meth:`MeshRaycaster.surface_distance`,
    at most 7 % high), the fraction farther than ``max_m`` (or seen nowhere near a surface) and the number of
    points; and ``map_shape_median_m`` / ``map_shape_p90_m``, the same under that trajectory's alignment fitted on
    the whole capture after the landing (drift forgiven, as ``shape_m``: a few tenths of a degree of the short fit
    are centimetres across the site, whichever map it turns)."""
    raycaster = MeshRaycaster(terrain.triangles())
    rng = np.random.default_rng(run.seed)
    out = {}
    for name, method in MAPS.items():
        points = run.maps[name]
        if len(points) > max_points:
            points = points[rng.choice(len(points), max_points, replace=False)]
        points = points.astype(np.float64)
        out[name] = {"map_points": int(len(run.maps[name]))}
        for prefix, T in (("map", _alignment(run, method, fit_s)),
                          ("map_shape", _shape_alignment(run, method))):
            d = raycaster.surface_distance(points @ T[:3, :3].T + T[:3, 3], max_range=max_m)
            near = d[np.isfinite(d)]
            out[name] |= {f"{prefix}_median_m": float(np.median(near)) if near.size else float("nan"),
                          f"{prefix}_p90_m": float(np.percentile(near, 90)) if near.size else float("nan")}
            if prefix == "map":
                out[name]["map_far_fraction"] = float(1.0 - near.size / max(len(d), 1))
    return out
