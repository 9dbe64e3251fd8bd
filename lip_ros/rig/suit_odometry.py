"""The inertial suit's own root trajectory (``/mocap/odometry``): foot-contact dead reckoning that drifts.

A suit like the HSC4D rig's estimates where the pelvis goes by chaining the
legs from foot to foot: while a foot is planted, the pelvis moves relative to
it as the joint angles say. :func:`foot_contacts` finds the planted feet in a
performer's motion (each foot's slowest sole point, slower than
``ContactConfig.speed_mps``, weighted smoothly); :func:`simulate_suit_odometry`
integrates the pelvis velocity relative to the planted sole points (the true
velocity while a foot stands still, the pelvis's own in flight) with the suit's
errors: a stride-scale error of a few per cent, a heading that drifts (a
constant rate plus a random walk), and no knowledge of stairs or slopes: the
height is the pelvis's above the planted feet, as if the ground were flat.
Positions and orientations are in the suit's world ``mocap_world``, its
inertial frame I (z up, heading ``psi`` in the world W), with the origin under
the first pelvis position; stamps on the suit's clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lip_ros.core.rotations import matrix_to_quat, rot_z
from lip_ros.hsc4d.sensors import SUIT_RATE_HZ
from lip_ros.rig.motion.posture import sole_points
from lip_ros.rig.motion.primitives import smoothstep
from lip_ros.rig.trajectory import Trajectory

__all__ = ["ContactConfig", "FootContacts", "foot_contacts", "SuitOdometryConfig", "SuitOdometry",
           "simulate_suit_odometry"]


@dataclass(frozen=True)
class ContactConfig:
    """When a foot counts as planted."""

    speed_mps: float = 0.25  # its slowest sole point is slower than this (weight 1 below 0.1 m/s, 0 above)
    fade_mps: float = 0.15

    def weight(self, speed: np.ndarray) -> np.ndarray:
        """Stance weight 0..1 of a foot whose slowest sole point moves at ``speed``."""
        return smoothstep((self.speed_mps - speed) / self.fade_mps)


@dataclass(frozen=True)
class FootContacts:
    """Both feet at T times: stance weight (T, 2), their slowest sole point (T, 2, 3) and its velocity."""

    weight: np.ndarray
    anchor: np.ndarray
    anchor_velocity: np.ndarray

    @property
    def stance(self) -> np.ndarray:
        """(T, 2) bool: the foot is planted (weight above one half)."""
        return self.weight > 0.5


def foot_contacts(motion: Trajectory, t: np.ndarray, config: ContactConfig | None = None,
                  fd_step: float = 1e-3) -> FootContacts:
    """The planted feet of ``motion`` at times ``t`` (s): each foot's slowest sole point (heel, ball or toe
    tip; central differences over ``fd_step``) and its stance weight."""
    c = config or ContactConfig()
    t = np.asarray(t, dtype=np.float64)
    points = []
    for dt in (-fd_step, 0.0, fd_step):
        glob, pos = motion.sample(t + dt).global_pose(motion.skeleton)
        points.append(sole_points(motion.skeleton, glob, pos).reshape(len(t), 3, 2, 3))  # (T, kind, foot, 3)
    velocity = (points[2] - points[0]) / (2.0 * fd_step)
    speed = np.linalg.norm(velocity, axis=-1)  # (T, 3, 2)
    slowest = np.argmin(speed, axis=1)  # (T, 2)
    rows = np.arange(len(t))[:, None]
    feet = np.arange(2)[None, :]
    anchor = points[1][rows, slowest, feet]
    return FootContacts(c.weight(speed[rows, slowest, feet]), anchor, velocity[rows, slowest, feet])


@dataclass(frozen=True)
class SuitOdometryConfig:
    """The suit's dead-reckoning errors (each drawn per capture)."""

    stride_scale: float = 0.04  # relative, uniform in +-this
    heading_rate_deg_per_min: float = 3.0  # constant drift, uniform in +-this
    heading_walk_deg_per_sqrt_min: float = 1.0  # plus a random walk
    rate_hz: float = SUIT_RATE_HZ


@dataclass(eq=False)
class SuitOdometry:
    """The suit's root trajectory: ``stamp_ns`` (N,) on its clock, ``position`` (N, 3) and ``quat`` (N, 4)
    (x, y, z, w) of the pelvis in ``mocap_world``, ``velocity`` (N, 3) of the pelvis in its own frame; the
    errors drawn (``scale``, ``heading_rate``, rad/s) and ``heading_error`` (N,) rad."""

    stamp_ns: np.ndarray
    position: np.ndarray
    quat: np.ndarray
    velocity: np.ndarray
    scale: float
    heading_rate: float
    heading_error: np.ndarray


def simulate_suit_odometry(motion: Trajectory, t_start: float, t_end: float, psi: float, clock_offset_s: float,
                           rng: np.random.Generator, config: SuitOdometryConfig | None = None,
                           contacts: ContactConfig | None = None) -> SuitOdometry:
    """The suit's odometry of ``motion`` (in the world W) over [t_start, t_end] s, in its inertial frame of
    heading ``psi`` in W, stamped on the suit's clock (``clock_offset_s`` after the motion's)."""
    c = config or SuitOdometryConfig()
    t = np.arange(t_start, t_end, 1.0 / c.rate_hz)
    dt = 1.0 / c.rate_hz
    h = 1e-3
    pose = motion.sample(t)
    velocity = (motion.sample(t + h).root_pos - motion.sample(t - h).root_pos) / (2.0 * h)
    feet = foot_contacts(motion, t, contacts)
    w = feet.weight
    total = w.sum(axis=1)
    relative = velocity - np.einsum("tf,tfa->ta", w, feet.anchor_velocity) / np.maximum(total, 1e-9)[:, None]
    flying = total < 1e-3
    relative[flying] = velocity[flying]  # no foot down: the suit's own inertial integration (a jump's flight)
    scale = 1.0 + rng.uniform(-c.stride_scale, c.stride_scale)
    rate = np.radians(rng.uniform(-c.heading_rate_deg_per_min, c.heading_rate_deg_per_min)) / 60.0
    walk = np.radians(c.heading_walk_deg_per_sqrt_min) / np.sqrt(60.0)
    heading = rate * (t - t[0]) + np.concatenate([[0.0], np.cumsum(rng.normal(0.0, walk * np.sqrt(dt), t.size - 1))])
    R_err = rot_z(heading)  # the suit's heading error, in W
    step = np.einsum("tab,tb->ta", R_err[:, :2, :2], scale * relative[:, :2]) * dt
    xy = np.concatenate([[np.zeros(2)], np.cumsum(0.5 * (step[1:] + step[:-1]), axis=0)])
    # the ground is where the planted feet are, held through a flight; the height is the pelvis's above it
    ground = np.einsum("tf,tf->t", w, feet.anchor[..., 2]) / np.maximum(total, 1e-9)
    keep = np.maximum.accumulate(np.where(flying, 0, np.arange(t.size)))
    height = pose.root_pos[:, 2] - ground[keep]
    R_I_W = rot_z(psi).T
    position = np.einsum("ab,tb->ta", R_I_W, np.column_stack([xy, np.zeros(t.size)]))
    position[:, 2] = height
    R_I_M = R_I_W @ R_err @ pose.local_rot[:, 0]
    own = np.einsum("tba,tb->ta", pose.local_rot[:, 0], scale * velocity)  # in the pelvis frame
    stamp_ns = np.rint((t + clock_offset_s) * 1e9).astype(np.int64)
    return SuitOdometry(stamp_ns, position, matrix_to_quat(R_I_M), own, float(scale), float(rate), heading)
