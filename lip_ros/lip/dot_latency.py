"""Each DOT's latency to the LiDAR clock, estimated online from the limbs the LiDAR sees (ROS-free).

A DOT driver that stamps samples on their arrival over Bluetooth stamps them
tens of milliseconds late, each sensor differently. Once calibrated, a DOT
gives the direction of its bone (shank or forearm) in the level frame P at any
time; the LiDAR sees the same limb at the frame's pose time. The latency is
the shift of the DOT's stamps that best lines the two up:

* :class:`LimbFinder` finds, in each frame's performer points (in P), the
  axes of the lower legs (points 7-22 % of the body's height above the floor)
  and of the arms away from the trunk (42-66 % of the height, farther than
  10 % of the height from the trunk's vertical axis): connected groups of
  points, elongated, their principal direction (the shanks': the line of
  their horizontal position on their height, which the band's cut does not
  lean; :func:`_level_cut_axis`). The floor and the height are
  running medians of the performer's own lowest and highest points, so
  neither the ground plane nor the performer's size need to be known. Where
  the 6 cm that links them finds no limb because the performer's points lie
  farther apart than that, up and down or sideways (a limb far from the
  LiDAR, a few beams across), they link by the points' own spacing instead,
  measured on the whole performer in each of the two directions: a spinning
  LiDAR's rows and columns need not be alike (an OS1-128's rows are 0.35 deg
  apart, its columns 0.18 deg at 2048 and 0.70 deg at 512).
* :class:`LatencyEstimator` compares, for every observed frame and every
  latency of a grid (:class:`LatencyConfig`), the DOT's bone direction at
  the pose time plus that latency with the nearest limb axis seen (the two
  legs or arms are not told apart), as a truncated squared angle. Costs
  summed over a window of frames have their minimum at the latency; it is
  taken when it is clear (a contrast against latencies 40 ms away, not at the
  grid's edge), so a limb that does not move (arms still while walking,
  standing still) leaves its DOT's latency as it was.

Accuracy on the rig: docs/conventions.md ("DOT latency"); tests:
``test/lip/test_dot_latency.py``.
"""

from __future__ import annotations

import functools
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["LatencyConfig", "LimbFinder", "LatencyEstimator", "LIMB_SENSORS"]

#: The limb each DOT lies on, as :class:`LimbFinder` names it.
LIMB_SENSORS = {"left_wrist": "forearm", "right_wrist": "forearm", "left_ankle": "shank", "right_ankle": "shank"}


@dataclass(frozen=True)
class LatencyConfig:
    """Where limbs are looked for, the latencies considered, and when an estimate is taken."""

    enabled: bool = True
    low_ns: int = -40_000_000  # latencies whose costs are kept: a minimum must lie contrast_ns inside them, so
    high_ns: int = 240_000_000  # 0-200 ms can be estimated (an estimate below 0 is taken as 0)
    step_ns: int = 4_000_000
    window: int = 300  # frames whose costs are summed, per sensor (30 s at 10 Hz)
    min_frames: int = 15  # frames observed before the first estimate (docs/lip/transfer.md "Sooner")
    every: int = 15  # frames between two estimates
    max_angle_deg: float = 15.0  # the angle between the DOT's bone and the nearest limb axis is truncated here
    contrast_ns: int = 40_000_000  # the minimum must stand out against latencies this far on either side ...
    min_contrast_deg2: float = 4.0  # ... by this much (mean truncated squared angle per frame)
    shank_band: tuple[float, float] = (0.07, 0.22)  # heights of the lower legs above the floor / body height
    forearm_band: tuple[float, float] = (0.42, 0.66)  # heights of the forearms (hanging to level)
    trunk_band: tuple[float, float] = (0.55, 0.8)  # heights whose median point is the trunk's vertical axis
    forearm_off_trunk: float = 0.1  # arm points are farther than this from the trunk's axis / body height
    link_m: float = 0.06  # points closer than this are one limb
    min_points: int = 6  # of a limb
    sparse_link: float = 2.0  # where a band has no limb so and the performer's points lie farther apart than
    sparse_min_points: int = 4  # link_m up and down or sideways, they link within this many of their spacings in
    sparse_min_span: float = 2.5  # each direction (never less than link_m), and a limb needs this many points
    #                               spanning this many spacings along its axis (three beams or more)
    min_length_m: float = 0.1  # a limb's points span at least this along its axis
    min_elongation: float = 4.0  # first / second principal variance
    history: int = 30  # frames of lowest and highest points for the floor and the body height

    def __post_init__(self) -> None:
        if not (self.low_ns < self.high_ns and self.step_ns > 0 and self.window >= self.min_frames >= 1
                and self.every >= 1 and self.contrast_ns >= self.step_ns and self.history >= 1
                and self.min_points >= self.sparse_min_points >= 2 and self.sparse_link > 0.0
                and self.sparse_min_span >= 0.0):
            raise ValueError(f"invalid {self}")

    @property
    def grid_ns(self) -> np.ndarray:
        """The latencies considered (G,), int64 nanoseconds."""
        return np.arange(self.low_ns, self.high_ns + 1, self.step_ns, dtype=np.int64)


