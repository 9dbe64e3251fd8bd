"""A synthetic HSC4D capture: a performer who carries a hip LiDAR and wears a 17-IMU suit walks through a site.

One seed draws the site (:class:`lip_ros.rig.terrain.Terrain`), the motion
(:func:`lip_ros.rig.motion.make_site_motion`: A-pose, a ballistic jump, the
site's route over stairs and a ramp), the body, the LiDAR's true mounting on
the hip (the nominal :class:`~lip_ros.rig.hip_lidar.HipMount` perturbed: the
method knows only the nominal one), the suit's inertial heading, clock offset
(up to +-1 s) and sensor errors, and its drifting odometry. Everything is in
the site's world frame W (z up, the open ground at z = 0); stamps are
nanoseconds on the LiDAR's clock, ``epoch_ns`` plus seconds since the motion
began, except the suit's, which run ``clock_offset_s`` ahead.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from lip_ros.core.body import BodyModel
from lip_ros.core.frames import R_L_M_FACING_X
from lip_ros.core.rotations import matrix_to_quat, quat_to_matrix
from lip_ros.hsc4d.sensors import SUIT_RATE_HZ
from lip_ros.rig.capture import EPOCH_NS
from lip_ros.rig.hip_lidar import HipMount
from lip_ros.rig.imu import ImuNoise, ImuRigConfig, ImuStream, ImuTruth, make_imu_truth, simulate_imus
from lip_ros.rig.lidar import Actor, Frame, OusterModel
from lip_ros.rig.mesh_raycast import MeshRaycaster
from lip_ros.rig.motion import PerformerMotion, make_site_motion
from lip_ros.rig.suit_odometry import (
    FootContacts,
    SuitOdometry,
    SuitOdometryConfig,
    foot_contacts,
    simulate_suit_odometry,
)
from lip_ros.rig.terrain import SCENES, Terrain

__all__ = ["ODOMETRY_AXES", "SiteCaptureConfig", "SiteTruth", "SiteCapture", "TRUTH_RATE_HZ"]

#: Rate of the ground truth trajectories (Hz).
TRUTH_RATE_HZ = 100.0

#: The axes the suit odometry's orientation may be given in: the pelvis segment's own, in the model axes (x left,
#: y up, z forward), or a ROS base_link's (x forward, y left, z up).
ODOMETRY_AXES = ("model", "base_link")


@dataclass(frozen=True)
class SiteCaptureConfig:
    """What defines an HSC4D capture; ``seed`` draws the rest."""

    seed: int = 0
    seconds: float = 90.0
    columns: int = 1024
    rate_hz: float = 10.0
    # the hip LiDAR's beams over the OS1's 45 deg: the contract's OS1-64, or a variant (an OS1-16, -32 or -128)
    beams: int = 64
    imu_noise: bool = True
    odometry: SuitOdometryConfig = field(default_factory=SuitOdometryConfig)
    # the LiDAR's tilt up on the hip before the seed's perturbation (+-5 deg): a variant away from the nominal 30 deg
    # the method is told tests that it finds the mounting from the data
    mount_tilt_up_deg: float = HipMount.tilt_up_deg
    # the LiDAR's spin about its own axis (deg; where its +x, an Ouster's connector, points; 0 where the body faces,
    # as the method's nominal mounting): a variant for a sensor worn another way round
    mount_spin_deg: float = HipMount.spin_deg
    # the LiDAR's lever arm in the pelvis frame (m; x left, y up, z forward) before the seed's perturbation; None: the
    # rig's own (0.15 m to the right, 0.1 m behind): a variant, e.g. the sensor on the other hip
    mount_lever_m: tuple[float, float, float] | None = None
    # the rate of the suit's IMUs and of its odometry (``odometry.rate_hz`` is overridden): the contract's 100 Hz,
    # or a variant (the method is told 100 Hz unless its ``suit_rate_hz`` is set)
    suit_rate_hz: float = SUIT_RATE_HZ
    # the wearer's size, times the contract skeleton (None: the seed's, 0.9-1.1): a variant for a wearer smaller or
    # taller than the rig draws (the method scales the contract's skeleton to the standing pelvis height)
    body_scale: float | None = None
    # the suit's IMU errors (noise, biases, tilt and heading errors) this many times the DOT-like ones
    # (ImuNoise.suit(): tilt error 0.5 deg, bias 0.02 m/s^2): a variant for a suit worse than the rig's
    suit_noise_scale: float = 1.0
    # what the site holds besides the ground and the walk's terrace, stairs and ramp (terrain.SCENES): the rig's own
    # "site", or a variant with less for the LiDAR to register on ("sparse": the facades only; "open": nothing)
    scene: str = "site"
    # a wearer who sways in the A-pose, the body turning about each axis through the ground between the feet by up
    # to this much (deg, at most 3; 0: perfectly still): a variant for the still start the method measures the
    # pelvis gyro's bias on
    sway_deg: float = 0.0
    # the axes ``/mocap/odometry``'s orientation is given in (ODOMETRY_AXES): the pelvis segment's, in the contract's
    # model axes (x left, y up, z forward), or a variant in a ROS base_link's (x forward, y left, z up), which the
    # contract does not rule out
    odometry_axes: str = "model"

    def __post_init__(self) -> None:
        if (self.columns not in (512, 1024, 2048) or self.rate_hz not in (10.0, 20.0) or self.seconds <= 0
                or self.beams not in (16, 32, 64, 128) or self.scene not in SCENES
                or not 0.0 <= self.mount_tilt_up_deg <= 60.0 or not -180.0 <= self.mount_spin_deg <= 180.0
                or not 20.0 <= self.suit_rate_hz <= 1000.0 or self.suit_noise_scale < 0.0
                or not 0.0 <= self.sway_deg <= 3.0 or self.odometry_axes not in ODOMETRY_AXES
                or (self.body_scale is not None and not 0.5 <= self.body_scale <= 1.5)
                or (self.mount_lever_m is not None and (len(self.mount_lever_m) != 3
                                                        or not np.isfinite(self.mount_lever_m).all()))):
            raise ValueError(f"invalid {self}")

    def as_dict(self) -> dict:
        """Plain Python types."""
        return asdict(self)


@dataclass(frozen=True)
class SiteTruth:
    """The performer at T times (s since the motion began): pelvis position (T, 3) and orientation (T, 3, 3),
    joint positions (T, 24, 3), global rotations (T, 24, 3, 3) and local ones (T, 24, 3, 3), all in W; the
    LiDAR's pose (T, 3, 3), (T, 3); the planted feet."""

    t: np.ndarray
    pelvis: np.ndarray
    R_W_M: np.ndarray
    joints: np.ndarray
    glob_rot: np.ndarray
    local_rot: np.ndarray
    R_W_L: np.ndarray
    p_W_L: np.ndarray
    contacts: FootContacts


