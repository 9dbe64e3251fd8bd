"""A synthetic LIP capture session: motion, body, scene, Ouster frames and DOT streams, with ground truth.

The same session feeds bag recording (:mod:`lip_ros.rig.bag`) and training
data (frames and IMU streams as arrays), deterministically from one seed. All
stamps are nanoseconds on the capture clock: ``epoch_ns`` + seconds since the
capture started (the motion's time 0).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from lip_ros.core.body import BodyModel
from lip_ros.core.rotations import rot_x, rot_y
from lip_ros.core.skeleton import load_skeleton
from lip_ros.rig.domain import DOMAINS, PerformerDraw
from lip_ros.rig.imu import ImuNoise, ImuRigConfig, ImuStream, ImuTruth, make_imu_truth, simulate_imus
from lip_ros.rig.lidar import Actor, Frame, OusterModel
from lip_ros.rig.motion import PerformerMotion, make_motion
from lip_ros.rig.scene import KeepOut, Scene

__all__ = ["CaptureConfig", "GroundTruth", "CaptureFrame", "CaptureSession", "EPOCH_NS", "SENSORS"]

#: Capture clock origin of rig captures: 2026-01-01T00:00:00Z (fixed, so a seed gives identical bags).
EPOCH_NS = 1_767_225_600 * 1_000_000_000
#: The Ouster models the rig simulates, by name.
SENSORS = {"os1-128": OusterModel.os1_128, "os1-64": OusterModel.os1_64, "os0-128": OusterModel.os0_128,
           "os2-128": OusterModel.os2_128}


@dataclass(frozen=True)
class CaptureConfig:
    """Everything that defines a capture; ``seed`` draws the rest (body, style, clutter, mounting, noise)."""

    scenario: str = "walk"
    seconds: float = 20.0
    seed: int = 0
    distance_m: float = 8.0  # from the LiDAR to the centre of the capture area
    bearing_deg: float = 0.0  # azimuth of the area's centre in L (0 = straight ahead, +x)
    area_radius_m: float = 2.5
    lidar_height_m: float = 1.2
    lidar_pitch_deg: float = 0.0  # the LiDAR tilted about its y axis: positive looks down along +x
    lidar_roll_deg: float = 0.0  # ... and about its x axis: positive lifts +y
    sensor: str = "os1-128"
    columns: int = 1024
    rate_hz: float = 10.0
    azimuth_window_deg: tuple[float, float] | None = None  # Ouster encoder angles from column 0, sweep order
    column0_azimuth_deg: float = 180.0  # where column 0 looks in L (180: the rig's default, 0: ouster-ros os_lidar)
    beam_azimuth_deg: tuple[float, ...] = ()  # per-row azimuth offsets of the beams, cycled (() = none)
    clutter: bool = True
    second_person: bool = False
    max_mount_deg: float = 40.0
    imu_heading_spread_deg: float = 0.0  # each DOT's own inertial heading within +-this of the others' (0: reset)
    imu_latency_ms: tuple[float, float] = (0.0, 0.0)  # each DOT stamped on arrival, late by a constant in this range
    imu_latency_jitter_ms: float = 0.0  # ... plus |normal| of this std per sample
    body_scale: float | None = None  # the performer's size, times the contract skeleton's (None: random 0.9-1.1)
    facing_deg: float = 0.0  # the performer calibrates facing the LiDAR turned by this (counter-clockwise)
    imu_noise: bool = True
    domain: str = "standard"  # what the performer's shape, sensors, motion style and occluder are drawn from

    def __post_init__(self) -> None:
        if self.domain not in DOMAINS:
            raise ValueError(f"domain must be one of {sorted(DOMAINS)}, not {self.domain!r}")
        if self.sensor not in SENSORS:
            raise ValueError(f"sensor must be one of {sorted(SENSORS)}, not {self.sensor!r}")
        if not 2.0 <= self.distance_m <= 100.0:
            raise ValueError(f"distance_m must be in [2, 100], not {self.distance_m}")
        if self.seconds <= 0 or self.rate_hz <= 0:
            raise ValueError("seconds and rate_hz must be positive")

    def as_dict(self) -> dict:
        """Plain Python types (for the truth sidecar)."""
        d = asdict(self)
        d["azimuth_window_deg"] = None if self.azimuth_window_deg is None else list(self.azimuth_window_deg)
        d["beam_azimuth_deg"] = list(self.beam_azimuth_deg)
        d["imu_latency_ms"] = list(self.imu_latency_ms)
        return d


@dataclass(frozen=True)
class GroundTruth:
    """The performer's pose at ``stamp_ns``: when the sweep scanned them (frame stamp + mean point ``t``)."""

    stamp_ns: int
    root_pos: np.ndarray  # (3,) pelvis in L
    local_rot: np.ndarray  # (24, 3, 3), [0] = pelvis orientation in L
    glob_rot: np.ndarray  # (24, 3, 3) bone orientations in L
    joint_pos: np.ndarray  # (24, 3) joint positions in L


