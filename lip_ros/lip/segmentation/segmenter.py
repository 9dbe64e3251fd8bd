"""Performer segmentation: the calibrated performer's points in the organized clouds of a static Ouster.

``PerformerSegmenter.process(points, stamp_ns)`` takes one organized frame, the
(H, W) structured array with fields x, y, z, t (ns after the stamp) and range
(mm) that ``lip_msgs_py.cloud_to_array`` returns (or the rig produces), and
gives a :class:`SegmentationResult`: the performer's pixel mask, points, per-point
times and a status. Bad input never raises; it gets a status and a reason.

How (all vectorised over the range image, no per-point Python loops):

1. **Ground**: a plane fitted once by RANSAC on the first frame (or given in
   the configuration); returns within ``ground_tolerance_m`` of it are ground.
2. **Background**: per pixel, the farthest surface seen consistently
   (:class:`lip_ros.lip.segmentation.scene.BackgroundModel`). Foreground =
   returns nearer than the background by a range-dependent margin, plus returns
   above the ground that the background does not explain (not known yet, or
   farther: what was learned there has left). Feet stay foreground: near the
   ground only the "nearer" test applies.
3. **Lock** (before the performer is known): every return above the ground is
   clustered over the full image (people who stand still cannot be told from
   the background yet) and the human-sized clusters are tracked. The lock rule
   is explicit (``lock_rule``):

   - ``"t_pose"`` (default): the calibration protocol. The performer is the
     human-sized cluster that stays put (within ``still_m``) and, while it
     does, spreads its arms: its outline across the line of sight grows on both
     sides, by ``t_pose_side_m`` each, to a width of at least
     ``t_pose_width_m`` (A-pose to T-pose). The thresholds hold for performers
     of 1.45-2.0 m turned up to 45 deg from facing the sensor (the outline
     across the line of sight shrinks with the cosine of the turn; the far arm
     grows less than the near one). Static clutter never changes shape
     (when someone passes in front of it, it only ever regains one side),
     bystanders walk. With ``expected_xy`` only clusters within
     ``expected_radius_m`` of it count.
   - ``"still"``: the human-sized cluster nearest to ``expected_xy`` (within
     ``expected_radius_m``) that stayed put for ``lock_frames`` frames; locks in
     the A-pose. The T-pose rule also needs ``lock_frames`` still frames.

   With ``resume_xy`` (where the performer was last seen, e.g. before a
   restart) a human-sized cluster within ``resume_radius_m`` of it is locked
   at once, nearest first, whatever its pose; the rule above still applies
   elsewhere.

   At the lock, the background learned under the performer is forgotten.
4. **Tracking**: foreground returns in a window of columns around the
   performer's constant-velocity prediction are clustered; the performer and
   the other people seen near it are assigned to clusters nearest first within
   their gates, so a bystander who comes close keeps their own track. The
   performer's points are its cluster plus the unassigned clusters within
   ``fragment_m`` (a limb split off at long range, its parts on either side of
   someone in front), less the points nearer to a bystander's prediction than
   to its own (people who touch merge into one cluster). Not found: the gate
   grows; after ``lost_after_s`` the status is LOST and the performer is
   re-acquired as a human-sized cluster within ``reacquire_m`` of where it was
   last seen; after ``relock_after_s`` the lock rule also looks at the whole
   frame again, so a performer who comes back elsewhere (or a capture played
   again from its start) is found by the pose that locked on them first.

A frame stamped more than :data:`lip_ros.core.clock.CLOCK_STEP_NS` before the
last one is a clock that stepped back (a PTP step, a bag played again): every
stamp the tracks remember moves with it, and the frame is segmented as the
next one; a frame only a little earlier is out of order (MALFORMED).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, replace

import numpy as np

from lip_ros.core.clock import stepped_back
from lip_ros.core.frames import level_rotation
from lip_ros.core.ground_plane import GroundPlane, fit_ground_plane
from lip_ros.core.scan_layout import ScanLayout, destagger, fit_scan_layout
from lip_ros.lip.segmentation.clusters import Clusters, describe_clusters, link_components
from lip_ros.lip.segmentation.scene import BackgroundModel
from lip_ros.lip.segmentation.tracking import Track, associate

__all__ = ["LOCK_RULES", "SegmentationConfig", "SegmentationStatus", "SegmentationResult", "PerformerSegmenter"]

#: Lock rules of :class:`SegmentationConfig` (see the module docstring).
LOCK_RULES = ("t_pose", "still")
_REQUIRED_FIELDS = ("x", "y", "z", "t", "range")
#: the longest frame interval a moved time line assumes between the last frame and the one after a clock step
_PERIOD_NS = 100_000_000


@dataclass(frozen=True)
class SegmentationConfig:
    """Thresholds of the performer segmentation (metres, seconds, frames)."""

    # ground
    ground_plane: tuple[float, float, float, float] | None = None  # a x + b y + c z + d = 0 in L; None: fit
    ground_tolerance_m: float = 0.025  # returns this close to the plane are ground (where no background is known)
    ground_max_tilt_deg: float = 15.0  # of the ground's normal from +z of L
    ground_min_points: int = 500  # inliers the fitted plane needs
    # background
    margin_m: float = 0.08  # foreground is nearer than the background by margin_m + margin_per_m * range
    margin_per_m: float = 0.005
    confirm_frames: int = 5  # consecutive returns that make a farther surface the background
    absorb_frames: int = 600  # ... a nearer one (an object left in the scene)
    # clustering
    link_m: float = 0.2  # neighbours join if closer than link_m + link_spacing * (their beam spacing at the range)
    link_spacing: float = 1.5
    link_reach: int = 2  # neighbours up to this many rows / columns apart
    # human size (lock, new bystanders, re-acquisition)
    min_points: int = 10
    min_top_m: float = 0.8  # highest point above the ground
    max_top_m: float = 2.5
    max_bottom_m: float = 0.8  # lowest point above the ground (feet on or near it)
    max_width_m: float = 2.3  # across the line of sight (arms out in T-pose: ~1.8)
    max_depth_m: float = 1.5  # along it
    hidden_feet: bool = True  # a cluster whose lower edge is hidden (a wall, the field of view) may end higher
    occluder_min_height_m: float = 0.1  # a nearer return below a cluster this high above the ground hides its feet
    # lock
    lock_rule: str = "t_pose"
    expected_xy: tuple[float, float] | None = None  # where the performer calibrates (xy in L), if known
    expected_radius_m: float = 2.0
    lock_frames: int = 3  # frames a candidate must have stood still in
    resume_xy: tuple[float, float] | None = None  # where the performer was last seen (resuming after a restart)
    resume_radius_m: float = 3.0
    still_m: float = 0.3  # standing still: staying within this of where it stopped
    t_pose_width_m: float = 0.9  # widest outline (arms out) ...
    t_pose_side_m: float = 0.12  # ... grown on the left and on the right by this much since the narrowest
    # tracking
    min_track_points: int = 3  # a cluster smaller than this is noise
    gate_m: float = 0.6  # association radius around the prediction, ...
    gate_growth_mps: float = 2.0  # ... growing while the performer is not seen, ...
    reacquire_m: float = 2.5  # ... up to this
    velocity_gain: float = 0.5  # exponential smoothing of the velocity
    horizon_s: float = 0.5  # longest extrapolation of a prediction
    window_m: float = 2.5  # clustering window around the prediction
    fragment_m: float = 1.0  # unassigned clusters this close to the performer's are part of it
    lost_after_s: float = 1.0
    relock_after_s: float = 2.0  # lost this long, the lock rule may also find the performer anywhere (a T-pose)
    other_gate_m: float = 0.8  # association radius of bystanders; new ones start farther than this from any track
    other_timeout_s: float = 0.5  # a bystander unseen this long is dropped

    def __post_init__(self) -> None:
        if self.lock_rule not in LOCK_RULES:
            raise ValueError(f"lock_rule must be one of {LOCK_RULES}, not {self.lock_rule!r}")
        if self.lock_rule == "still" and self.expected_xy is None:
            raise ValueError("lock_rule 'still' needs expected_xy")
        if not 1 <= self.confirm_frames <= self.absorb_frames < np.iinfo(np.uint16).max:
            raise ValueError("need 1 <= confirm_frames <= absorb_frames < 65535")
        if self.link_reach < 1 or self.min_points < 1 or self.min_track_points < 1 or self.lock_frames < 1:
            raise ValueError("link_reach, min_points, min_track_points and lock_frames must be >= 1")
        lengths = (self.ground_tolerance_m, self.margin_m, self.link_m, self.gate_m, self.window_m, self.still_m,
                   self.fragment_m, self.reacquire_m, self.other_gate_m, self.expected_radius_m)
        if min(lengths) <= 0.0 or self.margin_per_m < 0.0 or self.link_spacing < 0.0:
            raise ValueError("distances and margins must be positive")
        if not 0.0 < self.lost_after_s <= self.relock_after_s:
            raise ValueError("need 0 < lost_after_s <= relock_after_s")
        if not 0.0 < self.velocity_gain <= 1.0:
            raise ValueError("velocity_gain must be in (0, 1]")
        if self.ground_plane is not None:
            GroundPlane.from_coefficients(self.ground_plane)


class SegmentationStatus(str, enum.Enum):
    """Outcome of one frame."""

    OK = "ok"  # the performer's points are in the result
    NO_PERFORMER = "no_performer"  # not locked yet, or not found in this frame (shortly)
    LOST = "lost"  # not found for lost_after_s; re-acquiring near the last position
    EMPTY_FRAME = "empty_frame"  # no returns at all
    MALFORMED = "malformed"  # not an organized frame of the expected layout, shape or stamp order


@dataclass(frozen=True)
class SegmentationResult:
    """The performer in one frame. Arrays are empty and ``mask`` all False unless the status is OK."""

    status: SegmentationStatus
    reason: str  # why there are no points; if OK empty, or a note (locked, re-acquired)
    stamp_ns: int  # the frame's header stamp
    mask: np.ndarray  # (H, W) bool, the performer's pixels
    points: np.ndarray  # (N, 3) float32 xyz in the cloud's frame, in the order of the mask's pixels (row-major)
    t_ns: np.ndarray  # (N,) uint32, ns after stamp_ns
    position: np.ndarray | None  # (2,) tracked xy of the performer (the prediction when not seen), None before the lock
    clock_step_ns: int = 0  # > 0: the frame's stamp stepped this far back (lip_ros.core.clock); the time line moved

    @property
    def mean_t_ns(self) -> int | None:
        """Mean per-point time after the stamp (ns), None without points."""
        return int(np.rint(self.t_ns.astype(np.float64).mean())) if len(self.t_ns) else None

    @property
    def pose_stamp_ns(self) -> int | None:
        """When the performer was scanned: the stamp plus the mean point time (the contract's output stamp)."""
        mean = self.mean_t_ns
        return None if mean is None else self.stamp_ns + mean


@dataclass(frozen=True)
class _Frame:
    """One validated frame: range image (m, 0 = no return) and its flat structured points."""

    points: np.ndarray  # (H * W,) structured
    range_m: np.ndarray  # (H, W) float32

    @property
    def shape(self) -> tuple[int, int]:
        return self.range_m.shape

    def xyz(self, flat: np.ndarray) -> np.ndarray:
        """(N, 3) float32 points of flat pixel indices."""
        return np.stack([self.points[c][flat] for c in "xyz"], axis=1).astype(np.float32)


@dataclass(frozen=True)
class _Candidates:
    """Returns of a window of columns, clustered: flat pixel indices, points, clusters."""

    flat: np.ndarray  # (N,)
    xyz: np.ndarray  # (N, 3) float32
    clusters: Clusters


class PerformerSegmenter:
    """Finds, locks onto and tracks the performer frame by frame (see the module docstring)."""

    def __init__(self, config: SegmentationConfig | None = None, seed: int = 0) -> None:
        """A segmenter with ``config`` (default thresholds); ``seed`` seeds the ground plane's RANSAC."""
        self.config = config or SegmentationConfig()
        self._seed = seed
        self.reset()

    def reset(self) -> None:
        """Forget everything: background, ground (unless configured), tracks and the lock."""
        cfg = self.config
        self._rng = np.random.default_rng(self._seed)
        self.ground: GroundPlane | None = (
            None if cfg.ground_plane is None else GroundPlane.from_coefficients(cfg.ground_plane)
        )
        self.background: BackgroundModel | None = None
        # the last frame's range image and performer mask, which the background learns from before the next frame
        self._to_learn: tuple[np.ndarray, np.ndarray] | None = None
        self.layout: ScanLayout | None = None  # where the rows and columns look, fitted to the first frame
        self._row_shift: np.ndarray | None = None  # a staggered cloud's rows' shifts (ScanLayout.row_shift)
        self.performer: Track | None = None
        self._others: list[Track] = []
        self._relock_tracks: list[Track] = []  # the lock rule's candidates while the performer is lost (_relock)
        self._last_stamp_ns: int | None = None
        self._period_ns = _PERIOD_NS  # the last interval between two frames (at most _PERIOD_NS)

    @property
    def level(self) -> np.ndarray | None:
        """R_L_P (3, 3): the level frame whose z is the fitted ground's normal (gravity-up; see
        :func:`lip_ros.core.frames.level_rotation`), None before the ground is known."""
        return None if self.ground is None else level_rotation(self.ground.normal)

    @property
    def row_shift(self) -> np.ndarray | None:
        """(H,) columns each row of a staggered cloud is rolled by to line up (None: the cloud is destaggered);
        :attr:`layout` is then the lined-up cloud's."""
        return self._row_shift

    @property
    def layout_description(self) -> str:
        """One line on the cloud's scan layout (:meth:`ScanLayout.describe`), and whether it was staggered."""
        if self.layout is None:
            return "not derived yet"
        if self._row_shift is None:
            return self.layout.describe()
        return (f"staggered: rows lined up by shifts of up to {np.abs(self._row_shift).max()} columns; destaggered, "
                + self.layout.describe())

    @property
    def locked(self) -> bool:
        """Whether the performer has been found (it may be LOST now)."""
        return self.performer is not None

    # ---------------------------------------------------------------- frames

    def process(self, points: np.ndarray, stamp_ns: int) -> SegmentationResult:
        """Segment one organized frame (H, W) with fields x, y, z, t, range, stamped ``stamp_ns`` (int ns).

        The background learns from the frame afterwards: in :meth:`learn`, which a live caller runs once it has
        passed the result on (about a millisecond of a 1024-column frame off its latency), or else at the start
        of the next frame; either way before the next frame, with the same results."""
        self.learn()
        shape = points.shape if isinstance(points, np.ndarray) and points.ndim == 2 else (0, 0)
        stamp = int(stamp_ns) if isinstance(stamp_ns, (int, np.integer)) and not isinstance(stamp_ns, bool) else 0
        if isinstance(points, np.ndarray) and points.size == 0:
            return self._empty(SegmentationStatus.EMPTY_FRAME, f"frame of shape {points.shape} has no points",
                               stamp, shape)
        step = stepped_back(stamp, self._last_stamp_ns) if stamp else 0
        if step:
            self._shift_time(stamp - self._last_stamp_ns)
        problem = self._malformed(points, stamp_ns)
        result = (self._empty(SegmentationStatus.MALFORMED, problem, stamp, shape) if problem
                  else self._process(points, stamp, shape))
        return replace(result, clock_step_ns=step) if step else result

    def _process(self, points: np.ndarray, stamp: int, shape: tuple[int, ...]) -> SegmentationResult:
        """Segment a well-formed frame."""
        if self.layout is None:
            self._fit_layout(points)
        if self._row_shift is not None:  # a staggered cloud: its rows lined up, and the result put back
            return self._restaggered(self._segment(destagger(points, self._row_shift), stamp, shape))
        return self._segment(points, stamp, shape)

    def learn(self) -> None:
        """Update the background with the last frame segmented (:meth:`process`), if not done yet."""
        if self._to_learn is not None:
            self.background.update(*self._to_learn)
            self._to_learn = None

    def _shift_time(self, delta_ns: int) -> None:
        """The clock stepped by ``delta_ns``: every stamp remembered moves with it, as if the frame came one frame
        after the last (the scene, the ground and the tracks stay; only their time line moves)."""
        delta_ns -= self._period_ns
        self._last_stamp_ns += delta_ns
        for track in ([self.performer] if self.performer is not None else []) + self._others + self._relock_tracks:
            track.seen_ns += delta_ns

    def _fit_layout(self, points: np.ndarray) -> None:
        """Where the rows and columns look, and (a staggered cloud) how far each row must roll to line up."""
        self.layout = fit_scan_layout(points["x"], points["y"], points["z"])
        if self.layout is not None and self.layout.row_shift.any():
            self._row_shift = self.layout.row_shift
            self.layout = fit_scan_layout(*(destagger(points[f], self._row_shift) for f in "xyz"))

    def _restaggered(self, result: SegmentationResult) -> SegmentationResult:
        """A result on the destaggered cloud in the input's pixel order (mask, and the points in its order)."""
        if not result.mask.any():
            return replace(result, mask=destagger(result.mask, -self._row_shift))
        height, width = result.mask.shape
        rows, cols = np.nonzero(result.mask)
        order = np.argsort(rows * width + (cols - self._row_shift[rows]) % width)
        return replace(result, mask=destagger(result.mask, -self._row_shift), points=result.points[order],
                       t_ns=result.t_ns[order])

    def _segment(self, points: np.ndarray, stamp: int, shape: tuple[int, ...]) -> SegmentationResult:
        """Segment a well-formed, destaggered frame."""
        frame = self._read(points)
        if not frame.range_m.any():
            return self._empty(SegmentationStatus.EMPTY_FRAME, "no returns in the frame", stamp, shape)
        if self.background is None:
            cfg = self.config
            self.background = BackgroundModel(shape, cfg.margin_m, cfg.margin_per_m, cfg.confirm_frames,
                                              cfg.absorb_frames)
        if self.ground is None:
            self.ground = self._fit_ground(frame)
        if self.ground is None:
            result = self._empty(SegmentationStatus.NO_PERFORMER, "no ground plane found yet", stamp, shape)
        elif self.layout is None:
            result = self._empty(SegmentationStatus.NO_PERFORMER, "the cloud's rows and columns fit no spinning "
                                 "LiDAR's scan yet (too few returns, or not an organized cloud)", stamp, shape)
        elif self.performer is None:
            result = self._acquire(frame, stamp)
        else:
            result = self._track(frame, stamp)
        self._to_learn = (frame.range_m, result.mask)
        if self._last_stamp_ns is not None:
            self._period_ns = min(stamp - self._last_stamp_ns, _PERIOD_NS)
        self._last_stamp_ns = stamp
        return result

    def _malformed(self, points: object, stamp_ns: object) -> str:
        """Why the input is not an organized frame of the expected layout (empty string if it is)."""
        if not isinstance(stamp_ns, (int, np.integer)) or isinstance(stamp_ns, bool):
            return f"stamp must be integer nanoseconds, not {type(stamp_ns).__name__}"
        if not isinstance(points, np.ndarray) or points.dtype.names is None:
            return "points must be a structured numpy array"
        missing = [f for f in _REQUIRED_FIELDS if f not in points.dtype.names]
        if missing:
            return f"points lack the fields {missing}"
        odd = [f for f in _REQUIRED_FIELDS if points.dtype[f].kind not in "iuf" or points.dtype[f].shape]
        if odd:
            return f"the fields {odd} are not numeric scalars"
        if points.ndim != 2:
            return f"points must be organized (H, W), got shape {points.shape}"
        if self.background is not None and points.size and points.shape != self.background.shape:
            return f"frame shape {points.shape} differs from the first frame's {self.background.shape} (reset first)"
        if self._last_stamp_ns is not None and int(stamp_ns) <= self._last_stamp_ns:
            return f"stamp {int(stamp_ns)} is not after the previous frame's {self._last_stamp_ns}"
        return ""

    @staticmethod
    def _read(points: np.ndarray) -> _Frame:
        """Range image (m; 0 where there is no return) and the flat points."""
        range_m = points["range"].astype(np.float32)
        range_m *= np.float32(1e-3)
        return _Frame(points.reshape(-1), range_m)

    def _fit_ground(self, frame: _Frame) -> GroundPlane | None:
        """The ground plane of a frame's returns (at most about 20000 of them), or None."""
        cfg = self.config
        flat = np.flatnonzero(frame.range_m)
        return fit_ground_plane(frame.xyz(flat[::max(len(flat) // 20000, 1)]), cfg.ground_tolerance_m,
                                cfg.ground_max_tilt_deg, cfg.ground_min_points, self._rng)

    def _empty(self, status: SegmentationStatus, reason: str, stamp: int, shape: tuple[int, ...]) -> SegmentationResult:
        """A result without the performer."""
        position = None if self.performer is None else self.performer.predict(stamp, self.config.horizon_s)
        return SegmentationResult(status, reason, stamp, np.zeros(shape, dtype=bool), np.zeros((0, 3), np.float32),
                                  np.zeros(0, np.uint32), position)

    def _found(self, frame: _Frame, stamp: int, cand: _Candidates, selected: np.ndarray,
               reason: str = "") -> SegmentationResult:
        """The OK result of the points ``selected`` (bool over ``cand``'s points), in the mask's pixel order."""
        index = np.flatnonzero(selected)
        index = index[np.argsort(cand.flat[index])]
        flat = cand.flat[index]
        mask = np.zeros(frame.shape, dtype=bool)
        mask.reshape(-1)[flat] = True
        return SegmentationResult(SegmentationStatus.OK, reason, stamp, mask, cand.xyz[index],
                                  frame.points["t"][flat].astype(np.uint32), self.performer.position.copy())

    # ------------------------------------------------------------ clustering

    def _cluster(self, frame: _Frame, cols: np.ndarray | None, keep: np.ndarray,
                 near_ground_ok: np.ndarray) -> _Candidates:
        """Cluster returns ``keep`` (H, C) of the columns ``cols`` (None: all, wrapping) that lie above the ground
        or are ``near_ground_ok`` (H, C)."""
        height, width = frame.shape
        rows, sub = np.nonzero(keep)
        flat = rows * width + (sub if cols is None else cols[sub])
        xyz = frame.xyz(flat)
        above = self.ground.height(xyz) > self.config.ground_tolerance_m
        ok = (above | near_ground_ok[rows, sub]) & np.isfinite(xyz).all(axis=1)
        rows, sub, flat, xyz = rows[ok], sub[ok], flat[ok], xyz[ok]
        cfg = self.config
        grid = (height, width if cols is None else len(cols))
        angles = (self.layout.row_spacing_rad, 2.0 * np.pi / width)
        labels, k = link_components(rows, sub, xyz, frame.range_m.reshape(-1)[flat], grid, cols is None, angles,
                                    cfg.link_m, cfg.link_spacing, cfg.link_reach)
        clusters = describe_clusters(labels, k, xyz, self.ground.height(xyz))
        cut = self._cut_below(frame, rows, flat % width, labels, k)
        return _Candidates(flat, xyz, replace(clusters, cut_below=cut))

    def _cut_below(self, frame: _Frame, rows: np.ndarray, cols: np.ndarray, labels: np.ndarray, k: int
                   ) -> np.ndarray:
        """(K,) bool: clusters whose lower edge is hidden: below most of their lowest returns (those in the
        cluster's lowest two rows, one per column) the next row returns from something nearer that is not the
        ground (an occluder in front: a wall, a table), or there is no next row (the bottom of the field of
        view)."""
        if k == 0:
            return np.zeros(0, dtype=bool)
        height, width = frame.shape
        down = self.layout.row_down  # from the rows' fitted elevations, not from a row order taken for granted
        depth = rows if down > 0 else height - 1 - rows  # 0 for the highest row, growing downwards
        lowest = np.lexsort((-depth, labels * width + cols))  # per (cluster, column): the lowest pixel first
        key = (labels * width + cols)[lowest]
        low = lowest[np.concatenate([[True], key[1:] != key[:-1]])]
        bottom = np.zeros(k, dtype=np.int64)
        np.maximum.at(bottom, labels, depth)
        low = low[depth[low] >= bottom[labels[low]] - 1]  # the cluster's lower edge, not an arm's
        edge = depth[low] + 1 >= height
        below = np.clip(rows[low] + down, 0, height - 1)
        own = frame.range_m[rows[low], cols[low]]
        nearer = frame.range_m[below, cols[low]]
        cfg = self.config
        front = (nearer > 0.0) & (nearer < own - cfg.margin_m - cfg.margin_per_m * own)
        if front.any():
            xyz = frame.xyz(below[front] * width + cols[low][front])
            front[front] = self.ground.height(xyz) > cfg.occluder_min_height_m  # not the ground before the feet
        hidden = np.bincount(labels[low], edge | front, minlength=k)
        return hidden > 0.5 * np.bincount(labels[low], minlength=k)

    def _human_sized(self, c: Clusters) -> np.ndarray:
        """(K,) bool: clusters the size and shape of a person standing on the ground; one whose lower edge is
        hidden (behind a wall, below the field of view) may end higher than ``max_bottom_m``."""
        cfg = self.config
        grounded = c.bottom <= cfg.max_bottom_m
        if cfg.hidden_feet and c.cut_below is not None:
            grounded |= c.cut_below
        return ((c.count >= cfg.min_points) & (c.top >= cfg.min_top_m) & (c.top <= cfg.max_top_m)
                & grounded & (c.width <= cfg.max_width_m) & (c.depth <= cfg.max_depth_m))

    # ------------------------------------------------------------------ lock

    def _acquire(self, frame: _Frame, stamp: int, resume: bool = True) -> SegmentationResult:
        """Before the lock: track the human-sized clusters of all returns above the ground; lock by the rule
        (``resume``: also onto anyone near ``resume_xy``)."""
        cfg = self.config
        valid = frame.range_m > 0.0
        cand = self._cluster(frame, None, valid, np.zeros_like(valid))
        c = cand.clusters
        humans = self._human_sized(c)
        predicted = np.array([t.predict(stamp, cfg.horizon_s) for t in self._others]).reshape(-1, 2)
        match = associate(predicted, np.full(len(self._others), cfg.other_gate_m), c.centroid,
                          np.tile(humans, (len(self._others), 1)))
        seen = self._update_others(match, c, stamp, spawn=np.flatnonzero(humans))
        chosen = self._lock_choice(seen, resume)
        if chosen is None:
            return self._empty(SegmentationStatus.NO_PERFORMER, f"not locked yet: {self._lock_wait()}", stamp,
                               frame.shape)
        track, k = chosen
        self.performer = track
        self._others = [t for t in self._others if t is not track]
        taken = np.zeros(len(c), dtype=bool)
        taken[[j for t, j in seen if t is not track]] = True
        selected = self._with_fragments(c, k, taken)
        result = self._found(frame, stamp, cand, selected[c.labels],
                             f"locked onto the performer at ({track.position[0]:.2f}, {track.position[1]:.2f}) m")
        self._forget_under(frame, result, float(max(c.left[k], c.right[k])))
        return result

    def _forget_under(self, frame: _Frame, result: SegmentationResult, half_width: float) -> None:
        """Forget the background the still performer left before the lock: in the rows and columns around its
        pixels (``half_width`` to either side; arms moved out of the A-pose) where it is not farther than the
        performer."""
        rows = np.flatnonzero(result.mask.any(axis=1))
        box = np.zeros(frame.shape, dtype=bool)
        cols = self.layout.window(result.position, half_width + 0.3)
        box[max(rows[0] - 2, 0):rows[-1] + 3, slice(None) if cols is None else cols] = True
        reach = frame.range_m[result.mask].max() + self.config.link_m
        self.background.forget((box & (self.background.range < reach)) | result.mask)

    def _lock_wait(self) -> str:
        """What the lock rule is waiting for."""
        cfg = self.config
        where = "" if cfg.expected_xy is None else f" within {cfg.expected_radius_m} m of {cfg.expected_xy}"
        near = "" if cfg.resume_xy is None else (
            f"none within {cfg.resume_radius_m} m of the last position {tuple(round(v, 2) for v in cfg.resume_xy)}, ")
        if cfg.lock_rule == "t_pose":
            return f"{near}no human-sized cluster{where} has stood still and spread its arms (T-pose)"
        return f"{near}no human-sized cluster{where} has stood still for {cfg.lock_frames} frames"

    def _lock_choice(self, seen: list[tuple[Track, int]], resume: bool = True) -> tuple[Track, int] | None:
        """The candidate (track, its cluster) seen in this frame that the lock rule picks, if any."""
        cfg = self.config
        best, best_score = None, np.inf
        for track, k in seen:
            if cfg.resume_xy is not None and resume:
                away = float(np.linalg.norm(track.position - np.asarray(cfg.resume_xy)))
                if away <= cfg.resume_radius_m:  # resuming: any pose, before any candidate of the rule
                    if away - 1e6 < best_score:
                        best, best_score = (track, k), away - 1e6
                    continue
            if track.stay_frames < cfg.lock_frames:
                continue
            score = -float(track.widest.sum())
            if cfg.expected_xy is not None:
                score = float(np.linalg.norm(track.position - np.asarray(cfg.expected_xy)))
                if score > cfg.expected_radius_m:
                    continue
            if cfg.lock_rule == "t_pose" and (track.widest.sum() < cfg.t_pose_width_m
                                              or track.spread.min() < cfg.t_pose_side_m):
                continue
            if score < best_score:
                best, best_score = (track, k), score
        return best

    # -------------------------------------------------------------- tracking

    def _update_others(self, match: np.ndarray, c: Clusters, stamp: int, spawn: np.ndarray) -> list[tuple[Track, int]]:
        """Update the bystander tracks with their clusters ``match`` (one per track), drop the stale ones, start
        tracks on the unmatched ``spawn`` clusters away from every track (not a piece of someone tracked); returns
        the (track, cluster) pairs seen in this frame."""
        cfg = self.config
        seen = []
        for track, k in zip(self._others, match):
            if k >= 0:
                track.observe(c.centroid[k], c.left[k], c.right[k], stamp, cfg.velocity_gain)
                seen.append((track, int(k)))
        self._others = [t for t in self._others if t.unseen_s(stamp) <= cfg.other_timeout_s]
        anchors = [t.position for t in self._others]
        if self.performer is not None:
            anchors.append(self.performer.predict(stamp, cfg.horizon_s))
        for k in np.setdiff1d(spawn, match):
            if all(np.linalg.norm(c.centroid[k] - a) > cfg.other_gate_m for a in anchors):
                self._others.append(Track.start(c.centroid[k], c.left[k], c.right[k], stamp, cfg.still_m))
                seen.append((self._others[-1], int(k)))
                anchors.append(c.centroid[k])
        return seen

    def _with_fragments(self, c: Clusters, main: int, taken: np.ndarray) -> np.ndarray:
        """(K,) bool: cluster ``main`` and the clusters near it that are not ``taken`` (e.g. a limb split off at
        long range, or the performer's parts on either side of someone in front)."""
        selected = (np.linalg.norm(c.centroid - c.centroid[main], axis=1) <= self.config.fragment_m) & ~taken
        selected[main] = True
        return selected

    def _relock(self, frame: _Frame, stamp: int) -> SegmentationResult | None:
        """Lost for ``relock_after_s``: the lock rule over the whole frame (tracks of its own), as before the first
        lock; the result if it locked onto someone (the new performer, wherever they are), else None."""
        lost, others = self.performer, self._others
        self.performer, self._others = None, self._relock_tracks
        try:
            result = self._acquire(frame, stamp, resume=False)
        finally:
            locked = self.performer
            self._relock_tracks = [] if locked else self._others
            self.performer, self._others = locked or lost, [] if locked else others
        if locked is None:
            return None
        return replace(result, reason=f"lost for {lost.unseen_s(stamp):.1f} s, then {result.reason}")

    def _track(self, frame: _Frame, stamp: int) -> SegmentationResult:
        """After the lock: cluster the foreground around the prediction, assign performer and bystanders."""
        cfg = self.config
        performer = self.performer
        unseen = performer.unseen_s(stamp)
        lost = unseen >= cfg.lost_after_s
        if unseen >= cfg.relock_after_s and (relocked := self._relock(frame, stamp)) is not None:
            return relocked
        if not lost:
            self._relock_tracks = []
        gate = min(cfg.gate_m + cfg.gate_growth_mps * unseen, cfg.reacquire_m)
        tracks = [performer, *self._others]
        predicted = np.array([t.predict(stamp, cfg.horizon_s) for t in tracks])
        cols = self.layout.window(predicted[0], max(cfg.window_m, gate + cfg.fragment_m))
        range_m = frame.range_m if cols is None else frame.range_m[:, cols]
        nearer, unexplained = self.background.classify(range_m, slice(None) if cols is None else cols)
        cand = self._cluster(frame, cols, nearer | unexplained, nearer)
        c = cand.clusters
        humans = self._human_sized(c)
        big = (c.count >= cfg.min_track_points) & (c.width <= cfg.max_width_m) & (c.depth <= cfg.max_depth_m)
        # the performer is row 0; missed in the previous frame, it must be re-found as a whole person
        allowed = np.tile(big, (len(tracks), 1))
        if performer.seen_ns != self._last_stamp_ns:
            allowed[0] &= humans
        gates = np.array([gate] + [cfg.other_gate_m] * len(self._others))
        match = associate(predicted, gates, c.centroid, allowed)
        taken = np.zeros(len(c), dtype=bool)
        taken[match[match >= 0]] = True
        selected = np.zeros(len(c), dtype=bool) if match[0] < 0 else self._with_fragments(c, int(match[0]), taken)
        shared = selected.copy()
        if performer.seen_ns == self._last_stamp_ns:  # not while coasting: the prediction may have drifted
            shared |= taken & (np.linalg.norm(c.centroid - predicted[0], axis=1) <= gate + cfg.fragment_m)
        points = self._split_merged(cand, shared, predicted, match[1:], stamp)
        self._update_others(match[1:], c, stamp, spawn=np.flatnonzero(humans & ~selected & ~taken))
        if points.sum() < cfg.min_track_points:
            where = f"({performer.position[0]:.2f}, {performer.position[1]:.2f})"
            if lost:
                return self._empty(SegmentationStatus.LOST, f"performer not seen for {unseen:.1f} s; re-acquiring "
                                   f"within {gate:.1f} m of {where}", stamp, frame.shape)
            return self._empty(SegmentationStatus.NO_PERFORMER, f"performer not found within {gate:.1f} m of its "
                               f"prediction (last seen {unseen:.1f} s ago at {where})", stamp, frame.shape)
        self._observe_points(performer, cand.xyz[points], stamp)
        return self._found(frame, stamp, cand, points, "re-acquired the performer" if lost else "")

    def _split_merged(self, cand: _Candidates, shared: np.ndarray, predicted: np.ndarray, match: np.ndarray,
                      stamp: int) -> np.ndarray:
        """(N,) bool, the performer's points: those of the ``shared`` clusters (K,) nearer to the performer's
        prediction (``predicted`` row 0) than to any bystander's (rows 1..). People who touch merge into one
        cluster; a bystander without a cluster of its own (``match`` -1) is seen at its share."""
        idx = np.flatnonzero(shared[cand.clusters.labels])
        owner = np.argmin(np.linalg.norm(cand.xyz[idx, None, :2] - predicted[None, :, :], axis=2), axis=1)
        points = np.zeros(len(cand.flat), dtype=bool)
        points[idx[owner == 0]] = True
        for k in np.flatnonzero(match < 0):
            self._observe_points(self._others[k], cand.xyz[idx[owner == k + 1]], stamp)
        return points

    def _observe_points(self, track: Track, xyz: np.ndarray, stamp: int) -> None:
        """Update ``track`` with the outline of points ``xyz`` (N, 3), if there are at least ``min_track_points``."""
        if len(xyz) >= self.config.min_track_points:
            c = describe_clusters(np.zeros(len(xyz), dtype=np.int64), 1, xyz, np.zeros(len(xyz), dtype=np.float32))
            track.observe(c.centroid[0], c.left[0], c.right[0], stamp, self.config.velocity_gain)