@dataclass
class SiteCapture:
    """The simulated world of one HSC4D capture, built from a :class:`SiteCaptureConfig`."""

    config: SiteCaptureConfig
    epoch_ns: int = EPOCH_NS
    terrain: Terrain = field(init=False)
    motion: PerformerMotion = field(init=False)
    body: BodyModel = field(init=False)
    mount: HipMount = field(init=False)
    lidar: OusterModel = field(init=False)
    suit: ImuTruth = field(init=False)

    def __post_init__(self) -> None:
        cfg = self.config
        self.terrain = Terrain.random(cfg.seed, cfg.scene)
        self.motion = make_site_motion(self.terrain, cfg.seconds, cfg.seed, body_scale=cfg.body_scale,
                                       sway_deg=cfg.sway_deg)
        rng = np.random.default_rng([cfg.seed, 300])
        self.body = BodyModel(self.motion.skeleton, girth=float(rng.uniform(0.9, 1.15)))
        lever = {} if cfg.mount_lever_m is None else {"lever_m": np.array(cfg.mount_lever_m, dtype=np.float64)}
        self.mount = HipMount(tilt_up_deg=cfg.mount_tilt_up_deg, spin_deg=cfg.mount_spin_deg, **lever).perturbed(rng)
        self.lidar = OusterModel(beams=cfg.beams, columns=cfg.columns, rate_hz=cfg.rate_hz,
                                 column0_azimuth_deg=0.0)  # an OS1-64 unless a variant's beams
        self.suit = make_imu_truth(self.motion.skeleton, ImuRigConfig.suit(self.motion.skeleton, cfg.suit_rate_hz),
                                   np.random.default_rng([cfg.seed, 301]))
        self._caster: MeshRaycaster | None = None

    @property
    def num_frames(self) -> int:
        """Frames whose whole sweep lies inside the capture."""
        return int(np.floor(self.motion.duration * self.config.rate_hz + 1e-9))

    def frame_stamp_ns(self, k: int) -> int:
        """Header stamp of frame ``k`` (its first column's time)."""
        return self.epoch_ns + k * self.lidar.period_ns

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[tuple[int, Frame]]:
        """(k, frame) for frames ``start``..``stop`` (default: all), each from its own random stream; the
        wearer's own body blocks and returns rays."""
        if self._caster is None:
            self._caster = MeshRaycaster(self.terrain.triangles())
        poses = self.mount.poses(self.motion, self.epoch_ns)
        wearer = (Actor(self.body, self.motion),)
        for k in range(start, self.num_frames if stop is None else min(stop, self.num_frames)):
            rng = np.random.default_rng([self.config.seed, 400, k])
            yield k, self.lidar.scan_moving(self.frame_stamp_ns(k), self._caster, poses, rng, wearer,
                                            start_ns=self.epoch_ns)

    def suit_streams(self) -> dict[str, ImuStream]:
        """The 17 suit IMUs over the capture, stamped on the suit's clock."""
        noise = ImuNoise.suit().scaled(self.config.suit_noise_scale) if self.config.imu_noise else ImuNoise.none()
        streams = simulate_imus(self.motion, self.suit, 0.0, self.motion.duration, noise,
                                np.random.default_rng([self.config.seed, 302]))
        for s in streams.values():
            s.stamp_ns = s.stamp_ns + self.epoch_ns
        return streams

    def suit_odometry(self) -> SuitOdometry:
        """The suit's drifting ``/mocap/odometry``, stamped on the suit's clock."""
        odo = simulate_suit_odometry(self.motion, 0.0, self.motion.duration, self.suit.psi,
                                     self.suit.clock_offset_s, np.random.default_rng([self.config.seed, 303]),
                                     replace(self.config.odometry, rate_hz=self.config.suit_rate_hz))
        odo.stamp_ns = odo.stamp_ns + self.epoch_ns
        if self.config.odometry_axes == "base_link":
            axes = R_L_M_FACING_X.T  # base_link's x, y, z in the model axes: forward, left, up
            odo.quat = matrix_to_quat(quat_to_matrix(odo.quat) @ axes)
            odo.velocity = odo.velocity @ axes  # in the pelvis's own frame, in those axes
        return odo

    def truth(self, t: np.ndarray | None = None) -> SiteTruth:
        """The ground truth at times ``t`` (s since the motion began; default: the capture at TRUTH_RATE_HZ)."""
        if t is None:
            t = np.arange(0.0, self.motion.duration, 1.0 / TRUTH_RATE_HZ)
        pose = self.motion.sample(t)
        glob, joints = pose.global_pose(self.motion.skeleton)
        R_W_L, p_W_L = self.mount.poses(self.motion)(np.rint(np.asarray(t) * 1e9).astype(np.int64))
        return SiteTruth(np.asarray(t, dtype=np.float64), pose.root_pos, pose.local_rot[:, 0], joints, glob,
                         pose.local_rot, R_W_L, p_W_L, foot_contacts(self.motion, t))

    def lidar_poses(self, stamp_ns: np.ndarray) -> np.ndarray:
        """(N, 4, 4) the LiDAR's true pose T_W_L at LiDAR-clock times ``stamp_ns`` (N,)."""
        R_W_L, p_W_L = self.mount.poses(self.motion, self.epoch_ns)(np.asarray(stamp_ns, dtype=np.int64))
        out = np.tile(np.eye(4), (len(p_W_L), 1, 1))
        out[:, :3, :3], out[:, :3, 3] = R_W_L, p_W_L
        return out

    def phases_ns(self) -> list[tuple[str, int, int]]:
        """The motion's phase windows (a_pose, jump, walk, transitions) on the LiDAR's clock."""
        return [(p.name, self.epoch_ns + int(p.t_start * 1e9), self.epoch_ns + int(p.t_end * 1e9))
                for p in self.motion.phases]
