"""Scene-aware joint optimisation of the fused body over windows of frames (the paper's section 4.5; the one HSC4D
module that imports torch), ROS-free.

Given per frame the fused pelvis pose (translation ``t0``, rotation ``R0``), each leg's joint rotations as the
suit puts them and its bones (the hip, knee and ankle: :func:`~lip_ros.hsc4d.suit_body.leg_chains`), which foot
stands (from the suit's own foot motion, :func:`stance_from_suit`) and the LiDAR map's points,
:func:`optimise_window` moves the pelvis translation, turns the whole body about the pelvis (a small rotation per
frame) and turns each leg's hip, knee and ankle (the paper optimises the pose theta as well as the translation) to
minimise

* **contact**: each stance's mean height of the foot above the ground plane under it, less the sole's height (the
  ground: a plane fitted by RANSAC to the map's points within ``radius_m`` of the foot and from ``below_m`` under
  it to ``above_m`` over it, per stance, since the point cloud has holes; the band keeps the next tread of a
  stair out; the foot joint stands ``sole_m`` above its sole, measured on the still start; the mean over a
  stance, since the joint rises and falls as the foot rolls);
* **sliding**: a standing foot's motion from one frame to the next, while it stands in both; its square up to
  ``sliding_huber_m``, growing linearly beyond (a Huber loss): the suit calls a foot standing at a stance's edges
  while it already lifts (the suit's own foot up to the stance speed's 7 cm a frame at 10 Hz, the fused one
  further), and such a step must not drag the body with a force that grows with it;
* **orientation**: the body's turn away from the fused rotation (the landmarks; the suit's rotation) and its
  change from frame to frame (as smooth as the suit's);
* **smoothness**: the pelvis's horizontal step from frame to frame against the suit's (the paper's: move as smoothly
  as the suit; horizontal, since the suit's odometry knows no stairs and no jumps; the suit's steps scaled by the
  window's path over theirs, since its stride scale is off by a few per cent);
* **prior**: the translation's distance from the fused one (the landmarks' hold on the window);
* **pose**: the legs' joints' turn away from the suit's rotations and its change from frame to frame (the pose
  prior: the suit measures every leg segment; a stance's edges, where the foot rolls, and the suit's own errors
  are where the feet slide).

Each term is a mean over the window, weighted (:class:`SceneOptimisationConfig`); a weight of zero drops the term
(the ablation; without the pose prior the legs are free). The rest of the body keeps the suit's joint rotations:
the scene has nothing to say about it. L-BFGS in double precision solves a window of 100 frames in well under a
second.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import torch

from lip_ros.core.ground_plane import GroundPlane, fit_ground_plane
from lip_ros.core.torch_kinematics import axis_angle_to_matrix
from lip_ros.hsc4d.leg_scale import LegScale, LegScaleConfig, standing_steps

__all__ = ["SceneOptimisationConfig", "WindowInput", "WindowResult", "TERMS", "stance_from_suit",
           "fit_foot_planes", "leg_offsets", "feet_offsets", "optimise_window", "without", "SequenceResult",
           "sole_height", "SceneOptimiser", "optimise_sequence", "walk_leg_ratio", "MAX_WAIT_WINDOWS", "NoGroundYet"]

#: the loss terms, in report order
TERMS = ("contact", "sliding", "orientation", "smoothness", "prior", "pose")


#: the bound on the frames waiting for the first window's ground, in windows
MAX_WAIT_WINDOWS = 4


class NoGroundYet(ValueError):
    """The sole height is still unknown and no standing foot of the first window has the ground mapped under it:
    its frames wait for a later map."""


@dataclass(frozen=True)
class SceneOptimisationConfig:
    """Window length, the ground search round each foot and the terms' weights (the paper's l = 100, r = 0.6 m)."""

    window: int = 100  # frames per optimisation window
    radius_m: float = 0.6  # map points within this horizontal distance of a standing foot give its ground plane
    above_m: float = 0.05  # ... from this far above the foot joint (a riser is 10-18 cm: the next tread is out)
    below_m: float = 0.2  # ... to this far below it (the sole is a few cm; the tread below is out)
    plane_tolerance_m: float = 0.03  # RANSAC inlier distance
    plane_max_tilt_deg: float = 20.0  # steeper is not ground (ramps are up to 12 deg)
    plane_min_points: int = 8
    # the sole height takes only planes with plane_min_points inliers within this horizontal distance of the foot:
    # the ground measured under it, not extrapolated from the search disc's edge (an early map's arc of points half
    # a metre off, tilted up to 15 deg, put the first window's sole 2-5 cm off; contact keeps every plane:
    # with this rule for it too the 10-20 deg mounting variant lost planes that helped; docs/hsc4d/optimisation.md)
    support_radius_m: float = 0.25
    # a foot slower than this (and than the other) stands: the paper's 2 cm a frame at 20 Hz is 0.4 m/s; from the
    # suit's feet that missed the edges of the true stances (sliding 0.91 against 0.86 cm a frame on the development
    # captures, docs/hsc4d/optimisation.md)
    stance_speed_mps: float = 0.7
    contact_huber_m: float = 0.02  # the contact residual is quadratic below this, linear above (a wrong plane)
    # a standing foot's step is quadratic below this, linear above (a foot the suit calls standing as it lifts):
    # the bound on sliding, 1 cm a frame; a step beyond it is not a standing foot's
    sliding_huber_m: float = 0.01
    contact: float = 1.0  # weights: per m^2 of the mean squared (Huber) residual (3 cost 0.1 cm vertical) ...
    sliding: float = 3.0  # ... per m^2 of a standing foot's step (up to sliding_huber_m)
    orientation: float = 1.0  # ... per rad^2 of the turn away from the fused rotation and of its change
    smoothness: float = 1.0  # ... per m^2 of a frame's horizontal step length off the suit's
    prior: float = 1.0  # ... per m^2 of the translation's distance from the fused one
    # ... per rad^2 of the legs' six joints' summed squared turn from the suit's and of its change; chosen on the
    # development captures (docs/hsc4d/optimisation.md): 1 took out half as much sliding, 0.1 cost MPJPE
    pose: float = 0.3
    iterations: int = 60  # L-BFGS iterations per window
    # the legs' length from the walk (leg_scale.py): each window's bones times the ratio of the standing pelvis's
    # steps to the legs' over the windows so far (the bones as given until it is believed); False: as given
    legs_from_walk: bool = True
    # the first window waits for a map that shows the ground under its feet (mapped once the wearer walked away from
    # the start) for a window more, or this long if that is more (two 100-frame windows are 10 s at 20 Hz: the
    # wearer had not walked off the start's ground by then), up to four windows
    max_wait_s: float = 20.0

    def __post_init__(self) -> None:
        if not (self.window >= 3 and 0.0 < self.support_radius_m <= self.radius_m and self.above_m >= 0.0
                and self.below_m > 0.0 and self.plane_tolerance_m > 0.0 and 0.0 < self.plane_max_tilt_deg < 90.0
                and self.plane_min_points >= 3 and self.stance_speed_mps > 0.0 and self.contact_huber_m > 0.0
                and self.sliding_huber_m > 0.0
                and all(getattr(self, t) >= 0.0 for t in TERMS) and self.iterations > 0 and self.max_wait_s >= 0.0):
            raise ValueError(f"invalid {self}")


def without(config: SceneOptimisationConfig, term: str) -> SceneOptimisationConfig:
    """``config`` with the weight of ``term`` (one of :data:`TERMS`) set to zero."""
    if term not in TERMS:
        raise ValueError(f"unknown term {term!r}; one of {TERMS}")
    return replace(config, **{term: 0.0})


@dataclass(frozen=True)
class WindowInput:
    """One window of N frames: the fused pelvis translations ``t0`` (N, 3) and rotations ``R0`` (N, 3, 3) in
    ``map``, each leg's (left, right) hip, knee and ankle local rotations as the suit gives them (N, 2, 3, 3, 3) and
    its bones (N, 2, 4, 3; :func:`~lip_ros.hsc4d.suit_body.leg_chains`), which foot stands (N, 2)
    and the ground plane under it (N, 2, 4: unit normal and offset, ``n . p + d = 0``; NaN where none), the suit's
    pelvis horizontal step length into each frame (N,; the first is used only with ``before``); ``before``:
    the previous window's last frame as optimised (its translation (3,) and feet (2, 3)), or None."""

    t0: np.ndarray
    R0: np.ndarray
    legs: np.ndarray
    bones: np.ndarray
    stance: np.ndarray
    planes: np.ndarray
    suit_steps: np.ndarray
    before: tuple[np.ndarray, np.ndarray] | None = None


