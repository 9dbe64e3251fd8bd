"""Training and evaluation sequences from the synthetic rig, cached as .npz.

One sequence = one performer's random motion seen by a static OS1-128 (only
the rays that can hit the performer are cast: no scene) and four DOTs, at
10 Hz. Per LiDAR frame it holds what the calibrated LIP pipeline delivers and
the truth at the frame's pose time (frame stamp + mean ``t`` of the
performer's points, docs/conventions.md):

* ``points`` (P, 3) float32, the performer's points in L of all frames,
  frame k being ``points[offsets[k]:offsets[k + 1]]`` (empty if none); a
  tilted LiDAR's points are levelled first (L here is always level, as the
  pipeline makes it with the fitted ground);
* ``imu_rot`` (T, 4, 3, 3) bone orientations R_L_B and ``imu_acc`` (T, 4, 3)
  free accelerations in L, order :data:`lip_ros.lip.nets.config.IMU_NAMES`: the
  simulator's noisy DOT readings (orientation R_I_S, specific force f_S)
  mapped by a calibration that is the truth (R_L_I = Rz(psi), R_B_S) with a
  random error of 0.5-2 degrees per rotation, ``R_L_B = R_L_I R_I_S R_B_S^T``,
  ``a_L = R_L_I R_I_S f_S - g e_z`` (the paper's equation 13), interpolated
  to the pose time (slerp, linear) from the two neighbouring samples, off by the spec's
  ``imu_time_error_ms`` (the pipeline's residual sync error);
* the performer's body, IMU placement and noise, motion style and any occluder or point dropout drawn from
  the spec's domain (:mod:`lip_ros.rig.domain`: TRAINING for training and validation);
* truth: ``root_pos`` (T, 3), ``local_rot`` (T, 24, 3, 3) ([0] = pelvis in
  L), ``joint_pos`` (T, 24, 3), the performer's scaled ``bone_offsets`` (24, 3);
* ``pose_time`` (T,) seconds since the capture start.

Seed ranges: training seeds in [0, 500_000), validation in [500_000,
1_000_000); seeds >= 1_000_000 are reserved for held-out evaluation
(:func:`make_sequence` with an explicit distance).
"""

from __future__ import annotations

import json
import multiprocessing
import os
import sys
import zlib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from lip_ros.core.body import BodyModel
from lip_ros.core.rotations import axis_angle_to_matrix, rot_x, rot_y, rot_z
from lip_ros.core.skeleton import load_skeleton
from lip_ros.lip.nets.config import TRAINING_RATE_HZ
from lip_ros.lip.sensors import IMU_NAMES
from lip_ros.rig.domain import DOMAINS, TRAINING
from lip_ros.rig.imu import GRAVITY, ImuRigConfig, ImuStream, make_imu_truth, simulate_imus
from lip_ros.rig.lidar import Actor, OusterModel
from lip_ros.rig.motion import calibration_duration, random_motion

__all__ = [
    "TRAIN_SEEDS",
    "VAL_SEEDS",
    "EVAL_SEED_MIN",
    "SequenceSpec",
    "RigSequence",
    "spec_for_seed",
    "evaluation_spec",
    "make_sequence",
    "generate",
    "load_sequence",
    "ensure_cached",
    "DEFAULT_DATA_DIR",
]

TRAIN_SEEDS = range(500_000)
VAL_SEEDS = range(500_000, 1_000_000)
#: Seeds from here on are never used for training or validation.
EVAL_SEED_MIN = 1_000_000
#: Where ``lip_train`` caches simulated sequences unless told otherwise.
DEFAULT_DATA_DIR = Path.home() / ".cache" / "lip_ros" / "rigdata"
_CACHE_VERSION = 3


@dataclass(frozen=True)
class SequenceSpec:
    """Everything that defines a sequence; the seed draws the motion, body, mounting and noise."""

    seed: int
    distance_m: float  # LiDAR to the centre of the capture area
    bearing_deg: float = 0.0
    seconds: float = 30.0
    lidar_height_m: float = 1.2
    area_radius_m: float = 2.5
    calibration: bool = True  # start with the A-pose / T-pose calibration
    calib_error_deg: float = 2.0  # max calibration error per rotation (0: exact calibration)
    body_scale: float | None = None  # the performer's size times the contract skeleton's (None: drawn 0.9-1.1)
    lidar_pitch_deg: float = 0.0  # the LiDAR tilted (as CaptureConfig); the points are levelled, as the pipeline does
    lidar_roll_deg: float = 0.0
    domain: str = "standard"  # what the body, sensors, motion style and occluders are drawn from (rig.domain)
    imu_time_error_ms: float = 0.0  # the IMUs read this late (the pipeline's sync error; negative: early)
    held_out: tuple[str, ...] = ()  # motion families left out of the domain's

    def key(self) -> str:
        """Cache file stem: readable seed and distance plus a hash of the whole spec."""
        crc = zlib.crc32(json.dumps(asdict(self) | {"v": _CACHE_VERSION}, sort_keys=True).encode())
        return f"seq_{self.seed}_{self.distance_m:.1f}m_{crc:08x}"


