"""The pelvis trajectory fused from LiDAR odometry and the suit's motion in a pose graph (the one module that
imports ``gtsam``), ROS-free.

One node per LiDAR sweep: the pelvis pose T_O_P at the sweep's reference time
in the odometry frame O. The LiDAR's registered poses, where believed (the
speed rule in :mod:`lip_ros.hsc4d.lidar_odometry` marks the others), are
*landmarks*: priors on their node (robust: a Huber kernel). The suit's relative
motion between consecutive sweeps, T_Pprev_P, is a *between* factor: tight in
rotation and horizontally, loose vertically (the suit knows nothing of
stairs). Where neither is known (before the suit's clock is synchronised, a
sweep without a believed registration) a weak constant-position factor keeps the
chain connected.

Live, :class:`LiveTrajectoryGraph` solves incrementally over a fixed lag
(gtsam's IncrementalFixedLagSmoother, iSAM2 inside; older nodes are
marginalised, so the memory stays flat) and returns the newest node's estimate
per sweep. Offline, :func:`fuse_batch` solves the whole capture's graph at once
(Levenberg-Marquardt).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

__all__ = ["PoseGraphConfig", "LiveTrajectoryGraph", "fuse_batch"]


@dataclass(frozen=True)
class PoseGraphConfig:
    """Factor uncertainties (1 sigma) and the live solver's lag. The pelvis frame P: x left, y up, z forward."""

    landmark_position_m: float = 0.03
    landmark_rotation_deg: float = 1.0
    landmark_huber: float = 2.0  # sigmas: a landmark farther off than this counts linearly
    suit_rotation_deg: float = 0.2  # per step
    suit_position_fraction: float = 0.05  # of the step's horizontal length (stride-scale error, mounting)
    suit_position_floor_m: float = 0.005  # per step
    suit_vertical_m: float = 0.1  # per step along P's y: the suit's height is the pelvis's above its planted feet
    unknown_position_m: float = 1.0  # the constant-position factor where the suit's motion is unknown
    unknown_rotation_deg: float = 30.0
    lag_s: float = 10.0

    def __post_init__(self) -> None:
        if min(self.landmark_position_m, self.landmark_rotation_deg, self.landmark_huber, self.suit_rotation_deg,
               self.suit_position_floor_m, self.suit_vertical_m, self.unknown_position_m,
               self.unknown_rotation_deg, self.lag_s) <= 0.0 or self.suit_position_fraction < 0.0:
            raise ValueError(f"invalid {self}")


def _pose3(T: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(np.asarray(T, dtype=np.float64))


def _sigmas(rotation_deg: float, position: Sequence[float]) -> gtsam.noiseModel.Base:
    r = np.radians(rotation_deg)
    return gtsam.noiseModel.Diagonal.Sigmas(np.array([r, r, r, *position], dtype=np.float64))


class _Factors:
    """The factors of node ``k`` under ``config``."""

    def __init__(self, config: PoseGraphConfig) -> None:
        c = self.config = config
        self._landmark = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(c.landmark_huber),
            _sigmas(c.landmark_rotation_deg, [c.landmark_position_m] * 3))
        self.unknown = _sigmas(c.unknown_rotation_deg, [c.unknown_position_m] * 3)

    def add(self, graph: gtsam.NonlinearFactorGraph, k: int, landmark: np.ndarray | None,
            suit: np.ndarray | None) -> None:
        """Node ``k``'s landmark prior (T_O_P, or None) and its factor to node ``k - 1`` (the suit's T_Pprev_P, or
        None: the weak constant-position one); none to a node before the first."""
        c = self.config
        if landmark is not None:
            graph.add(gtsam.PriorFactorPose3(k, _pose3(landmark), self._landmark))
        if k == 0:
            return
        if suit is None:
            graph.add(gtsam.BetweenFactorPose3(k - 1, k, gtsam.Pose3(), self.unknown))
            return
        step = float(np.hypot(suit[0, 3], suit[2, 3]))
        horizontal = c.suit_position_floor_m + c.suit_position_fraction * step
        noise = _sigmas(c.suit_rotation_deg, [horizontal, c.suit_vertical_m, horizontal])
        graph.add(gtsam.BetweenFactorPose3(k - 1, k, _pose3(suit), noise))


def _initial(previous: np.ndarray | None, landmark: np.ndarray | None, suit: np.ndarray | None) -> np.ndarray:
    """A node's starting value: its landmark, else the last node moved by the suit (or held)."""
    if landmark is not None:
        return np.asarray(landmark, dtype=np.float64)
    if previous is None:
        return np.eye(4)
    return previous @ suit if suit is not None else previous


class LiveTrajectoryGraph:
    """Incremental fusion, one sweep at a time (:meth:`add`), over the last ``lag_s`` seconds."""

    def __init__(self, config: PoseGraphConfig | None = None) -> None:
        self.config = config or PoseGraphConfig()
        self._factors = _Factors(self.config)
        params = gtsam.ISAM2Params()
        self._smoother = gtsam.IncrementalFixedLagSmoother(self.config.lag_s, params)
        self._k = 0
        self._first_ns: int | None = None
        self._last: np.ndarray | None = None

    @property
    def count(self) -> int:
        """Sweeps added."""
        return self._k

    def add(self, stamp_ns: int, landmark: np.ndarray | None, suit: np.ndarray | None) -> np.ndarray:
        """Sweep ``stamp_ns``'s believed LiDAR pelvis pose T_O_P (or None) and the suit's motion T_Pprev_P since
        the last sweep (or None); the fused T_O_P (4, 4) of this sweep."""
        if self._first_ns is None:
            self._first_ns = int(stamp_ns)
        k = self._k
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self._factors.add(graph, k, landmark, suit if k else None)
        if k == 0 and landmark is None:  # anchor the first node somewhere
            graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), self._factors.unknown))
        values.insert(k, _pose3(_initial(self._last, landmark, suit)))
        stamps = {k: (stamp_ns - self._first_ns) * 1e-9}
        self._smoother.update(graph, values, stamps)
        self._last = self._smoother.calculateEstimatePose3(k).matrix()
        self._k += 1
        return self._last


def fuse_batch(landmarks: Sequence[np.ndarray | None], suit: Sequence[np.ndarray | None],
               config: PoseGraphConfig | None = None) -> np.ndarray:
    """The whole capture's fused pelvis poses T_O_P (N, 4, 4) from each sweep's believed LiDAR pelvis pose (or
    None) and the suit's motion since the sweep before (``suit[0]`` is ignored; None where unknown)."""
    if len(landmarks) != len(suit) or not landmarks:
        raise ValueError(f"{len(landmarks)} landmarks and {len(suit)} suit motions: need as many, at least one")
    factors = _Factors(config or PoseGraphConfig())
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    previous = None
    for k, (landmark, motion) in enumerate(zip(landmarks, suit)):
        factors.add(graph, k, landmark, motion if k else None)
        previous = _initial(previous, landmark, motion if k else None)
        values.insert(k, _pose3(previous))
    if landmarks[0] is None:
        graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), factors.unknown))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
    return np.array([result.atPose3(k).matrix() for k in range(len(landmarks))])