@dataclass(frozen=True)
class WindowResult:
    """The optimised pelvis translations (N, 3) and rotations (N, 3, 3), the legs' local rotations (N, 2, 3, 3, 3),
    the feet (N, 2, 3), each term's value before and after (unweighted), and the legs' length over the bones'
    given (:class:`SceneOptimiser`): the body's size to pose it with, times the given one."""

    t: np.ndarray
    R: np.ndarray
    legs: np.ndarray
    feet: np.ndarray
    before: dict[str, float]
    after: dict[str, float]
    leg_ratio: float = 1.0


def stance_from_suit(feet: np.ndarray, t_s: np.ndarray, speed_mps: float) -> np.ndarray:
    """(N, 2) bool, which foot stands at each of N frames: the slower of the two, if slower than ``speed_mps``,
    from the feet (N, 2, 3) as the suit alone places them (its own odometry and joints, where a standing foot is
    still) at times ``t_s`` (N,); central differences."""
    n = len(t_s)
    out = np.zeros((n, 2), dtype=bool)
    if n < 2:
        return out
    speed = np.linalg.norm(np.gradient(feet, t_s, axis=0), axis=2)  # (N, 2)
    slower = np.argmin(speed, axis=1)
    rows = np.arange(n)
    out[rows, slower] = speed[rows, slower] < speed_mps
    return out


