"""IMU simulator: Movella DOTs (LIP) or a calibrated 17-sensor suit (HSC4D) on a moving body.

Frames as in docs/conventions.md: L the LiDAR frame (z up, gravity along -z),
B a bone frame (the global rotation of the sensor's ``bone_joint``), S the
sensor frame with constant mounting ``R_B_S`` (``R_L_S = R_L_B @ R_B_S``) and I
the inertial frame all sensors of a rig share, ``R_L_I = Rz(psi)``. Per sample
a sensor reports the REP-145 fields of sensor_msgs/Imu:

* orientation ``R_I_S = R_L_I^T @ R_L_S`` as (x, y, z, w), times an error in I;
* linear_acceleration, the specific force ``f_S = R_L_S^T @ (a_L + [0, 0, g])``
  (+g up at rest), ``a_L`` the acceleration of the sensor's origin in L;
* angular_velocity ``w_S``, the rate of S relative to L, in S.

``a_L`` and ``w_S`` are central differences of the continuous trajectory with a
small step ``h`` around each measurement time: ``a_L = (p(t+h) - 2 p(t) + p(t-h)) / h^2``
and ``w_S = log(R_L_S(t-h)^T R_L_S(t+h)) / (2 h)``.
Stamps are int64 nanoseconds on the trajectory's clock (seconds since the
capture started) plus the rig's clock offset: the measurement time plus a small
clock jitter, or, with a latency (``ImuSpec.latency_s``, ``ImuNoise.latency_jitter``),
the arrival time of a driver that stamps on arrival (DOTs over Bluetooth): the
measurement time plus the sensor's constant latency plus a random delay, in
arrival order.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import lfilter

from lip_msgs_py import ImuSample, imu_sample
from lip_ros.core.frames import GRAVITY
from lip_ros.core.rotations import axis_angle_to_matrix, matrix_to_axis_angle, matrix_to_quat, rot_z
from lip_ros.core.skeleton import Skeleton
from lip_ros.hsc4d.sensors import SUIT_RATE_HZ, suit_imu_topic
from lip_ros.lip.sensors import IMU_TOPICS
from lip_ros.rig.trajectory import Trajectory

__all__ = [
    "ImuSpec",
    "ImuRigConfig",
    "ImuTruth",
    "ImuNoise",
    "ImuStream",
    "make_imu_truth",
    "simulate_imus",
    "DOT_ALONG",
    "DOT_SURFACE_M",
]

_WINDOW_S = 10.0  # trajectory time sampled per batch (bounds memory on long captures)
_JITTER_CLIP = 3.0  # stamp jitter is a normal clipped at this many standard deviations
#: Where the rig straps a DOT by default: this fraction along its bone (forearm, shank) and this far off its axis.
DOT_ALONG = 0.85
DOT_SURFACE_M = 0.035


@dataclass(frozen=True, eq=False)
class ImuSpec:
    """One sensor: where it is strapped and how its clock runs.

    Samples are taken at ``t_k = phase_s + k / rate_hz`` (trajectory seconds, any
    integer k). ``R_B_S`` (3, 3) is the sensor frame in the bone frame,
    ``offset_in_bone`` (3,) the sensor origin relative to the bone joint, in B, metres.
    """

    name: str
    bone_joint: str
    topic: str
    rate_hz: float
    R_B_S: np.ndarray
    offset_in_bone: np.ndarray
    phase_s: float = 0.0
    heading_offset: float = 0.0  # rad, this sensor's inertial heading minus the rig's psi (0: the shared one)
    latency_s: float = 0.0  # its stamps are this much later than the measurement (a driver stamping on arrival)


@dataclass(frozen=True)
class ImuRigConfig:
    """How a rig's sensors are drawn: which bones, nominal rate, clock and mounting spread.

    ``sensors`` lists (name, bone_joint, topic). Each sensor's true rate is
    ``rate_hz * (1 + u)``, u uniform in +-``rate_tol``; with ``shared_clock`` all
    sensors get one rate and phase (a suit samples all segments at once). The
    mounting ``R_B_S`` turns by an angle uniform in [0, ``max_mount_deg``] about a
    uniformly random axis. The sensor origin sits ``along`` of the way from the
    bone joint to its child joint(s) and ``surface_m`` off that axis in a random
    direction. The rig's stamps are offset from L's clock by a constant uniform
    in +-``max_clock_offset_s``.
    """

    sensors: tuple[tuple[str, str, str], ...]
    rate_hz: float
    rate_tol: float = 0.0
    shared_clock: bool = False
    max_mount_deg: float = 0.0
    along: float = 0.5
    surface_m: float = 0.0
    max_clock_offset_s: float = 0.0
    heading_spread_deg: float = 0.0  # each sensor's own inertial heading is psi + uniform(+-this) (0: one heading)
    latency_s: tuple[float, float] = (0.0, 0.0)  # each sensor's stamps late by a constant uniform in this range

    @classmethod
    def lip(cls, skeleton: Skeleton, max_mount_deg: float = 40.0, heading_spread_deg: float = 0.0,
            latency_s: tuple[float, float] = (0.0, 0.0), along: float = DOT_ALONG, surface_m: float = DOT_SURFACE_M
            ) -> ImuRigConfig:
        """The LIP rig: the contract's four DOTs (``lip_imus``), ~60 Hz +-0.5 %, by default near the wrists and
        ankles (``along`` the forearm and shank, ``surface_m`` off their axis)."""
        sensors = tuple((name, s["bone_joint"], IMU_TOPICS[name]) for name, s in skeleton.lip_imus.items())
        return cls(sensors, 60.0, rate_tol=0.005, max_mount_deg=max_mount_deg, along=along, surface_m=surface_m,
                   heading_spread_deg=heading_spread_deg, latency_s=latency_s)

    @classmethod
    def suit(cls, skeleton: Skeleton, rate_hz: float = SUIT_RATE_HZ) -> ImuRigConfig:
        """The HSC4D suit (``suit_imus``): 17 segments at the contract's rate, calibrated mounting, clock offset up to
        1 s."""
        sensors = tuple((seg, joint, suit_imu_topic(seg)) for seg, joint in skeleton.suit_imus.items())
        return cls(sensors, rate_hz, shared_clock=True, max_clock_offset_s=1.0)


@dataclass(frozen=True, eq=False)
class ImuTruth:
    """What calibration must recover: the sensors, the heading ``psi`` of I in L, the clock offset."""

    specs: tuple[ImuSpec, ...]
    psi: float
    clock_offset_s: float = 0.0

    @property
    def R_L_I(self) -> np.ndarray:
        """(3, 3) the inertial frame I in L, ``Rz(psi)``."""
        return rot_z(self.psi)

    def as_dict(self) -> dict:
        """Plain Python types (for YAML / JSON ground-truth files)."""
        return {
            "psi": float(self.psi),
            "R_L_I": self.R_L_I.tolist(),
            "clock_offset_s": float(self.clock_offset_s),
            "sensors": {
                s.name: {
                    "bone_joint": s.bone_joint,
                    "topic": s.topic,
                    "rate_hz": float(s.rate_hz),
                    "phase_s": float(s.phase_s),
                    "R_B_S": np.asarray(s.R_B_S).tolist(),
                    "heading_offset": float(s.heading_offset),
                    "latency_s": float(s.latency_s),
                    "offset_in_bone": np.asarray(s.offset_in_bone).tolist(),
                }
                for s in self.specs
            },
        }


@dataclass(frozen=True)
class ImuNoise:
    """Sensor errors, SI units; defaults after the Movella DOT datasheet.

    White noise is given as a density: per-sample std = density * sqrt(rate_hz).
    Biases are a constant (std per axis) plus a random walk (std grows as
    walk * sqrt(t), zero at the first sample). The orientation error, applied in
    I, is ``Rz(heading) @ exp([roll, pitch, 0])``: roll and pitch a stationary
    first-order Gauss-Markov process (std ``tilt``, correlation time ``tilt_tau``),
    heading a random walk from zero. Stamps deviate from the measurement time by
    a normal of std ``stamp_jitter`` clipped at 3 std; a sensor with a latency
    is stamped on arrival, each sample delayed by its latency plus the absolute
    value of a normal of std ``latency_jitter`` and never before the one before;
    each sample is lost with probability ``drop_prob``.
    """

    gyro_noise: float = float(np.deg2rad(0.007))  # rad/s/sqrt(Hz)
    gyro_bias: float = float(np.deg2rad(0.1))  # rad/s
    gyro_bias_walk: float = 1e-5  # rad/s/sqrt(s)
    accel_noise: float = 120e-6 * GRAVITY  # m/s^2/sqrt(Hz)
    accel_bias: float = 0.02  # m/s^2
    accel_bias_walk: float = 1e-4  # m/s^2/sqrt(s)
    tilt: float = float(np.deg2rad(0.5))  # rad
    tilt_tau: float = 20.0  # s
    heading_walk: float = float(np.deg2rad(2.0) / np.sqrt(60.0))  # rad/sqrt(s): 2 deg std after a minute
    stamp_jitter: float = 0.5e-3  # s
    latency_jitter: float = 0.0  # s, of the arrival delay of sensors with a latency
    drop_prob: float = 0.002

    def __post_init__(self) -> None:
        if any(v < 0 for v in vars(self).values()) or self.drop_prob >= 1.0 or self.tilt_tau <= 0:
            raise ValueError(f"invalid {self}")

    @classmethod
    def none(cls) -> ImuNoise:
        """No errors at all: exact readings, stamps and every sample."""
        return cls(**{k: 0.0 for k in cls.__dataclass_fields__ if k != "tilt_tau"})

    @classmethod
    def suit(cls) -> ImuNoise:
        """DOT-like sensor errors, but frame-counter stamps (no jitter) and no drops, as a suit's export."""
        return replace(cls(), stamp_jitter=0.0, drop_prob=0.0)

    def scaled(self, factor: float) -> ImuNoise:
        """These errors ``factor`` times as large (noise, biases, their walks, tilt and heading errors); stamps,
        drops and the tilt's correlation time unchanged."""
        fixed = ("tilt_tau", "stamp_jitter", "latency_jitter", "drop_prob")
        return replace(self, **{k: v * factor for k, v in vars(self).items() if k not in fixed})