@dataclass(frozen=True)
class CaptureFrame:
    """One LiDAR frame with its labels and the performer's ground truth."""

    index: int
    frame: Frame  # points (H, W) Ouster ``original`` array, labels (H, W): -1 scene, 0 performer, 1 other person
    truth: GroundTruth

    @property
    def stamp_ns(self) -> int:
        """The frame's header stamp: when column 0 fired."""
        return self.frame.stamp_ns


@dataclass
class CaptureSession:
    """The simulated world of one capture, built from a :class:`CaptureConfig`."""

    config: CaptureConfig
    epoch_ns: int = EPOCH_NS
    motion: PerformerMotion = field(init=False)
    body: BodyModel = field(init=False)
    others: list[Actor] = field(init=False)
    scene: Scene = field(init=False)
    lidar: OusterModel = field(init=False)
    imu_truth: ImuTruth = field(init=False)
    girth: float = field(init=False)
    draw: PerformerDraw = field(init=False)

    def __post_init__(self) -> None:
        cfg = self.config
        rng = np.random.default_rng([cfg.seed, 100])
        bearing = np.deg2rad(cfg.bearing_deg)
        centre = cfg.distance_m * np.array([np.cos(bearing), np.sin(bearing), 0.0])
        domain = DOMAINS[cfg.domain]
        self.draw = draw = domain.draw(cfg.seed)
        self.motion = make_motion(cfg.scenario, cfg.seconds, cfg.seed, centre, cfg.lidar_height_m, cfg.area_radius_m,
                                  cfg.body_scale, skeleton=load_skeleton().with_proportions(draw.proportions),
                                  facing_deg=cfg.facing_deg, activities=domain.activities, energy=domain.energy,
                                  tempo=domain.tempo)
        self.girth = float(rng.uniform(0.9, 1.15))
        self.body = BodyModel(self.motion.skeleton, girth=self.girth, torso_girth=draw.torso_girth,
                              limb_girth=draw.limb_girth)
        areas = [(centre, cfg.area_radius_m)]
        self.others = []
        if cfg.second_person:
            # a bystander wandering beside and behind the performer's area, never calibrating
            side = np.array([-np.sin(bearing), np.cos(bearing), 0.0]) * (cfg.area_radius_m + 2.0)
            other_centre = centre + side + 2.0 * centre / np.linalg.norm(centre)
            other = make_motion("walk", cfg.seconds, cfg.seed + 7919, other_centre, cfg.lidar_height_m, 1.8,
                                calibration=False)
            self.others.append(Actor(BodyModel(other.skeleton, girth=float(rng.uniform(0.9, 1.2))), other))
            areas.append((other_centre, 1.8))
        ground_z = -cfg.lidar_height_m
        if cfg.clutter:
            lo = np.min([c[:2] - r for c, r in areas], axis=0) - 0.5
            hi = np.max([c[:2] + r for c, r in areas], axis=0) + 0.5
            self.scene = Scene.random(np.random.default_rng([cfg.seed, 101]), KeepOut(lo[0], hi[0], lo[1], hi[1]),
                                      ground_z)
        else:
            self.scene = Scene(ground_z=ground_z)
        if draw.occluder is not None:
            self.scene = self.scene.with_box(*draw.occluder.box(centre, ground_z))
        self.lidar = SENSORS[cfg.sensor](columns=cfg.columns, rate_hz=cfg.rate_hz, rotation=self.lidar_rotation,
                                          azimuth_window_deg=cfg.azimuth_window_deg,
                                          column0_azimuth_deg=cfg.column0_azimuth_deg,
                                          beam_azimuth_deg=tuple(cfg.beam_azimuth_deg))
        imu_config = ImuRigConfig.lip(self.motion.skeleton, max_mount_deg=cfg.max_mount_deg,
                                      heading_spread_deg=cfg.imu_heading_spread_deg,
                                      latency_s=(cfg.imu_latency_ms[0] * 1e-3, cfg.imu_latency_ms[1] * 1e-3),
                                      along=draw.imu_along, surface_m=draw.imu_surface_m)
        self.imu_truth = make_imu_truth(self.motion.skeleton, imu_config, np.random.default_rng([cfg.seed, 102]))

    @property
    def num_frames(self) -> int:
        """Frames whose whole sweep lies inside the capture."""
        return int(np.floor(self.motion.duration * self.config.rate_hz + 1e-9))

    @property
    def actors(self) -> list[Actor]:
        """The performer (index 0, label 0) and any other people."""
        return [Actor(self.body, self.motion), *self.others]

    def frame_stamp_ns(self, k: int) -> int:
        """Header stamp of frame ``k``."""
        return self.epoch_ns + k * self.lidar.period_ns

    @property
    def lidar_rotation(self) -> np.ndarray:
        """R_S_L (3, 3): the LiDAR frame L in the level world S of the scene and the motion (pitch, then roll)."""
        cfg = self.config
        return rot_y(np.radians(cfg.lidar_pitch_deg)) @ rot_x(np.radians(cfg.lidar_roll_deg))

    def truth_at(self, stamp_ns: int) -> GroundTruth:
        """The performer's pose at a capture-clock time, in L."""
        pose = self.motion.sample(np.array([(stamp_ns - self.epoch_ns) * 1e-9]))
        glob, pos = pose.global_pose(self.motion.skeleton)
        R_L_S = self.lidar_rotation.T
        local = pose.local_rot[0].copy()
        local[0] = R_L_S @ local[0]
        return GroundTruth(int(stamp_ns), R_L_S @ pose.root_pos[0], local, R_L_S @ glob[0], pos[0] @ R_L_S.T)

    def imu_calibration(self) -> dict:
        """The DOTs' true calibration (:meth:`ImuTruth.as_dict`) with the inertial frame in L (``R_L_I``); ``psi``
        is its heading in the level world."""
        d = self.imu_truth.as_dict()
        d["R_L_I"] = (self.lidar_rotation.T @ self.imu_truth.R_L_I).tolist()
        return d

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[CaptureFrame]:
        """Frames ``start``..``stop`` (default: all), each from its own random stream."""
        static = self.lidar.static_image(self.scene)
        actors = self.actors
        for k in range(start, self.num_frames if stop is None else min(stop, self.num_frames)):
            rng = np.random.default_rng([self.config.seed, 200, k])
            frame = self.lidar.scan(self.frame_stamp_ns(k), static, actors, rng, start_ns=self.epoch_ns)
            mine = frame.labels == 0
            if mine.any():
                stamp = frame.stamp_ns + int(np.rint(frame.points["t"][mine].astype(np.float64).mean()))
            else:
                stamp = int(frame.actor_stamps_ns[0])
            yield CaptureFrame(k, frame, self.truth_at(stamp))

    def imu_streams(self) -> dict[str, ImuStream]:
        """The four DOT streams over the whole capture, stamps on the capture clock."""
        noise = self.draw.imu_noise() if self.config.imu_noise else ImuNoise.none()
        noise = replace(noise, latency_jitter=self.config.imu_latency_jitter_ms * 1e-3)
        streams = simulate_imus(self.motion, self.imu_truth, 0.0, self.motion.duration, noise,
                                np.random.default_rng([self.config.seed, 103]))
        for s in streams.values():
            s.stamp_ns = s.stamp_ns + self.epoch_ns
        return streams

    def dot_delays_ms(self) -> dict[str, float]:
        """Each DOT's true mean delay (ms): how late its samples are stamped on average, its latency plus the
        mean stamp jitter, what an online latency estimate should find."""
        return {name: 1e3 * float(np.mean((s.stamp_ns - self.epoch_ns) * 1e-9 - s.t_true
                                          - self.imu_truth.clock_offset_s))
                for name, s in self.imu_streams().items()}

    def phases_ns(self) -> list[tuple[str, int, int]]:
        """The motion's phase windows (calibration poses, activities) on the capture clock."""
        return [(p.name, self.epoch_ns + int(p.t_start * 1e9), self.epoch_ns + int(p.t_end * 1e9))
                for p in self.motion.phases]