def fit_foot_planes(feet: np.ndarray, stance: np.ndarray, points: np.ndarray, rng: np.random.Generator,
                    config: SceneOptimisationConfig) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2, 4) the ground plane under each standing foot (NaN where none is found or the foot does not stand)
    and (N, 2) whether it is measured under the foot (``plane_min_points`` of its inliers within ``support_radius_m``
    of it, not all at the search disc's edge):
    one plane per stance (a run of frames the same foot stands), fitted to the map's ``points`` (M, 3) within
    ``radius_m`` of the stance's median foot position, from ``above_m`` over it to ``below_m`` under it."""
    c = config
    out = np.full(stance.shape + (4,), np.nan)
    supported = np.zeros(stance.shape, dtype=bool)
    if not stance.any():
        return out, supported
    standing = feet[stance]  # (K, 3): the map's points near none of them are not looked at again per stance
    lo, hi = standing[:, :2].min(axis=0) - c.radius_m, standing[:, :2].max(axis=0) + c.radius_m
    points = points[((points[:, :2] >= lo) & (points[:, :2] <= hi)).all(axis=1)]
    for foot in range(2):
        runs = np.flatnonzero(np.diff(np.concatenate([[0], stance[:, foot].astype(np.int8), [0]])))
        for start, stop in zip(runs[::2], runs[1::2], strict=True):
            centre = np.median(feet[start:stop, foot], axis=0)
            near = points[np.hypot(points[:, 0] - centre[0], points[:, 1] - centre[1]) <= c.radius_m]
            local = near - (centre + [0.0, 0.0, c.above_m])  # the plane search wants the ground below the origin
            local = local[local[:, 2] >= -(c.above_m + c.below_m)]
            plane = fit_ground_plane(local, c.plane_tolerance_m, c.plane_max_tilt_deg, c.plane_min_points, rng)
            if plane is not None:
                origin = centre + [0.0, 0.0, c.above_m]
                out[start:stop, foot] = [*plane.normal, plane.offset - plane.normal @ origin]
                supported[start:stop, foot] = _supported(plane, local, c)
    return out, supported


def _supported(plane: GroundPlane, local: np.ndarray, c: SceneOptimisationConfig) -> bool:
    """Whether ``plane`` has ``plane_min_points`` inliers among ``local`` (M, 3; the foot at the origin's x, y)
    within ``support_radius_m`` of the foot horizontally."""
    near = local[np.hypot(local[:, 0], local[:, 1]) <= c.support_radius_m]
    return int((np.abs(plane.height(near)) < c.plane_tolerance_m).sum()) >= c.plane_min_points


def leg_offsets(R0: torch.Tensor, legs: torch.Tensor, bones: torch.Tensor, turns: torch.Tensor) -> torch.Tensor:
    """(N, 2, 3) each foot joint's offset from the pelvis: the pelvis rotations ``R0`` (N, 3, 3), the legs' local
    rotations ``legs`` (N, 2, 3, 3, 3) each turned by ``turns`` (N, 2, 3, 3: axis-angle, before it) and the bones
    (N, 2, 4, 3)."""
    n = len(R0)
    glob = R0[:, None].expand(n, 2, 3, 3)
    offset = torch.einsum("nkab,nkb->nka", glob, bones[:, :, 0])
    for j in range(3):
        glob = glob @ axis_angle_to_matrix(turns[:, :, j].reshape(-1, 3)).view(n, 2, 3, 3) @ legs[:, :, j]
        offset = offset + torch.einsum("nkab,nkb->nka", glob, bones[:, :, j + 1])
    return offset


def feet_offsets(R0: np.ndarray, legs: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """(N, 2, 3) each foot joint's offset from the pelvis as the legs stand (:func:`leg_offsets`, not turned)."""
    with torch.no_grad():
        R0_, legs_, bones_ = (torch.as_tensor(a, dtype=torch.float64) for a in (R0, legs, bones))
        return leg_offsets(R0_, legs_, bones_, torch.zeros(legs_.shape[:3] + (3,), dtype=torch.float64)).numpy()


def _step_mean(x: torch.Tensor) -> torch.Tensor:
    """The mean squared change of ``x`` (N, ...) from one frame to the next, summed over its other dimensions."""
    return ((x[1:] - x[:-1]) ** 2).flatten(1).sum(-1).mean() if len(x) > 1 else x.new_zeros(())


def _huber_square(steps: torch.Tensor, delta: float) -> torch.Tensor:
    """Each step's (M, 3) squared length up to ``delta``, ``2 delta |step| - delta^2`` beyond it (M,): a Huber
    loss, twice torch's, so that a step within ``delta`` weighs as its square."""
    square = (steps**2).sum(-1)
    length = torch.sqrt(square.clamp_min(delta**2))  # no square root of zero: its gradient is not finite
    return torch.where(square < delta**2, square, 2.0 * delta * length - delta**2)


def _terms(t: torch.Tensor, rot: torch.Tensor, turns: torch.Tensor, window: WindowInput, sole_m: float,
           c: SceneOptimisationConfig, fixed: dict[str, torch.Tensor]) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """Each term's value (unweighted) and the feet (N, 2, 3) for translations ``t`` (N, 3), body turns ``rot``
    (axis-angle, N, 3) and the legs' joints' turns ``turns`` (N, 2, 3, 3); ``fixed``: the window's tensors."""
    offsets = leg_offsets(fixed["R0"], fixed["legs"], fixed["bones"], turns)
    feet = t[:, None, :] + torch.einsum("nab,nkb->nka", axis_angle_to_matrix(rot), offsets)  # (N, 2, 3)
    zero = t.new_zeros(())
    runs, planes, stance = fixed["runs"], fixed["planes"], fixed["stance"]
    has_plane = runs >= 0
    if has_plane.any():
        p = planes[has_plane]
        height = (p[:, :3] * feet[has_plane]).sum(-1) + p[:, 3] - sole_m
        ids = runs[has_plane]
        count = torch.zeros(int(ids.max()) + 1, dtype=t.dtype).index_add_(0, ids, torch.ones_like(height))
        mean = torch.zeros_like(count).index_add_(0, ids, height)[count > 0] / count[count > 0]
        contact = torch.nn.functional.huber_loss(mean, torch.zeros_like(mean), delta=c.contact_huber_m)
    else:
        contact = zero
    all_t, all_feet, all_stance = t, feet, stance
    if window.before is not None:
        t_b, feet_b = (torch.as_tensor(a, dtype=t.dtype) for a in window.before)
        all_t, all_feet = torch.cat([t_b[None], t]), torch.cat([feet_b[None], feet])
        all_stance = torch.cat([stance[:1], stance])  # the frame before counts as standing as the first does
    both = all_stance[1:] & all_stance[:-1]
    sliding = _huber_square((all_feet[1:] - all_feet[:-1])[both], c.sliding_huber_m).mean() if both.any() else zero
    orientation = (rot**2).sum(-1).mean() + _step_mean(rot)
    steps = torch.linalg.norm(all_t[1:, :2] - all_t[:-1, :2], dim=-1)  # horizontal: the suit knows no heights
    suit = torch.as_tensor(window.suit_steps[-len(steps):], dtype=t.dtype) if len(steps) else steps
    smoothness = ((steps - suit) ** 2).mean() if len(steps) else zero
    prior = ((t - fixed["t0"]) ** 2).sum(-1).mean()
    pose = (turns**2).flatten(1).sum(-1).mean() + _step_mean(turns)
    return {"contact": contact, "sliding": sliding, "orientation": orientation, "smoothness": smoothness,
            "prior": prior, "pose": pose}, feet


def stance_runs(stance: np.ndarray) -> np.ndarray:
    """(N, 2) int64: which run of consecutive standing frames of the same foot each frame is in (numbered from 0
    across both feet), -1 where the foot does not stand."""
    out = np.full(stance.shape, -1, dtype=np.int64)
    n = 0
    for foot in range(stance.shape[1]):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], stance[:, foot].astype(np.int8), [0]])))
        for start, stop in zip(edges[::2], edges[1::2], strict=True):
            out[start:stop, foot] = n
            n += 1
    return out


