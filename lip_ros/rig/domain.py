"""Rig domains: the ranges a capture's performer, body, sensors and motion are drawn from.

* :data:`STANDARD`: the rig as it always drew; the held-out in-distribution captures.
* :data:`TRAINING`: the LIP training data's wider randomisation (body proportions and surface, IMU placement and
  noise, motion energy and tempo, point dropout, occluders); the out-of-distribution protocol's weights are
  trained on it without the :data:`HELD_OUT_ACTIVITIES`.
* :data:`SHIFTED`: the out-of-distribution test variant. Each of its choices lies outside what TRAINING draws
  (docs/lip/transfer.md lists them): the held-out motion families, proportions and a body surface beyond the
  training ranges, sensors mid-bone, 3x the IMU noise, faster and larger motion, a LiDAR mounted high and tilted
  down, DOTs stamped late, a low wall in front of the performer.

A domain draws per seed (:meth:`RigDomain.draw`) from a random stream of its own, so the STANDARD draw changes
nothing that the rig drew before domains existed.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from lip_ros.core.skeleton import PROPORTION_GROUPS
from lip_ros.rig.imu import DOT_ALONG, DOT_SURFACE_M, ImuNoise
from lip_ros.rig.motion import ACTIVITIES
from lip_ros.rig.motion.clips import ENERGY_RANGE, TEMPO_RANGE

__all__ = ["Range", "Occluder", "PerformerDraw", "RigDomain", "STANDARD", "TRAINING", "SHIFTED", "SHIFT_GROUPS",
           "DOMAINS", "HELD_OUT_ACTIVITIES"]

Range = tuple[float, float]

#: Motion families the out-of-distribution protocol's weights never see in training (``lip_train --hold-out``).
HELD_OUT_ACTIVITIES = ("martial",)


@dataclass(frozen=True)
class Occluder:
    """A thin vertical wall across the line of sight to the capture area, standing on the ground.

    Placed in the area's frame: ``distance_m`` in front of the area's centre towards the LiDAR, its middle
    ``lateral_m`` to the side (counter-clockwise seen from above), ``width_m`` wide and ``height_m`` high.
    """

    distance_m: float
    lateral_m: float
    width_m: float
    height_m: float

    def hides(self, points: np.ndarray, centre: np.ndarray, ground_z: float) -> np.ndarray:
        """(N,) bool: which ``points`` (N, 3) in the LiDAR's level frame (origin at the LiDAR) the wall hides from
        the LiDAR, the area's centre at ``centre`` (2,) or (3,)."""
        centre = np.asarray(centre, dtype=np.float64)[:2]
        u = centre / np.linalg.norm(centre)  # along the line of sight
        v = np.array([-u[1], u[0]])
        wall = float(np.linalg.norm(centre)) - self.distance_m
        depth = points[:, :2] @ u
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(depth > wall, wall / depth, np.nan)  # the ray's fraction where it crosses the wall's plane
        side = s * (points[:, :2] @ v) - self.lateral_m
        height = s * points[:, 2] - ground_z
        return (np.abs(side) <= 0.5 * self.width_m) & (height <= self.height_m)

    def box(self, centre: np.ndarray, ground_z: float) -> tuple[np.ndarray, np.ndarray, float]:
        """The wall as a box of the scene: centre (3,), half sizes (3,), yaw (rad)."""
        centre = np.asarray(centre, dtype=np.float64)[:2]
        u = centre / np.linalg.norm(centre)
        v = np.array([-u[1], u[0]])
        xy = centre - self.distance_m * u + self.lateral_m * v
        half = np.array([0.05, 0.5 * self.width_m, 0.5 * self.height_m])
        return np.array([xy[0], xy[1], ground_z + half[2]]), half, float(np.arctan2(u[1], u[0]))


@dataclass(frozen=True)
class PerformerDraw:
    """One seed's draw from a domain."""

    proportions: dict[str, float]  # PROPORTION_GROUPS group -> length factor (empty: the contract's shape)
    torso_girth: float
    limb_girth: float
    imu_along: float
    imu_surface_m: float
    imu_noise_factor: float
    point_dropout: float
    occluder: Occluder | None

    def imu_noise(self) -> ImuNoise:
        """The DOT datasheet's errors (densities, biases, tilt, heading walk, stamp jitter, drops) times the drawn
        factor."""
        base = ImuNoise()
        f = self.imu_noise_factor
        if f == 1.0:
            return base
        keep = {"tilt_tau", "latency_jitter", "drop_prob"}
        scaled = {k.name: getattr(base, k.name) * f for k in fields(base) if k.name not in keep}
        return replace(base, **scaled, drop_prob=min(0.5, base.drop_prob * f))


