"""The performer's translation from the body surface the LiDAR sees, warm-started from the network.

The network's translation is the point mean plus an offset it learned from the training bodies' surfaces: a
performer thicker or thinner than those, or with other proportions, moves the point mean against the pelvis,
and the offset does not follow. Here the estimated pose is dressed in the capsule body of
:class:`lip_ros.core.body.BodyModel` (the body scale the network estimated) with the performer's shape (three
girths and the spine's length) and moved, with the shape, until its surface passes through
the performer's points: a few Gauss-Newton steps, the network's translation a weak prior.

The residual of a point whose ray meets the body is its range error (measured range minus the range at which
the ray meets the surface) times the cosine of the incidence: LiDAR noise lies along the ray, and a distance
measured across the surface instead made noisy bodies too thin and too near (10 % and 1.4 cm at 2 cm of
noise; tested). A point whose ray misses the body counts by its distance to it, with less weight (mostly a
limb the pose puts elsewhere). Huber weights beyond 3 cm. The shape belongs to the performer, not to a frame:
an information filter carries it from frame to frame (each frame's solution, regularised by the estimate so
far, is the new estimate), forgetting over ``shape_memory_frames``. The points' frame must have the sensor at
its origin (L, or L levelled).

Docs: docs/lip/transfer.md ("Surface fit").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lip_ros.core.body import LIMB_PARTS, TORSO_PARTS, BodyModel
from lip_ros.core.capsule_rays import first_hits
from lip_ros.core.skeleton import NUM_JOINTS, PROPORTION_GROUPS, forward_kinematics, load_skeleton
from lip_ros.lip.surface_kernel import normal_equations

__all__ = ["SurfaceFitConfig", "SURFACE_FIT", "SurfaceFit", "SurfaceFitter"]


@dataclass(frozen=True)
class SurfaceFitConfig:
    """Settings of the surface fit (docs/lip/transfer.md)."""

    iterations: int = 4  # Gauss-Newton steps per frame (from the last frame's correction)
    point_noise_m: float = 0.02  # standard deviation of a point's distance to the surface (range noise, body shape)
    huber_m: float = 0.03  # a point's distance to the surface beyond which its weight falls as 1/distance
    miss_weight: float = 0.3  # weight of points whose ray misses the body (outside its silhouette: often a limb
    #                           the pose puts elsewhere)
    translation_prior_m: float = 0.10  # standard deviation of the network's translation, as a prior
    max_shift_m: float = 0.25  # the fit never moves the translation further than this from the network's
    proportion_groups: tuple[str, ...] = ("spine",)  # bone groups whose lengths are fitted (a "+" joins groups of
    #   ``core.skeleton.PROPORTION_GROUPS`` into one length; the legs' lengths drift with leg-pose errors: docs)
    girth_prior: float = 0.15  # standard deviation of the girths (1 = the contract body) before any data
    proportion_prior: float = 0.1  # standard deviation of the proportions before any data
    shape_range: tuple[float, float] = (0.5, 2.0)  # girths and proportions are kept within this
    shape_memory_frames: float = 100.0  # the running shape estimate forgets with this time constant (frames)
    min_points: int = 20  # fewer performer points: the network's translation stays
    max_points: int = 600  # more are thinned evenly to this many (time per frame)

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.min_points < 1 or self.max_points < self.min_points:
            raise ValueError(f"need iterations >= 1 and 1 <= min_points <= max_points: {self}")
        unknown = {g for group in self.proportion_groups for g in group.split("+")} - set(PROPORTION_GROUPS)
        if unknown:
            raise ValueError(f"unknown bone groups {sorted(unknown)}; known: {sorted(PROPORTION_GROUPS)}")


#: The settings the LIP model uses by default.
SURFACE_FIT = SurfaceFitConfig()
#: Girths in the shape: torso, limbs, the rest.
_GIRTHS = 3
#: Smallest cosine of incidence a range error is scaled by (grazing rays).
_MIN_COS = 0.1


@dataclass(frozen=True)
class SurfaceFit:
    """One frame's fit."""

    translation: np.ndarray  # (3,) the fitted pelvis position
    shape: np.ndarray  # (3 + G,) the performer's girths and bone lengths after this frame (running estimate)
    residual_m: float  # median |residual| of the points at the last Gauss-Newton step (NaN if not fitted)
    fitted: bool  # False: too few points, the translation is the network's