def optimise_window(window: WindowInput, sole_m: float, config: SceneOptimisationConfig | None = None
                    ) -> WindowResult:
    """Optimise one window (module docstring); ``sole_m``: how far the foot joint stands above its sole."""
    c = config or SceneOptimisationConfig()
    dtype = torch.float64
    fixed = {name: torch.as_tensor(getattr(window, name), dtype=dtype) for name in ("t0", "R0", "legs", "bones",
                                                                                    "planes")}
    fixed["stance"] = torch.as_tensor(window.stance, dtype=torch.bool)
    fixed["runs"] = torch.as_tensor(stance_runs(window.stance & np.isfinite(window.planes).all(-1)))
    t = fixed["t0"].clone().requires_grad_(True)
    rot = torch.zeros_like(t).requires_grad_(True)
    turns = torch.zeros(window.legs.shape[:3] + (3,), dtype=dtype, requires_grad=True)
    weights = {name: getattr(c, name) for name in TERMS}

    def evaluate() -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        return _terms(t, rot, turns, window, sole_m, c, fixed)

    with torch.no_grad():
        before = {k: float(v) for k, v in evaluate()[0].items()}
    optimiser = torch.optim.LBFGS([t, rot, turns], lr=1.0, max_iter=c.iterations, line_search_fn="strong_wolfe",
                                  tolerance_grad=1e-12, tolerance_change=1e-14)

    def closure() -> torch.Tensor:
        optimiser.zero_grad()
        terms = evaluate()[0]
        loss = sum(weights[k] * terms[k] for k in TERMS)
        loss.backward()
        return loss

    optimiser.step(closure)
    with torch.no_grad():
        terms, feet = evaluate()
        after = {k: float(v) for k, v in terms.items()}
        n = len(t)
        legs = (axis_angle_to_matrix(turns.reshape(-1, 3)).view(n, 2, 3, 3, 3) @ fixed["legs"]).numpy()
        R_turn = axis_angle_to_matrix(rot).numpy()
    return WindowResult(t.detach().numpy().copy(), R_turn @ window.R0, legs, feet.numpy(), before, after)


