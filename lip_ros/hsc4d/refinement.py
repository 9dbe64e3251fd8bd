"""The offline refinement of a whole HSC4D capture (ROS-free): the whole pose graph at once, the scene-aware
optimisation over the site's map as each window saw it, and the map rebuilt from the refined trajectory (the paper's
S_opt).

:class:`CaptureRefiner` takes a capture's inputs in the order they arrive, as
the live graph does: the suit's segments (the pelvis's also drives the
trajectory), the suit's own odometry and the hip LiDAR's sweeps into a
:class:`~lip_ros.hsc4d.trajectory.TrajectoryPipeline`. Of each live output it
keeps what the refinement needs (:class:`LiveRecord`): the body posed on the
fused pelvis, the suit's own pelvis and body (which foot stands, the suit's
steps), and puts the sweep's points in the pipeline's site map
(:meth:`TrajectoryPipeline.add_to_map`: the whole site, placed by the live
odometry: S_live). :meth:`CaptureRefiner.refine` then

1. solves the whole capture's graph at once (:meth:`TrajectoryPipeline.refine`);
2. optimises it window by window with the scene
   (:func:`~lip_ros.hsc4d.scene_optimisation.optimise_sequence`), each window
   on the site map as it stood when the window was optimised live, as the
   live optimisation has it: when its last sweep was kept, or for a first
   window waiting for the ground under its feet, the first map that showed it
   (a *view*: kept every window, the points near the path of the windows that
   may still wait for it), each point moved with its sweep to the graph's
   trajectory (as in 3.). Not on the final map: a voxel's
   nearest sighting may come from a later visit, placed by that time's pose
   error, and the contact term then moved the feet by the difference
   (docs/hsc4d/optimisation.md "The map each window stands on");
3. holds the refined body's standing feet where they stood, as the live graph
   holds its bodies' (:mod:`~lip_ros.hsc4d.foot_lock`, ``RefinementConfig.foot_lock``);
4. rebuilds the map from the refined trajectory (S_opt: each point moved by the
   shift of the sweep that placed it, :func:`sweep_shifts`, :meth:`SiteMap.shifted`).

Memory: about 4 KB per sweep (the bodies), 20 B per map point and the views
(20 B per point near the path, a few tens of thousands per view, a view per
window; the same point in up to four views), for the whole capture
(``TrajectoryConfig.record_s`` bounds the graph's record).
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from lip_ros.core.imu_sync import ImuSampleLike
from lip_ros.core.skeleton import load_skeleton
from lip_ros.hsc4d.foot_lock import FOOT_LOCK, FootLockConfig, locked_bodies
from lip_ros.hsc4d.scene_optimisation import (
    MAX_WAIT_WINDOWS,
    SceneOptimisationConfig,
    optimise_sequence,
    walk_leg_ratio,
)
from lip_ros.hsc4d.site_map import SiteMap
from lip_ros.hsc4d.suit_body import (
    FEET,
    BodyPose,
    SuitBody,
    SuitBodyConfig,
    bent_legs,
    leg_chains,
    moved_body,
    resized_body,
)
from lip_ros.hsc4d.trajectory import TrajectoryConfig, TrajectoryPipeline, TrajectoryStep

__all__ = ["RefinementConfig", "LiveRecord", "Refinement", "MapViews", "CaptureRefiner", "sweep_shifts",
           "FOOT_REACH_M"]

#: how far (m, horizontally) beyond a window's search radius round a foot a view keeps the map round the live
#: pelvis path: a foot stands within about half a metre of the pelvis; the rest leaves room for the refined
#: pelvis's departure from the live one
FOOT_REACH_M = 1.0


@dataclass(frozen=True)
class RefinementConfig:
    """The live trajectory's (the site map's among them) and the optimisation's settings."""

    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    scene: SceneOptimisationConfig = field(default_factory=SceneOptimisationConfig)
    foot_lock: FootLockConfig | None = FOOT_LOCK  # the refined body's standing feet held (None: not)