@dataclass
class RigSequence:
    """One generated sequence (see the module docstring for the arrays)."""

    points: np.ndarray
    offsets: np.ndarray
    imu_rot: np.ndarray
    imu_acc: np.ndarray
    root_pos: np.ndarray
    local_rot: np.ndarray
    joint_pos: np.ndarray
    bone_offsets: np.ndarray
    pose_time: np.ndarray
    meta: dict

    @property
    def num_frames(self) -> int:
        """Number of LiDAR frames T."""
        return len(self.pose_time)

    def frame_points(self, k: int) -> np.ndarray:
        """(N, 3) performer points of frame k."""
        return self.points[self.offsets[k] : self.offsets[k + 1]]


#: Ranges of the training and validation specs (:func:`spec_for_seed`).
DISTANCE_M = (4.0, 25.0)
LIDAR_HEIGHT_M = (0.5, 3.0)
BODY_SCALE = (0.8, 1.2)  # about 1.38-2.06 m
MAX_TILT_DEG = 10.0  # each of pitch and roll
SYNC_ERROR_MS = 15.0  # the IMU readings' time error, +-


def spec_for_seed(seed: int, seconds: float = 30.0, held_out: tuple[str, ...] = ()) -> SequenceSpec:
    """A training/validation spec: distance 4-25 m, any bearing, the LiDAR 0.5-3 m high and tilted up to 10 deg in
    pitch and roll, a performer 0.8-1.2x the contract skeleton drawn from the TRAINING domain (shape, sensors,
    motion style, occluders; without the ``held_out`` motion families), the IMUs up to 15 ms out of sync, and
    one in four starting with the calibration poses (if ``seconds`` leaves 10 s after them)."""
    rng = np.random.default_rng([seed, 7_000])
    return SequenceSpec(
        seed=int(seed),
        distance_m=round(float(rng.uniform(*DISTANCE_M)), 1),
        bearing_deg=round(float(rng.uniform(-180.0, 180.0)), 1),
        seconds=seconds,
        lidar_height_m=round(float(rng.uniform(*LIDAR_HEIGHT_M)), 2),
        calibration=bool(rng.random() < 0.25) and seconds >= calibration_duration(seed) + 10.0,
        body_scale=round(float(rng.uniform(*BODY_SCALE)), 3),
        lidar_pitch_deg=round(float(rng.uniform(-MAX_TILT_DEG, MAX_TILT_DEG)), 1),
        lidar_roll_deg=round(float(rng.uniform(-MAX_TILT_DEG, MAX_TILT_DEG)), 1),
        domain=TRAINING.name,
        imu_time_error_ms=round(float(rng.uniform(-SYNC_ERROR_MS, SYNC_ERROR_MS)), 1),
        held_out=tuple(held_out),
    )


def evaluation_spec(seed: int, distance_m: float, seconds: float = 30.0, bearing_deg: float = 0.0) -> SequenceSpec:
    """A held-out evaluation spec (``seed`` >= EVAL_SEED_MIN): a capture as recorded, starting with the
    calibration poses, LiDAR 1.2 m high; build it with :func:`make_sequence`."""
    if seed < EVAL_SEED_MIN:
        raise ValueError(f"evaluation seeds start at {EVAL_SEED_MIN}, not {seed}")
    return SequenceSpec(seed=int(seed), distance_m=float(distance_m), bearing_deg=float(bearing_deg),
                        seconds=seconds, calibration=True)