@dataclass(frozen=True)
class SequenceResult:
    """A whole sequence optimised window by window: pelvis poses T_map_P (N, 4, 4), the legs' local rotations
    (N, 2, 3, 3, 3), feet (N, 2, 3), which foot stood (N, 2), the planes found (N, 2, 4), the sole height (m)
    and each window's terms before and after; the legs' length over the bones' given, per frame. Each window used
    the sole height at its own legs' length; ``sole_m`` is the one at the last window's."""

    pelvis: np.ndarray
    legs: np.ndarray
    feet: np.ndarray
    stance: np.ndarray
    planes: np.ndarray
    sole_m: float
    windows: list[WindowResult]
    leg_ratio: np.ndarray  #: (N,) each frame's :attr:`WindowResult.leg_ratio` (1 where left as fused)
    #: (N,) :attr:`SceneOptimiser.leg_ratio` as each frame came, after the windows solved before it: the size a live
    #: body node gives its fused body at that frame (less the time a window takes to solve)
    arrival_leg_ratio: np.ndarray


def sole_height(feet: np.ndarray, stance: np.ndarray, planes: np.ndarray) -> float:
    """The foot joint's height above its sole: the median height of the standing feet (N, 2, 3) above their planes
    (N, 2, 4) (of the first window: the still start and what follows it, before the fused height can drift); NaN
    without any."""
    ok = stance & np.isfinite(planes).all(-1)
    if not ok.any():
        return float("nan")
    return float(np.median(np.einsum("ka,ka->k", planes[ok][:, :3], feet[ok]) + planes[ok][:, 3]))