class SurfaceFitter:
    """Streaming surface fit of one performer; :meth:`reset` for another."""

    def __init__(self, config: SurfaceFitConfig | None = None) -> None:
        self.config = config or SurfaceFitConfig()
        self._skeleton = load_skeleton()
        self._body = BodyModel(self._skeleton)  # the contract skeleton's capsules, scaled per frame
        part = [n.removeprefix("left_").removeprefix("right_") for n in self._body.names]
        self._group = np.array([0 if p in TORSO_PARTS else 1 if p in LIMB_PARTS else 2 for p in part], dtype=np.int64)
        groups = self.config.proportion_groups
        self._gain = np.zeros((len(groups), NUM_JOINTS, 1))  # 1 on the offsets each bone group's length scales
        for i, group in enumerate(groups):
            self._gain[i, [self._skeleton.index(j) for g in group.split("+") for j in PROPORTION_GROUPS[g]]] = 1.0
        sd = np.array([self.config.girth_prior] * _GIRTHS + [self.config.proportion_prior] * len(groups))
        self._prior = np.diag(1.0 / sd**2)
        self.reset()

    def reset(self) -> None:
        """Forget the performer's shape (and the last correction)."""
        self._info = self._prior.copy()  # information of the running shape estimate
        self._shape = np.ones(len(self._prior))  # the running shape estimate
        self._correction = np.zeros(3)  # the last fitted translation minus the network's

    @property
    def shape_names(self) -> tuple[str, ...]:
        """What each entry of :attr:`shape` is."""
        return ("torso_girth", "limb_girth", "head_hands_feet_girth",
                *(f"{g}_length" for g in self.config.proportion_groups))

    @property
    def shape(self) -> np.ndarray:
        """The running shape estimate: the girths of the torso, the limbs and the rest (head, neck, shoulders,
        hands, feet), then the lengths of the ``proportion_groups`` (1 = the contract body)."""
        return self._shape.copy()

    def offsets(self, shape: np.ndarray) -> np.ndarray:
        """(24, 3) rest offsets of the contract skeleton with the bone-group lengths of ``shape`` (as
        :attr:`shape`; its girths do not matter here)."""
        return self._skeleton.offsets * (1.0 + np.sum(self._gain * (shape[_GIRTHS:] - 1.0)[:, None, None], axis=0))

    def _capsules(self, local_rot: np.ndarray, scale: float, shape: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Root-relative capsule ends a, b (K, 3) of the pose on the skeleton with the bone-group lengths of
        ``shape``, their derivatives (G, K, 3) by each length (exact: joint positions are linear in the bone
        offsets)."""
        # the pose's skeleton, then each group's bones alone (their joints' positions are the derivatives)
        variants = np.concatenate([self.offsets(shape)[None], self._skeleton.offsets * self._gain])
        glob, pos = forward_kinematics(self._skeleton, np.broadcast_to(local_rot, (len(variants), NUM_JOINTS, 3, 3)),
                                       offsets=variants)
        a, b, _ = self._body.capsules(glob, pos)
        a0, b0, _ = self._body.capsules(glob[:1], np.zeros((1, NUM_JOINTS, 3)))  # the ends' offsets from joints
        return scale * a[0], scale * b[0], scale * (a[1:] - a0), scale * (b[1:] - b0)

    def fit(self, points: np.ndarray, local_rot: np.ndarray, scale: float, translation: np.ndarray) -> SurfaceFit:
        """One frame: performer points (N, 3), the pose's local rotations (24, 3, 3) (``[0]`` the pelvis
        orientation) on the contract skeleton scaled by ``scale``, the network's ``translation`` (3,), in one
        frame's axes."""
        c = self.config
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        points = points[np.isfinite(points).all(axis=1)]
        if len(points) > c.max_points:
            points = points[np.linspace(0, len(points) - 1, c.max_points).astype(int)]
        t0 = np.asarray(translation, dtype=np.float64)
        prior_shape = self._shape
        if len(points) < c.min_points or not (np.isfinite(t0).all() and np.isfinite(local_rot).all()):
            return SurfaceFit(t0.copy(), self.shape, float("nan"), False)
        forget = np.exp(-1.0 / c.shape_memory_frames)  # older frames count less: the performer may change
        info = forget * self._info + (1.0 - forget) * self._prior
        a0, b0, da, db = self._capsules(local_rot, scale, prior_shape)
        r0 = scale * self._body.radius
        t = t0 + _clip_norm(self._correction, c.max_shift_m)  # warm start: the last frame's correction
        shape = prior_shape.copy()
        prior_t = 1.0 / c.translation_prior_m**2
        ranges = np.linalg.norm(points, axis=1)
        ray = points / np.maximum(ranges, 1e-9)[:, None]  # the sensor is at the origin of the points' frame
        for _ in range(c.iterations):
            change = shape[_GIRTHS:] - prior_shape[_GIRTHS:]
            a = a0 + np.einsum("g,gkj->kj", change, da)
            ab = b0 + np.einsum("g,gkj->kj", change, db) - a
            radius = r0 * shape[self._group]
            hit_ranges, met = first_hits(-t, ray, a, a + ab, radius)  # where each ray meets the body (root-relative)
            H, rhs, res = normal_equations(points, ray, ranges, t, a, ab, radius, r0, self._group, da, db, hit_ranges,
                                           met, c.huber_m, c.point_noise_m, c.miss_weight, _MIN_COS, _GIRTHS)
            H_data = H.copy()
            H[:3, :3] += prior_t * np.eye(3)
            rhs[:3] -= prior_t * (t - t0)
            H[3:, 3:] += info
            rhs[3:] -= info @ (shape - prior_shape)
            step = np.linalg.solve(H, rhs)
            t = t0 + _clip_norm(t + step[:3] - t0, c.max_shift_m)
            shape = np.clip(shape + step[3:], *c.shape_range)
        self._correction = t - t0
        # the frame's information about the shape, the translation marginalised out
        H_ss = H_data[3:, 3:] - H_data[3:, :3] @ np.linalg.solve(H_data[:3, :3] + prior_t * np.eye(3), H_data[:3, 3:])
        self._info = info + H_ss  # the frame's solution is the new estimate (an information filter's update)
        self._shape = shape
        return SurfaceFit(t, self.shape, float(np.median(np.abs(res))), True)


def _clip_norm(v: np.ndarray, limit: float) -> np.ndarray:
    """``v`` shortened to at most ``limit`` long."""
    n = float(np.linalg.norm(v))
    return v if n <= limit else v * (limit / n)