@dataclass(frozen=True)
class RigDomain:
    """Ranges (uniform) a capture is drawn from; a degenerate range is a fixed value."""

    name: str
    activities: tuple[str, ...] = ACTIVITIES  # motion families (``mixed`` chains them)
    proportions: Range = (0.0, 0.0)  # each PROPORTION_GROUPS group's length factor is 1 +- this (random sign)
    torso_girth: Range = (1.0, 1.0)  # radius factor of the torso capsules (on top of the performer's girth)
    limb_girth: Range = (1.0, 1.0)  # ... of the arm and leg capsules
    imu_along: Range = (DOT_ALONG, DOT_ALONG)  # sensor origin along the bone, fraction towards the child joint
    imu_surface_m: Range = (DOT_SURFACE_M, DOT_SURFACE_M)  # ... and off the bone's axis
    imu_noise_factor: Range = (1.0, 1.0)  # on every IMU error
    energy: Range = ENERGY_RANGE  # motion style: amplitude factor
    tempo: Range = TEMPO_RANGE  # ... duration factor (smaller is faster)
    point_dropout: Range = (0.0, 0.0)  # fraction of the performer's returns lost at random (training data)
    occluder_prob: float = 0.0  # chance of a low wall between the LiDAR and the performer
    occluder_height_m: Range = (0.5, 1.1)  # ... its height
    distance_m: Range = (4.0, 20.0)  # of captures: LiDAR to the area's centre, spread evenly over the set
    lidar_height_m: Range = (1.2, 1.2)  # of captures (training sequences draw their own)
    lidar_pitch_deg: Range = (0.0, 0.0)  # of captures, positive looks down along +x
    imu_heading_spread_deg: float = 0.0  # of captures: each DOT's heading within +-this (0: reset together)
    imu_latency_ms: Range = (0.0, 0.0)  # of captures: each DOT stamped late by a constant in this range

    def draw(self, seed: int) -> PerformerDraw:
        """The performer's shape, sensors and occluder for ``seed`` (deterministic)."""
        rng = np.random.default_rng([seed, 300])
        prop = {g: round(1.0 + float(rng.choice([-1.0, 1.0]) * rng.uniform(*self.proportions)), 4)
                for g in PROPORTION_GROUPS}
        draw = PerformerDraw(
            proportions={} if self.proportions == (0.0, 0.0) else prop,
            torso_girth=float(rng.uniform(*self.torso_girth)),
            limb_girth=float(rng.uniform(*self.limb_girth)),
            imu_along=float(rng.uniform(*self.imu_along)),
            imu_surface_m=float(rng.uniform(*self.imu_surface_m)),
            imu_noise_factor=float(rng.uniform(*self.imu_noise_factor)),
            point_dropout=float(rng.uniform(*self.point_dropout)),
            occluder=None,
        )
        if rng.random() < self.occluder_prob:
            draw = replace(draw, occluder=Occluder(distance_m=float(rng.uniform(1.2, 2.5)),
                                                   lateral_m=float(rng.uniform(-0.8, 0.8)),
                                                   width_m=float(rng.uniform(1.0, 2.5)),
                                                   height_m=float(rng.uniform(*self.occluder_height_m))))
        return draw


STANDARD = RigDomain("standard")
TRAINING = RigDomain(
    "training",
    proportions=(0.0, 0.08),
    torso_girth=(0.85, 1.2),
    limb_girth=(0.85, 1.2),
    imu_along=(0.55, 0.95),
    imu_surface_m=(0.02, 0.06),
    imu_noise_factor=(0.5, 2.0),
    energy=(0.7, 1.3),
    tempo=(0.75, 1.3),
    point_dropout=(0.0, 0.3),
    occluder_prob=0.3,
)
SHIFTED = RigDomain(
    "shifted",
    proportions=(0.09, 0.15),
    torso_girth=(1.3, 1.45),
    limb_girth=(0.7, 0.8),
    imu_along=(0.35, 0.5),
    imu_surface_m=(0.07, 0.09),
    imu_noise_factor=(3.0, 3.0),
    energy=(1.35, 1.5),
    tempo=(0.6, 0.7),
    occluder_prob=1.0,
    occluder_height_m=(0.4, 0.7),
    distance_m=(8.0, 20.0),
    lidar_height_m=(3.3, 3.8),
    lidar_pitch_deg=(8.0, 14.0),
    imu_latency_ms=(20.0, 60.0),
)
#: SHIFTED's choices in groups: ``shifted_<group>`` is STANDARD with that group's choices of SHIFTED (which of them
#: costs what: docs/lip/transfer.md).
SHIFT_GROUPS = {
    "body": ("proportions", "torso_girth", "limb_girth"),
    "imus": ("imu_along", "imu_surface_m", "imu_noise_factor", "imu_latency_ms"),
    "imu_placement": ("imu_along", "imu_surface_m"),  # the IMU group's parts
    "imu_errors": ("imu_noise_factor",),
    "imu_timing": ("imu_latency_ms",),
    "motion": ("energy", "tempo"),
    "mount": ("distance_m", "lidar_height_m", "lidar_pitch_deg"),
    "wall": ("occluder_prob", "occluder_height_m"),
}
#: Domains by name.
DOMAINS = {d.name: d for d in (STANDARD, TRAINING, SHIFTED)} | {
    f"shifted_{group}": replace(STANDARD, name=f"shifted_{group}", **{f: getattr(SHIFTED, f) for f in choices})
    for group, choices in SHIFT_GROUPS.items()
}