class SceneOptimiser:
    """The optimisation live: frames go in one at a time (:meth:`add`); once a window is :attr:`full`,
    :meth:`optimise` solves its oldest window on the map as it stands then, continuing from the window before.
    The sole height is measured in the first window optimised (from the still start; :func:`sole_height`) unless
    given; until a map shows the ground under that window's feet, its frames wait (up to :attr:`capacity`: then
    the oldest window must be :meth:`drop` ped). The legs' length over the bones given (:attr:`leg_ratio`): given,
    or from the walk of the windows optimised so far (``legs_from_walk``, :mod:`~lip_ros.hsc4d.leg_scale`); a
    measured sole height follows it, since the first window's pelvis height above its ground is what was seen (the
    legs' length and the sole share it)."""

    def __init__(self, config: SceneOptimisationConfig | None = None, sole_m: float | None = None,
                 seed: int = 0, leg_ratio: float | None = None) -> None:
        if leg_ratio is not None and not (np.isfinite(leg_ratio) and leg_ratio > 0.0):
            raise ValueError(f"the legs' length over the bones' must be > 0, got {leg_ratio}")
        self.config = config or SceneOptimisationConfig()
        self._sole_given = sole_m
        self._leg_ratio_given = leg_ratio
        self.walk = LegScale()  #: the legs' length from the windows' standing feet
        # the first window's standing frames: the pelvis (K, 3), the foot's offset at the bones' size (K, 3), plane
        self._sole_seen: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._walked_s = -np.inf  # the newest frame whose standing steps the walk has
        self._rng = np.random.default_rng(seed)
        self._frames: list[tuple[np.ndarray, ...]] = []  # (t_s, pelvis, legs, bones, suit_pelvis, suit_feet)
        self._before: tuple[np.ndarray, np.ndarray, float] | None = None  # last frame optimised: t, feet, ratio
        self._last_suit: np.ndarray | None = None  # the suit's pelvis at the window before's last frame

    def __len__(self) -> int:
        return len(self._frames)

    @property
    def leg_ratio(self) -> float:
        """The legs' length over the bones given: the one given, the walk's once believed, else 1."""
        if self._leg_ratio_given is not None:
            return self._leg_ratio_given
        walk = self.walk.ratio if self.config.legs_from_walk else None
        return 1.0 if walk is None else walk

    @property
    def sole_m(self) -> float | None:
        """The foot joint's height above its sole: the one given, or measured in the first window with the legs'
        length now (:attr:`leg_ratio`); None before."""
        if self._sole_given is not None or self._sole_seen is None:
            return self._sole_given
        pelvis, offsets, planes = self._sole_seen
        return sole_height((pelvis + self.leg_ratio * offsets)[:, None], np.ones((len(pelvis), 1), dtype=bool),
                           planes[:, None])

    @property
    def full(self) -> bool:
        """Whether a whole window is waiting."""
        return len(self._frames) >= self.config.window

    @property
    def capacity(self) -> int:
        """Frames that may wait: two windows, or ``max_wait_s`` of frames at the rate of those waiting if that is
        more, at most four windows."""
        c, frames = self.config, self._frames
        n = 2 * c.window
        if len(frames) >= 2 and frames[-1][0] > frames[0][0]:
            rate_hz = (len(frames) - 1) / (frames[-1][0] - frames[0][0])
            n = max(n, int(round(c.max_wait_s * rate_hz)))
        return min(n, MAX_WAIT_WINDOWS * c.window)

    def add(self, t_s: float, pelvis: np.ndarray, legs: np.ndarray, bones: np.ndarray, suit_pelvis: np.ndarray,
            suit_feet: np.ndarray) -> None:
        """One frame at ``t_s`` (s): the fused pelvis pose T_map_P (4, 4) in ``map``, the legs' local rotations
        (2, 3, 3, 3) and bones (2, 4, 3) (:func:`~lip_ros.hsc4d.suit_body.leg_chains`), the pelvis (3,) and feet
        (2, 3) as the suit alone places them (any frame). Refused (RuntimeError) beyond :attr:`capacity`: optimise
        or drop first."""
        if len(self._frames) >= self.capacity:
            raise RuntimeError(f"{len(self._frames)} frames are waiting: optimise or drop first")
        self._frames.append(tuple(np.asarray(a, dtype=np.float64) for a in (t_s, pelvis, legs, bones, suit_pelvis,
                                                                             suit_feet)))

    def drop(self, n: int | None = None) -> int:
        """Forget the oldest ``n`` frames waiting (None: all) and the continuity with the window before them (a
        gap follows); how many were dropped."""
        n = len(self._frames) if n is None else min(n, len(self._frames))
        del self._frames[:n]
        self._before = self._last_suit = None
        return n

    def optimise(self, points: np.ndarray) -> tuple[WindowResult, np.ndarray, np.ndarray]:
        """Optimise the oldest window of frames waiting (or all of them, if fewer: the end of a capture) on the
        map's ``points`` (M, 3) in ``map``: the result for those frames, which foot stood (N, 2) and the planes
        under them (N, 2, 4). ValueError without frames; :class:`NoGroundYet` when the sole height is still unknown
        and no standing foot has the ground mapped under it (the frames are kept: try again with a later map, or drop
        them)."""
        if not self._frames:
            raise ValueError("no frames to optimise")
        c = self.config
        frames = self._frames[: c.window]
        t_s, pelvis, legs, bones, suit_pelvis, suit_feet = (np.array(a) for a in zip(*frames, strict=True))
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        t0 = pelvis[:, :3, 3]
        offsets = feet_offsets(pelvis[:, :3, :3], legs, bones)
        stance = stance_from_suit(suit_feet, t_s, c.stance_speed_mps)
        # each pair once: a first window waiting for the ground comes again, maybe with more frames
        self.walk.add(*standing_steps(t0, offsets, stance, t_s[1:] > self._walked_s))
        self._walked_s = max(self._walked_s, float(t_s[-1]))
        ratio = self.leg_ratio
        planes, supported = fit_foot_planes(t0[:, None, :] + ratio * offsets, stance, points, self._rng, c)
        if self.sole_m is None:
            ok = stance & supported
            if not ok.any():
                raise NoGroundYet(f"no standing foot with the ground mapped under it: no sole height yet "
                                 f"({int(stance.sum())} standing feet in {len(t_s)} frames, {len(points)} map "
                                 f"points)")
            self._sole_seen = (t0[np.nonzero(ok)[0]], offsets[ok], planes[ok])
        chain = suit_pelvis if self._last_suit is None else np.concatenate([self._last_suit[None], suit_pelvis])
        suit_steps = np.linalg.norm(np.diff(chain[:, :2], axis=0), axis=1)  # horizontal (the suit's frame is level)
        fused_steps = np.linalg.norm(np.diff(pelvis[:, :2, 3], axis=0), axis=1)
        if self._last_suit is None:
            suit_steps = np.concatenate([[0.0], suit_steps])
        scale = fused_steps.sum() / suit_steps[1:].sum() if suit_steps[1:].sum() > 0.0 else 1.0
        before = None
        if self._before is not None:  # its feet as the legs' length now puts them (they scale about the pelvis)
            t_last, feet_last, ratio_last = self._before
            before = (t_last, t_last + (feet_last - t_last) * (ratio / ratio_last))
        result = optimise_window(WindowInput(t0, pelvis[:, :3, :3], legs, ratio * bones, stance, planes,
                                             scale * suit_steps, before), self.sole_m, c)
        result = replace(result, leg_ratio=ratio)
        self._before, self._last_suit = (result.t[-1], result.feet[-1], ratio), suit_pelvis[-1]
        del self._frames[: len(frames)]
        return result, stance, planes