@dataclass(frozen=True)
class LiveRecord:
    """The live outputs kept for the refinement, per sweep posed (N): reference times (LiDAR clock), the stamps the
    sweeps came with, the fused pelvis T_map_P, the odometry's sensor pose T_map_L and the pelvis through the
    mounting as it then stood (N, 4, 4), why a
    registration was not believed (N,), the body on the fused pelvis, the suit's own pelvis pose (in its world)
    and its body on it."""

    stamps_ns: np.ndarray
    sweeps_ns: np.ndarray
    pelvis: np.ndarray
    lidar: np.ndarray
    lidar_pelvis: np.ndarray
    rejected: np.ndarray
    body: BodyPose
    suit_pelvis: np.ndarray
    suit_joints: np.ndarray


@dataclass(frozen=True)
class Refinement:
    """The refined capture at the live sweeps' times (N,): the whole graph's pelvis T_map_P (N, 4, 4), that after the
    scene-aware optimisation, the body on it (its standing feet held with ``foot_lock``), the whole-site map rebuilt
    from the refined trajectory (S_opt) (M, 3) in ``map``, the sole height used (m), the time per optimisation window
    and for the whole refinement (s), and the legs' length from the whole walk over the live body's (the refined
    body's size over the live one's)."""

    stamps_ns: np.ndarray
    graph: np.ndarray
    pelvis: np.ndarray
    body: BodyPose
    map: np.ndarray
    sole_m: float
    window_s: np.ndarray
    seconds: float
    leg_ratio: float


class MapViews:
    """The site map as it stood at chosen steps, each view only near the pelvis path given with it (the map each
    optimisation window stands on, module docstring)."""

    def __init__(self, radius_m: float) -> None:
        self.radius_m = radius_m  #: a view keeps the points within this horizontal distance of its path
        self._views: list[tuple[int, np.ndarray, np.ndarray]] = []  # (step, points, the sweep of each)

    @property
    def newest(self) -> int | None:
        """The step of the newest view (None: none yet)."""
        return self._views[-1][0] if self._views else None

    @property
    def size(self) -> int:
        """The points kept, in all views."""
        return sum(len(v[1]) for v in self._views)

    def add(self, step: int, site: SiteMap, path_xy: np.ndarray) -> None:
        """Keep ``site`` as it stands at ``step`` (later than the newest view's), near the positions ``path_xy``
        (P, 2) in ``map``."""
        if self._views and step <= self._views[-1][0]:
            raise ValueError(f"views are kept in step order: {step} after {self._views[-1][0]}")
        self._views.append((step, *site.near(path_xy, self.radius_m)))

    def at(self, step: int, shifts: np.ndarray) -> np.ndarray:
        """(M, 3) the first view kept at ``step`` or later, each point moved by its sweep's shift (K, 3);
        LookupError if none is that late."""
        for newest, points, sweeps in self._views:
            if newest >= step:
                return points + shifts[sweeps]
        raise LookupError(f"no view of the map at step {step} or later (newest: {self.newest})")


def _stack(poses: list[BodyPose]) -> BodyPose:
    return BodyPose(*(np.array([getattr(p, f) for p in poses]) for f in ("local_rot", "glob_rot", "joints")))