def _small_rotation(max_deg: float, rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    angle = np.deg2rad(rng.uniform(0.25 * max_deg, max_deg)) if max_deg > 0 else 0.0
    return axis_angle_to_matrix(axis / np.linalg.norm(axis) * angle)


def _calibrated_imu(
    stream: ImuStream, R_L_I: np.ndarray, R_B_S: np.ndarray, times: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Bone orientation (T, 3, 3) and free acceleration (T, 3) in L at ``times`` (s) from one DOT's readings."""
    t = stream.stamp_ns * 1e-9
    R_L_S = R_L_I @ Rotation.from_quat(stream.quat).as_matrix()
    R_L_B = R_L_S @ R_B_S.T
    acc = np.einsum("nab,nb->na", R_L_S, stream.accel) - [0.0, 0.0, GRAVITY]
    tq = np.clip(times, t[0], t[-1])
    rot = Slerp(t, Rotation.from_matrix(R_L_B))(tq).as_matrix()
    return rot, np.stack([np.interp(tq, t, acc[:, i]) for i in range(3)], axis=-1)


def make_sequence(spec: SequenceSpec) -> RigSequence:
    """Simulate one sequence (deterministic in ``spec``)."""
    bearing = np.deg2rad(spec.bearing_deg)
    centre = spec.distance_m * np.array([np.cos(bearing), np.sin(bearing), 0.0])
    domain = DOMAINS[spec.domain]
    draw = domain.draw(spec.seed)
    motion = random_motion(spec.seed, spec.seconds, centre, spec.lidar_height_m, spec.area_radius_m, spec.calibration,
                           spec.body_scale, load_skeleton().with_proportions(draw.proportions),
                           tuple(a for a in domain.activities if a not in spec.held_out), domain.energy, domain.tempo)
    rng = np.random.default_rng([spec.seed, 7_001])
    body = BodyModel(motion.skeleton, girth=float(rng.uniform(0.9, 1.15)), torso_girth=draw.torso_girth,
                     limb_girth=draw.limb_girth)
    R_S_L = rot_y(np.radians(spec.lidar_pitch_deg)) @ rot_x(np.radians(spec.lidar_roll_deg))  # L in the level world
    lidar = OusterModel.os1_128(rate_hz=TRAINING_RATE_HZ, rotation=R_S_L)
    actors = [Actor(body, motion)]
    num_frames = int(np.floor(motion.duration * lidar.rate_hz + 1e-9))
    clouds, pose_time = [], np.empty(num_frames)
    for k in range(num_frames):
        frame_rng = np.random.default_rng([spec.seed, 7_002, k])
        frame = lidar.scan(k * lidar.period_ns, None, actors, frame_rng)
        pts = frame.points[frame.labels == 0]
        xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=-1) @ R_S_L.T
        lost = frame_rng.random(len(pts)) < draw.point_dropout
        if draw.occluder is not None:
            lost |= draw.occluder.hides(xyz, centre, -spec.lidar_height_m)
        pts, xyz = pts[~lost], xyz[~lost]
        clouds.append(xyz.astype(np.float32))
        t_ns = k * lidar.period_ns + pts["t"].astype(np.float64).mean() if len(pts) else frame.actor_stamps_ns[0]
        pose_time[k] = float(t_ns) * 1e-9
    pose = motion.sample(pose_time)
    _, joint_pos = pose.global_pose(motion.skeleton)

    imu_config = ImuRigConfig.lip(motion.skeleton, along=draw.imu_along, surface_m=draw.imu_surface_m)
    truth = make_imu_truth(motion.skeleton, imu_config, np.random.default_rng([spec.seed, 7_003]))
    streams = simulate_imus(motion, truth, 0.0, motion.duration, draw.imu_noise(),
                            np.random.default_rng([spec.seed, 7_004]))
    imu_time = pose_time - 1e-3 * spec.imu_time_error_ms
    R_L_I = rot_z(truth.psi) @ _small_rotation(spec.calib_error_deg, rng)
    specs = {s.name: s for s in truth.specs}
    imu = [_calibrated_imu(streams[n], R_L_I, specs[n].R_B_S @ _small_rotation(spec.calib_error_deg, rng), imu_time)
           for n in IMU_NAMES]
    counts = np.array([len(c) for c in clouds])
    return RigSequence(
        points=np.concatenate(clouds) if clouds else np.zeros((0, 3), np.float32),
        offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        imu_rot=np.stack([r for r, _ in imu], axis=1).astype(np.float32),
        imu_acc=np.stack([a for _, a in imu], axis=1).astype(np.float32),
        root_pos=pose.root_pos.astype(np.float32),
        local_rot=pose.local_rot.astype(np.float32),
        joint_pos=joint_pos.astype(np.float32),
        bone_offsets=motion.skeleton.offsets.astype(np.float32),
        pose_time=pose_time,
        meta=asdict(spec) | {"scenario": motion.scenario, "mean_points": float(counts.mean())},
    )


def _save(seq: RigSequence, path: Path) -> None:
    arrays = {k: v for k, v in vars(seq).items() if k != "meta"}
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, meta=np.array(json.dumps(seq.meta)), **arrays)
    tmp.replace(path)


def load_sequence(path: str | Path) -> RigSequence:
    """Read a cached sequence."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files if k != "meta"}
        meta = json.loads(str(z["meta"]))
    return RigSequence(meta=meta, **arrays)


def generate(spec: SequenceSpec, cache_dir: str | Path) -> Path:
    """Path of the cached sequence of ``spec``, simulating it first if missing."""
    path = Path(cache_dir) / f"{spec.key()}.npz"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        _save(make_sequence(spec), path)
    return path


def ensure_cached(specs: list[SequenceSpec], cache_dir: str | Path, workers: int = 2) -> list[Path]:
    """Cache all ``specs`` (``workers`` processes, at most the machine's cores), printing progress to stderr;
    their paths, in order."""
    cache_dir = Path(cache_dir)
    missing = [s for s in specs if not (cache_dir / f"{s.key()}.npz").exists()]
    if missing:
        print(f"rigdata: simulating {len(missing)} of {len(specs)} sequences into {cache_dir}", file=sys.stderr,
              flush=True)
        workers = max(1, min(workers, os.cpu_count() or 1))
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            for i, _ in enumerate(pool.map(generate, missing, [cache_dir] * len(missing)), 1):
                if i % 10 == 0 or i == len(missing):
                    print(f"rigdata: {i}/{len(missing)} simulated", file=sys.stderr, flush=True)
    return [cache_dir / f"{s.key()}.npz" for s in specs]