@dataclass(eq=False)
class ImuStream:
    """One sensor's published samples (N after drops) and their ground truth.

    Published: ``stamp_ns`` (N,) int64 measurement time + clock offset + jitter;
    ``quat`` (N, 4) (x, y, z, w), w >= 0, the (noisy) orientation R_I_S;
    ``gyro`` (N, 3) rad/s, angular velocity of S in S; ``accel`` (N, 3) m/s^2,
    specific force in S. Truth: ``t_true`` (N,) float64 s, the measurement time
    on the trajectory clock; ``index`` (N,) int64, k of ``t_k`` (gaps = drops);
    ``R_L_B_true`` (N, 3, 3) the bone orientation in L; ``acc_L_true`` (N, 3) the
    sensor origin's acceleration in L, gravity excluded (free acceleration).
    """

    name: str
    topic: str
    stamp_ns: np.ndarray
    quat: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    t_true: np.ndarray
    index: np.ndarray
    R_L_B_true: np.ndarray
    acc_L_true: np.ndarray

    def samples(self, frame_id: str) -> Iterator[ImuSample]:
        """The published samples as validated :class:`lip_msgs_py.ImuSample` in ``frame_id``."""
        for k in range(len(self.stamp_ns)):
            yield imu_sample(int(self.stamp_ns[k]), frame_id, self.quat[k], self.gyro[k], self.accel[k])