class CaptureRefiner:
    """Plays a capture into the live trajectory and keeps what its offline refinement needs."""

    def __init__(self, config: RefinementConfig | None = None) -> None:
        c = self.config = config or RefinementConfig()
        self.pipeline = TrajectoryPipeline(c.trajectory)
        self.body = SuitBody(load_skeleton(), SuitBodyConfig(capacity=c.trajectory.suit_capacity))
        self.counts: Counter[str] = Counter()  #: frames not kept for the refinement, by reason
        self._feet = [self.body.skeleton.index(f) for f in FEET]
        self._steps: list[tuple[int, int, np.ndarray, np.ndarray, np.ndarray, str]] = []  # each step but its points
        self._mapped: list[int] = []  # each step's index in the pipeline's site map
        self._bodies: list[BodyPose] = []
        self._suit: list[tuple[np.ndarray, np.ndarray]] = []  # the suit's pelvis pose and joints
        self.views = MapViews(c.scene.radius_m + FOOT_REACH_M)  #: the map each window stands on
        self._scaled = False

    def add_suit_imu(self, segment: str, samples: list[ImuSampleLike]) -> list[str | None]:
        """Samples of one suit segment (suit clock, in time order); the pelvis's also go to the trajectory. For
        each, why it was rejected (None if kept)."""
        if segment == self.body.pelvis_segment:
            for sample in samples:
                self.pipeline.add_pelvis_imu(sample)
        return self.body.add(segment, samples)

    def add_suit_odometry(self, stamp_ns: int, position: np.ndarray, quat: np.ndarray) -> str | None:
        """One sample of the suit's own odometry (suit clock); why it was rejected, None if kept."""
        return self.pipeline.add_suit_odometry(stamp_ns, position, quat)

    def add_sweep(self, points: np.ndarray, point_ns: np.ndarray, stamp_ns: int) -> list[TrajectoryStep]:
        """One sweep (:meth:`TrajectoryPipeline.add_sweep`); the live steps that became ready, each kept."""
        steps = self.pipeline.add_sweep(points, point_ns, stamp_ns)
        self.keep(steps)
        return steps

    def keep(self, steps: list[TrajectoryStep]) -> None:
        """Keep live steps of :attr:`pipeline` (:meth:`add_sweep` does): the body on each, the suit's own, and its
        points in the site map; or why not (counted)."""
        for step in steps:
            self._keep(step)

    def _keep(self, step: TrajectoryStep) -> None:
        if not self._scaled:  # the wearer stands still in A-pose at the first step, map's origin under them
            self.body.scale_to_pelvis_height(float(step.pelvis[2, 3]))
            self._scaled = True
        suit_ns = step.stamp_ns + self.pipeline.offset_ns
        T_suit = self.pipeline.suit.pelvis(step.stamp_ns)
        body, why = self.body.pose(suit_ns, step.pelvis)
        suit = None if T_suit is None or body is None else self.body.pose(suit_ns, T_suit)[0]
        if suit is None:
            self.counts[f"not refined: {why or 'no suit odometry near the sweep'}"] += 1
            return
        self._mapped.append(self.pipeline.add_to_map(step))
        self._steps.append((step.stamp_ns, step.sweep_ns, step.pelvis, step.lidar, step.lidar_pelvis, step.rejected))
        self._bodies.append(body)
        self._suit.append((T_suit, suit.joints))
        if len(self._steps) % self.config.scene.window == 0:
            self._view()

    def _view(self) -> None:
        """Keep the site map as it stands now near the path of the steps a window may still be waiting with."""
        path = np.array([s[2][:2, 3] for s in self._steps[-MAX_WAIT_WINDOWS * self.config.scene.window:]])
        self.views.add(len(self._steps) - 1, self.pipeline.site, path)

    @property
    def record(self) -> LiveRecord:
        """The live outputs kept so far."""
        stamps, sweeps, pelvis, lidar, lidar_pelvis, rejected = (zip(*self._steps, strict=True) if self._steps
                                                                  else ([],) * 6)
        return LiveRecord(np.array(stamps, dtype=np.int64), np.array(sweeps, dtype=np.int64),
                          *(np.array(a).reshape(-1, 4, 4) for a in (pelvis, lidar, lidar_pelvis)),
                          np.array(rejected, dtype=object), _stack(self._bodies),
                          np.array([s[0] for s in self._suit]).reshape(-1, 4, 4),
                          np.array([s[1] for s in self._suit]))

    def refine(self, scene: SceneOptimisationConfig | None = None, sole_m: float | None = None) -> Refinement:
        """The offline refinement of everything kept (module docstring), the scene-aware optimisation with
        ``scene`` (default: the configuration's; its window and ground search radius as the configuration's, which
        the views were kept for) and ``sole_m`` (None: measured in its first window); the legs' length from the
        whole capture's walk at once (``scene.legs_from_walk``; :func:`walk_leg_ratio`), the body resized to it;
        ValueError before any sweep was posed."""
        start = time.perf_counter()
        scene = scene or self.config.scene
        if scene.window != self.config.scene.window or scene.radius_m > self.config.scene.radius_m:
            raise ValueError(f"the views of the map were kept for windows of {self.config.scene.window} frames and a "
                             f"ground search within {self.config.scene.radius_m} m, not {scene.window} and "
                             f"{scene.radius_m}")
        live = self.record
        if not len(live.stamps_ns):
            raise ValueError(f"nothing to refine: {self.pipeline.status}")
        all_ns, all_graph = self.pipeline.refine()
        k = np.searchsorted(all_ns, live.stamps_ns)
        if not (k < len(all_ns)).all() or not np.array_equal(all_ns[np.minimum(k, len(all_ns) - 1)], live.stamps_ns):
            raise ValueError("the graph's record lacks sweeps posed live (TrajectoryConfig.record_s shorter than "
                             "the capture?)")
        graph = all_graph[k]
        if self.views.newest != len(self._steps) - 1:
            self._view()  # the last window's
        shifts = self._shifts(live, graph)  # the feet meet the ground as their own trajectory puts it
        t_s = (live.stamps_ns - live.stamps_ns[0]) * 1e-9
        skeleton = self.body.skeleton
        legs, bones = leg_chains(skeleton, live.body.local_rot)
        suit_feet = live.suit_joints[:, self._feet]
        walk = walk_leg_ratio(t_s, graph, legs, bones, suit_feet, scene) if scene.legs_from_walk else None
        ratio = 1.0 if walk is None else walk
        t0 = time.perf_counter()
        result = optimise_sequence(t_s, graph, legs, bones, live.suit_pelvis[:, :3, 3], suit_feet,
                                   lambda step: self.views.at(step, shifts), scene, sole_m, leg_ratio=ratio)
        window_s = np.full(len(result.windows), (time.perf_counter() - t0) / max(len(result.windows), 1))
        body = resized_body(bent_legs(moved_body(live.body, live.pelvis, result.pelvis), skeleton, result.legs), ratio)
        if self.config.foot_lock is not None:
            body = locked_bodies(skeleton, t_s, body, suit_feet, self.config.foot_lock)
        rebuilt = self.pipeline.site.shifted(self._shifts(live, result.pelvis))
        return Refinement(live.stamps_ns, graph, result.pelvis, body, rebuilt, result.sole_m, window_s,
                          time.perf_counter() - start, ratio)

    def _shifts(self, live: LiveRecord, to: np.ndarray) -> np.ndarray:
        """(K, 3) how far each sweep in the site map moves for the pelvis trajectory ``to`` (N, 4, 4)
        (:func:`sweep_shifts`); the sweeps of steps not kept stay where they are."""
        shifts = np.zeros((self.pipeline.mapped, 3))
        shifts[self._mapped] = sweep_shifts(live.lidar, to, self.pipeline.T_L_M)
        return shifts


def sweep_shifts(lidar: np.ndarray, pelvis: np.ndarray, T_L_M: np.ndarray) -> np.ndarray:
    """(N, 3) how far to move each sweep placed by its odometry pose T_map_L ``lidar`` (N, 4, 4) so that its sensor
    stands where the pelvis pose T_map_P ``pelvis`` (N, 4, 4) puts it through the mounting ``T_L_M`` (4, 4; the one
    the refinement's graph used, the capture's last), its attitude kept as registered: ICP places a sweep to a
    fraction of a degree against the map, and turning it with the graph, or with the optimisation's turn of the body
    about the pelvis (which places the feet), moved the rig sites' walls by centimetres (measured). Measured from
    the sweep's own placement, through the mounting the graph used: from the live fused pelvis, as before session
    35, S_opt took the live graph's departures from the odometry and the lever arm estimate's changes over the
    capture, and was blurrier than S_live."""
    sensor = pelvis[:, :3, 3] - np.einsum("nij,j->ni", lidar[:, :3, :3], T_L_M[:3, 3])
    return sensor - lidar[:, :3, 3]