def optimise_sequence(t_s: np.ndarray, pelvis: np.ndarray, legs: np.ndarray, bones: np.ndarray,
                      suit_pelvis: np.ndarray, suit_feet: np.ndarray, map_at: Callable[[int], np.ndarray],
                      config: SceneOptimisationConfig | None = None, sole_m: float | None = None,
                      seed: int = 0, leg_ratio: float | None = None) -> SequenceResult:
    """Optimise N frames at times ``t_s`` in windows of ``config.window``, each once its last frame is in (as a
    live optimiser one window behind would): the fused pelvis poses T_map_P (N, 4, 4) in ``map``, the legs' local
    rotations (N, 2, 3, 3, 3) and bones ((N,) 2, 4, 3) (:func:`~lip_ros.hsc4d.suit_body.leg_chains`), the pelvis
    (N, 3) and the feet (N, 2, 3) as the suit alone places them (any frame: for the step lengths and the stance),
    the map's points when frame ``k`` was the newest (``map_at(k)``, (M, 3) in ``map``), with a
    :class:`SceneOptimiser`. ``sole_m`` None: measured in the first window (:func:`sole_height`) on the first map
    that shows the ground under its feet, the window waiting for it as long as the optimiser's
    :attr:`SceneOptimiser.capacity` allows (then it is left as fused); ValueError if none does by the end.
    ``leg_ratio`` None: the legs' length from the walk as the windows come (:attr:`SceneOptimiser.leg_ratio`)."""
    optimiser = SceneOptimiser(config, sole_m, seed, leg_ratio)
    bones = np.broadcast_to(bones, legs.shape[:2] + (4, 3)).copy()
    out_pelvis, out_legs = pelvis.copy(), np.array(legs, dtype=np.float64)
    out_feet = pelvis[:, None, :3, 3] + feet_offsets(pelvis[:, :3, :3], legs, bones)
    stance = np.zeros((len(t_s), 2), dtype=bool)
    planes = np.full((len(t_s), 2, 4), np.nan)
    ratio, arrival = np.ones(len(t_s)), np.ones(len(t_s))
    windows: list[WindowResult] = []
    done = 0  # the first frame not optimised (or skipped) yet
    for k in range(len(t_s)):
        arrival[k] = optimiser.leg_ratio
        optimiser.add(t_s[k], pelvis[k], legs[k], bones[k], suit_pelvis[k], suit_feet[k])
        last = k == len(t_s) - 1
        while optimiser.full or (last and len(optimiser)):
            try:
                result, st, pl = optimiser.optimise(map_at(k))
            except NoGroundYet:
                if len(optimiser) < optimiser.capacity and not last:
                    break  # the first window waits for a map with the ground under its feet, as the node's does
                if optimiser.sole_m is None and last:
                    raise
                done += optimiser.drop(optimiser.config.window)  # those frames stay as fused
                continue
            w = slice(done, done + len(result.t))
            out_pelvis[w, :3, :3], out_pelvis[w, :3, 3], out_legs[w], out_feet[w] = (result.R, result.t, result.legs,
                                                                                      result.feet)
            stance[w], planes[w], ratio[w] = st, pl, result.leg_ratio
            windows.append(result)
            done = w.stop
    if optimiser.sole_m is None:
        raise NoGroundYet("no standing foot with the ground mapped under it: no sole height")
    return SequenceResult(out_pelvis, out_legs, out_feet, stance, planes, float(optimiser.sole_m), windows, ratio,
                          arrival)


def walk_leg_ratio(t_s: np.ndarray, pelvis: np.ndarray, legs: np.ndarray, bones: np.ndarray, suit_feet: np.ndarray,
                   config: SceneOptimisationConfig | None = None) -> float | None:
    """The legs' length over the ``bones``' from a whole sequence's walk at once (:mod:`~lip_ros.hsc4d.leg_scale`,
    every pair kept): N frames as :func:`optimise_sequence` takes them; None if the walk does not tell it."""
    c = config or SceneOptimisationConfig()
    bones = np.broadcast_to(bones, legs.shape[:2] + (4, 3)).copy()
    walk = LegScale(LegScaleConfig(capacity=max(LegScaleConfig().capacity, 2 * len(t_s))))
    walk.add(*standing_steps(pelvis[:, :3, 3], feet_offsets(pelvis[:, :3, :3], legs, bones),
                             stance_from_suit(suit_feet, t_s, c.stance_speed_mps)))
    return walk.ratio