def _random_rotation(max_angle: float, rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    return axis_angle_to_matrix(axis / np.linalg.norm(axis) * rng.uniform(0.0, max_angle))


def _sensor_offset(
    skeleton: Skeleton, joint: str, along: float, surface: float, rng: np.random.Generator
) -> np.ndarray:
    """Sensor origin in the bone frame: ``along`` towards the child joint(s), ``surface`` off the axis."""
    j = skeleton.index(joint)
    children = skeleton.children(j)
    axis = skeleton.offsets[children].mean(axis=0) if children else np.zeros(3)
    radial = rng.normal(size=3)
    norm = np.linalg.norm(axis)
    if norm > 0:
        radial -= radial @ axis / norm**2 * axis
    return along * axis + surface * radial / np.linalg.norm(radial)


def make_imu_truth(skeleton: Skeleton, config: ImuRigConfig, rng: np.random.Generator) -> ImuTruth:
    """Draw a rig: per-sensor rate, phase, mounting and placement, the heading psi and the clock offset."""

    def clock() -> tuple[float, float]:
        rate = config.rate_hz * (1.0 + rng.uniform(-config.rate_tol, config.rate_tol))
        return rate, rng.uniform(0.0, 1.0 / rate)

    shared = clock()
    specs = []
    for name, joint, topic in config.sensors:
        rate, phase = shared if config.shared_clock else clock()
        R_B_S = _random_rotation(np.deg2rad(config.max_mount_deg), rng)
        offset = _sensor_offset(skeleton, joint, config.along, config.surface_m, rng)
        specs.append(ImuSpec(name, joint, topic, rate, R_B_S, offset, phase))
    psi = rng.uniform(-np.pi, np.pi)
    offset_s = rng.uniform(-config.max_clock_offset_s, config.max_clock_offset_s)
    if config.heading_spread_deg > 0.0:  # drawn last: without a spread the rig draws what it always drew
        spread = np.deg2rad(config.heading_spread_deg)
        specs = [replace(s, heading_offset=float(rng.uniform(-spread, spread))) for s in specs]
    if config.latency_s[1] > 0.0:  # likewise
        specs = [replace(s, latency_s=float(rng.uniform(*config.latency_s))) for s in specs]
    return ImuTruth(tuple(specs), float(psi), float(offset_s))


def _sample_index(spec: ImuSpec, t_start: float, t_end: float, h: float) -> np.ndarray:
    """The k of all sample times within [t_start + h, t_end - h]."""
    k0 = np.ceil((t_start + h - spec.phase_s) * spec.rate_hz)
    k1 = np.floor((t_end - h - spec.phase_s) * spec.rate_hz)
    return np.arange(k0, k1 + 1, dtype=np.int64)


def _kinematics(
    traj: Trajectory, specs: tuple[ImuSpec, ...], times: list[np.ndarray], h: float
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per sensor at its times t: R_L_B (n, 3, 3), w_S (n, 3) and a_L (n, 3) by central differences.

    The trajectory is sampled window by window, each distinct time of t - h, t,
    t + h once (a suit's sensors share their sample times).
    """
    skel = traj.skeleton
    joints = [skel.index(s.bone_joint) for s in specs]
    t_lo = min(t[0] for t in times)
    edges = t_lo + _WINDOW_S * np.arange(np.ceil((max(t[-1] for t in times) - t_lo) / _WINDOW_S) + 2)
    cuts = [np.searchsorted(t, edges) for t in times]
    out: list[list[tuple[np.ndarray, ...]]] = [[] for _ in specs]
    for w in range(edges.size - 1):
        parts = [t[c[w] : c[w + 1]] for t, c in zip(times, cuts)]
        stacked = [np.concatenate([p - h, p, p + h]) for p in parts]
        uniq, inv = np.unique(np.concatenate(stacked), return_inverse=True)
        if uniq.size == 0:
            continue
        glob, pos = traj.sample(uniq).global_pose(skel)
        inv = np.split(inv, np.cumsum([s.size for s in stacked])[:-1])
        for i, (spec, j, ix, part) in enumerate(zip(specs, joints, inv, parts)):
            R_L_B = glob[ix, j].reshape(3, part.size, 3, 3)  # at t - h, t, t + h
            p_L = pos[ix, j].reshape(3, part.size, 3) + R_L_B @ spec.offset_in_bone
            R_L_S = R_L_B @ spec.R_B_S
            w_S = matrix_to_axis_angle(np.swapaxes(R_L_S[0], -1, -2) @ R_L_S[2]) / (2.0 * h)
            a_L = (p_L[2] - 2.0 * p_L[1] + p_L[0]) / h**2
            out[i].append((R_L_B[1], w_S, a_L))
    return [tuple(np.concatenate(a) for a in zip(*o)) for o in out]


def _random_walk(n: int, dt: float, walk: float, rng: np.random.Generator, dim: int = 3) -> np.ndarray:
    """Random walk (n, dim) of std walk * sqrt(t - t_0), zero at the first sample."""
    steps = rng.normal(scale=walk * np.sqrt(dt), size=(n, dim))
    steps[0] = 0.0
    return np.cumsum(steps, axis=0)


def _gauss_markov(n: int, dt: float, std: float, tau: float, rng: np.random.Generator, dim: int) -> np.ndarray:
    """Stationary first-order Gauss-Markov process (n, dim): x_k = a x_(k-1) + w_k, a = exp(-dt / tau)."""
    a = np.exp(-dt / tau)
    drive = rng.normal(scale=std, size=(n, dim))
    drive[1:] *= np.sqrt(1.0 - a * a)
    return lfilter([1.0], [1.0, -a], drive, axis=0)


def _bias(n: int, dt: float, const: float, walk: float, rng: np.random.Generator) -> np.ndarray:
    return rng.normal(scale=const, size=3) + _random_walk(n, dt, walk, rng)


def _errors(
    noise: ImuNoise, rate_hz: float, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gyro and accel errors (n, 3), orientation errors R_err (n, 3, 3) in I, stamp errors (n,) s."""
    dt = 1.0 / rate_hz
    gyro = _bias(n, dt, noise.gyro_bias, noise.gyro_bias_walk, rng)
    gyro += rng.normal(scale=noise.gyro_noise * np.sqrt(rate_hz), size=(n, 3))
    accel = _bias(n, dt, noise.accel_bias, noise.accel_bias_walk, rng)
    accel += rng.normal(scale=noise.accel_noise * np.sqrt(rate_hz), size=(n, 3))
    tilt = _gauss_markov(n, dt, noise.tilt, noise.tilt_tau, rng, dim=2)
    heading = _random_walk(n, dt, noise.heading_walk, rng, dim=1)[:, 0]
    R_err = rot_z(heading) @ axis_angle_to_matrix(np.pad(tilt, ((0, 0), (0, 1))))
    bound = _JITTER_CLIP * noise.stamp_jitter
    stamp = np.clip(rng.normal(scale=noise.stamp_jitter, size=n), -bound, bound)
    return gyro, accel, R_err, stamp


def simulate_imus(
    traj: Trajectory,
    truth: ImuTruth,
    t_start: float,
    t_end: float,
    noise: ImuNoise,
    rng: np.random.Generator,
    fd_step: float = 2e-3,
) -> dict[str, ImuStream]:
    """Simulate every sensor of ``truth`` on ``traj`` over [t_start + fd_step, t_end - fd_step].

    ``traj.skeleton`` must be the skeleton the specs were drawn for;
    ``fd_step`` is the finite-difference step h in seconds.
    """
    if fd_step <= 0:
        raise ValueError(f"fd_step must be positive, not {fd_step}")
    for spec in truth.specs:
        if 2 * _JITTER_CLIP * noise.stamp_jitter >= 1.0 / spec.rate_hz:
            raise ValueError(f"stamp jitter {noise.stamp_jitter} s could reorder the stamps of {spec.name}")
    index = [_sample_index(s, t_start, t_end, fd_step) for s in truth.specs]
    if any(k.size == 0 for k in index):
        raise ValueError(f"no samples in [{t_start}, {t_end}] s")
    times = [s.phase_s + k / s.rate_hz for s, k in zip(truth.specs, index)]
    kinematics = _kinematics(traj, truth.specs, times, fd_step)
    streams = {}
    for spec, k, t, (R_L_B, gyro, acc_L) in zip(truth.specs, index, times, kinematics):
        R_I_L = rot_z(truth.psi + spec.heading_offset).T  # this sensor's own inertial frame
        R_L_S = R_L_B @ spec.R_B_S
        accel = np.einsum("nba,nb->na", R_L_S, acc_L + [0.0, 0.0, GRAVITY])
        gyro_err, accel_err, R_err, stamp_err = _errors(noise, spec.rate_hz, t.size, rng)
        keep = rng.random(t.size) >= noise.drop_prob
        stamp_ns = np.rint((t + truth.clock_offset_s + stamp_err) * 1e9).astype(np.int64)
        if spec.latency_s > 0.0:  # stamped on arrival, in order
            delay = spec.latency_s + np.abs(rng.normal(scale=noise.latency_jitter, size=t.size))
            stamp_ns = np.maximum.accumulate(stamp_ns + np.rint(delay * 1e9).astype(np.int64))
            stamp_ns += np.arange(t.size)  # strictly increasing (1 ns apart at worst)
        streams[spec.name] = ImuStream(
            name=spec.name,
            topic=spec.topic,
            stamp_ns=stamp_ns[keep],
            quat=matrix_to_quat(R_err[keep] @ R_I_L @ R_L_S[keep]),
            gyro=(gyro + gyro_err)[keep],
            accel=(accel + accel_err)[keep],
            t_true=t[keep],
            index=k[keep],
            R_L_B_true=R_L_B[keep],
            acc_L_true=acc_L[keep],
        )
    return streams