class LimbFinder:
    """The axes of the performer's lower legs and forearms in one frame's points (in P, z up)."""

    def __init__(self, config: LatencyConfig | None = None) -> None:
        self.config = config or LatencyConfig()
        self._lowest: deque[float] = deque(maxlen=self.config.history)
        self._highest: deque[float] = deque(maxlen=self.config.history)

    def axes(self, points: np.ndarray) -> dict[str, np.ndarray]:
        """Limb name ("shank", "forearm") -> (K, 3) unit axes found (K may be 0); points (N, 3) in P."""
        c = self.config
        points = np.asarray(points, dtype=np.float64)
        points = points[np.isfinite(points).all(axis=1)]
        found = {"shank": np.zeros((0, 3)), "forearm": np.zeros((0, 3))}
        if len(points) < c.min_points:
            return found
        z = points[:, 2]
        self._lowest.append(float(np.min(z)))
        self._highest.append(float(np.max(z)))
        floor = float(np.median(self._lowest))
        height = float(np.median(self._highest)) - floor
        if height <= 0.0:
            return found
        h = (z - floor) / height
        spacing = functools.cache(lambda: _spacings(points))  # measured where a band needs it
        found["shank"] = self._groups(points[(h > c.shank_band[0]) & (h < c.shank_band[1])], spacing, cut=True)
        trunk = (h > c.trunk_band[0]) & (h < c.trunk_band[1])
        if trunk.sum() >= c.min_points:
            off = np.linalg.norm(points[:, :2] - np.median(points[trunk, :2], axis=0), axis=1) / height
            found["forearm"] = self._groups(points[(h > c.forearm_band[0]) & (h < c.forearm_band[1])
                                                   & (off > c.forearm_off_trunk)], spacing)
        return found

    def _groups(self, points: np.ndarray, spacing: Callable[[], tuple[float, float]], cut: bool = False
                ) -> np.ndarray:
        """Axes (K, 3) of the connected, elongated groups of ``points``: linked closer than ``link_m``; where that
        finds none because the performer's points lie farther apart than that up and down or sideways
        (``spacing()``: :func:`_spacings`; far from the LiDAR, a few beams across a limb), linked by the spacing in
        each direction instead. ``cut``: the band's two levels cut every limb in it (:func:`_level_cut_axis`)."""
        c = self.config
        if len(points) < c.sparse_min_points:
            return np.zeros((0, 3))
        points = points[:: -(-len(points) // _MAX_GROUPED)]  # thinned evenly: the groups' axes stay
        offsets = points[:, None, :] - points[None, :, :]
        up = np.abs(offsets[..., 2])
        side = np.hypot(offsets[..., 0], offsets[..., 1])
        axes = self._elongated(points, up**2 + side**2 <= c.link_m**2, c.min_points, c.min_length_m, cut)
        if len(axes) or max(spacing()) <= c.link_m:  # found, or not sparse: the points fell apart otherwise (a
            return axes  # limb hidden in part, no limb)
        link_up, link_side = (max(c.link_m, c.sparse_link * s) for s in spacing())
        near = (up / link_up) ** 2 + (side / link_side) ** 2 <= 1.0
        return self._elongated(points, near, c.sparse_min_points, c.min_length_m, cut, spacing())

    def _elongated(self, points: np.ndarray, near: np.ndarray, min_points: int, min_length_m: float, cut: bool,
                   spacing: tuple[float, float] | None = None) -> np.ndarray:
        """Axes (K, 3) of the elongated groups that ``near`` (N, N) links, of at least ``min_points`` spanning
        ``min_length_m`` along the principal axis, and ``sparse_min_span`` of the points' ``spacing`` (up and down,
        sideways) in the axis's direction if given; the principal axis, or where ``cut`` :func:`_level_cut_axis`."""
        c = self.config
        labels = _components(near)
        axes = []
        for k in np.unique(labels):
            group = points[labels == k]
            if len(group) < min_points:
                continue
            variance, vectors = np.linalg.eigh(np.cov(group.T))
            axis = vectors[:, 2]
            needed = min_length_m
            if spacing is not None:  # the spacing in the axis's direction: up and down for a vertical limb
                step = 1.0 / np.hypot(axis[2] / spacing[0], np.hypot(axis[0], axis[1]) / spacing[1])
                needed = max(needed, c.sparse_min_span * step)
            if variance[2] >= c.min_elongation * variance[1] and np.ptp(group @ axis) >= needed:
                axes.append(_level_cut_axis(group, axis) if cut else axis)
        return np.array(axes).reshape(-1, 3)


def _level_cut_axis(group: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The axis (3,) of a limb whose points (N, 3) two levels cut (the top and bottom of its band), from their
    principal ``axis``: the least-squares line of their horizontal position on their height. The points are the
    side of the limb facing the LiDAR; cut by two levels, a tilted limb's side is a strip with level ends, whose
    principal axis leans farther from the vertical than the limb (a walking shank's by up to 2 deg: on rig walks
    the ankle DOTs' latencies came out 5-8 ms late with it, 2-4 ms with this; docs/lip/transfer.md "Late by the
    cut"); each level's points are centred on a line parallel to the limb. A limb closer to level than
    ``_MIN_STEEPNESS`` (the vertical part of the unit axis) keeps its principal axis."""
    if abs(axis[2]) < _MIN_STEEPNESS:
        return axis
    height = group[:, 2] - group[:, 2].mean()
    slope = (group[:, :2] - group[:, :2].mean(axis=0)).T @ height / (height @ height)
    line = np.array([slope[0], slope[1], 1.0])
    return line / np.linalg.norm(line)


#: Below this vertical part of its unit principal axis (60 deg from the vertical) a cut limb keeps that axis: its
#: levels hold too few points to place a line through.
_MIN_STEEPNESS = 0.5


def _spacings(points: np.ndarray) -> tuple[float, float]:
    """How far apart the performer's points (N, 3) lie up and down, and sideways: the lower quartiles, over up to
    ``_MAX_GROUPED`` of them, of the distance to the nearest point more above or below than beside it, and to the
    nearest more beside than above or below (among its ``_NEIGHBOURS`` nearest). Measured over the whole performer,
    whose trunk is several beams wide and tall: a limb's own points may have no neighbour beside them but the
    other limb. The lower quartile is the beams' spacing where the body faces the LiDAR (the median, taken farther
    apart where it turns away, linked the two shanks at 12 m). A direction in which no point has a neighbour takes
    the other's spacing (inf for both with fewer than 2 points)."""
    if len(points) < 2:
        return np.inf, np.inf
    tree = cKDTree(points)
    queries = points[:: -(-len(points) // _MAX_GROUPED)]
    distance, index = tree.query(queries, k=min(_NEIGHBOURS + 1, len(points)))
    distance, offsets = distance[:, 1:], points[index[:, 1:]] - queries[:, None, :]  # the point itself first
    up = np.abs(offsets[..., 2]) > np.hypot(offsets[..., 0], offsets[..., 1])
    spacing = []
    for along in (up, ~up):
        nearest = np.where(along, distance, np.inf).min(axis=1)
        nearest = nearest[np.isfinite(nearest)]
        spacing.append(float(np.percentile(nearest, 25)) if len(nearest) else np.inf)
    vertical, horizontal = spacing
    return (horizontal if np.isinf(vertical) else vertical), (vertical if np.isinf(horizontal) else horizontal)


#: At most this many points of one band are grouped (more are thinned evenly); as many measure the spacings.
_MAX_GROUPED = 300
#: The spacings up and down and sideways are looked for among a point's this many nearest neighbours (a beam's
#: next in its row and the next row's, where one direction's spacing is up to 4 times the other's).
_NEIGHBOURS = 12


def _components(near: np.ndarray) -> np.ndarray:
    """Labels (N,) of the connected groups of N points, ``near`` (N, N) saying which pairs link (a point links to
    itself)."""
    np.fill_diagonal(near, True)
    labels = np.arange(len(near))
    while True:  # every point takes the least label of its neighbours, then of that label's point
        lowest = np.where(near, labels[None, :], len(near)).min(axis=1)
        lowest = lowest[lowest]
        if np.array_equal(lowest, labels):
            return labels
        labels = lowest


#: ``bone_axis(name, stamps_ns)``: the unit direction (T, 3) in P of sensor ``name``'s bone at the DOT stamps
#: ``stamps_ns`` (T,), NaN where the DOT has no data.
BoneAxisAt = Callable[[str, np.ndarray], np.ndarray]


class LatencyEstimator:
    """Each sensor's latency from frames of limb axes (:meth:`observe`) and its DOT's bone directions.

    A frame observed at pose time ``t`` is scored at :meth:`update` with the
    pose time of a later frame whose DOT data is complete, ``t + high_ns`` or
    later: the latencies taken off being never negative, the data it needs is
    there, live or from a bag, and the estimate depends on the data alone.
    """

    def __init__(self, sensors: Mapping[str, str] = LIMB_SENSORS, config: LatencyConfig | None = None) -> None:
        self.config = config or LatencyConfig()
        self.sensors = dict(sensors)  # sensor -> limb
        self.finder = LimbFinder(self.config)
        self._grid = self.config.grid_ns
        # (pose time, limb -> axes) of frames not yet scored (all those seen while calibrating, up to a window)
        self._waiting: deque[tuple[int, dict[str, np.ndarray]]] = deque(maxlen=self.config.window)
        self._costs = {n: deque(maxlen=self.config.window) for n in self.sensors}  # per frame, (G,) over the grid
        self._since = dict.fromkeys(self.sensors, 0)  # frames scored since the last estimate
        #: the latest clear estimate per sensor (ns), None until there is one
        self.estimate_ns: dict[str, int | None] = dict.fromkeys(self.sensors)
        #: per sensor: how many frames its costs hold, and how clear its latest minimum was
        self.frames = dict.fromkeys(self.sensors, 0)
        self.contrast_deg2: dict[str, float] = dict.fromkeys(self.sensors, 0.0)

    def observe(self, pose_stamp_ns: int, points: np.ndarray) -> None:
        """The performer's points (N, 3) in P of a frame posed at ``pose_stamp_ns``."""
        axes = self.finder.axes(points)
        if any(len(a) for a in axes.values()):
            self._waiting.append((pose_stamp_ns, axes))

    def update(self, now_ns: int, bone_axis: BoneAxisAt) -> dict[str, int]:
        """Score the frames the DOT data covers at ``now_ns`` (a pose time whose data is complete); the sensors
        whose latency estimate is new, and their estimates (ns)."""
        c = self.config
        while self._waiting and self._waiting[0][0] + c.high_ns <= now_ns:
            t, axes = self._waiting.popleft()
            for name, limb in self.sensors.items():
                cost = self._cost(bone_axis(name, t + self._grid), axes[limb])
                if cost is not None:
                    self._costs[name].append(cost)
                    self._since[name] += 1
        changed = {}
        for name, costs in self._costs.items():
            self.frames[name] = len(costs)
            if len(costs) >= c.min_frames and self._since[name] >= c.every:
                self._since[name] = 0
                estimate = self._minimum(name, np.mean(costs, axis=0))
                if estimate is not None and estimate != self.estimate_ns[name]:
                    self.estimate_ns[name] = changed[name] = estimate
        return changed

    def _cost(self, bone: np.ndarray, axes: np.ndarray) -> np.ndarray | None:
        """Truncated squared angle (G,) between the bone directions (G, 3) and the nearest of the axes (K, 3)."""
        if len(axes) == 0 or not np.isfinite(bone).all():
            return None
        cos = np.abs(bone @ axes.T).max(axis=1)
        angle = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))
        return np.minimum(angle, self.config.max_angle_deg) ** 2

    def _minimum(self, name: str, cost: np.ndarray) -> int | None:
        """The latency of the cost curve's minimum (parabola through its neighbours), None if not clear."""
        c = self.config
        k = int(np.argmin(cost))
        reach = int(round(c.contrast_ns / c.step_ns))
        if k < reach or k >= len(cost) - reach:
            self.contrast_deg2[name] = 0.0
            return None
        self.contrast_deg2[name] = float(min(cost[k - reach], cost[k + reach]) - cost[k])
        if self.contrast_deg2[name] < c.min_contrast_deg2:
            return None
        curvature = cost[k - 1] - 2.0 * cost[k] + cost[k + 1]
        shift = 0.5 * (cost[k - 1] - cost[k + 1]) / curvature if curvature > 0.0 else 0.0
        return max(int(round(self._grid[k] + shift * c.step_ns)), 0)  # a DOT is never stamped before measuring
