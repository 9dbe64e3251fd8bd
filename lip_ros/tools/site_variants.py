"""The HSC4D rig's capture and its variants as command-line options, shared by ``lip_rig site-bag`` and
``hsc4d_eval`` (the same capture either way: a bag for the node graph, or the ROS-free evaluation)."""

from __future__ import annotations

import argparse

from lip_ros.rig.site_capture import ODOMETRY_AXES, SiteCaptureConfig
from lip_ros.rig.terrain import SCENES

__all__ = ["add_site_arguments", "site_capture_config"]


def add_site_arguments(parser: argparse.ArgumentParser) -> None:
    """The capture's length, the LiDAR's columns and rate, and the rig variants (the hip LiDAR's beams and true
    mounting, the wearer's size, the suit's rate and noise, the scene), each defaulting to the rig's own."""
    d = SiteCaptureConfig
    parser.add_argument("--seconds", type=float, default=d.seconds, help="capture length")
    parser.add_argument("--columns", type=int, choices=(512, 1024, 2048), default=d.columns)
    parser.add_argument("--rate", type=float, choices=(10.0, 20.0), default=d.rate_hz, help="LiDAR rate, Hz")
    parser.add_argument("--beams", type=int, choices=(16, 32, 64, 128), default=d.beams,
                        help="a rig variant: the hip LiDAR's beams over the OS1-64's field of view (the contract's 64)")
    parser.add_argument("--mount-tilt-up", type=float, default=d.mount_tilt_up_deg, metavar="DEG",
                        help="a rig variant: the hip LiDAR's true tilt up (before each seed's +-5 deg); the method is "
                             "told the nominal 30 deg")
    parser.add_argument("--mount-spin", type=float, default=d.mount_spin_deg, metavar="DEG",
                        help="a rig variant: the hip LiDAR turned about its own spin axis by DEG (where its +x, the "
                             "connector, points; 0: where the body faces)")
    parser.add_argument("--mount-lever", type=float, nargs=3, metavar=("X", "Y", "Z"),
                        help="a rig variant: the hip LiDAR's lever arm in the pelvis frame (m; x left, y up, z "
                             "forward), e.g. 0.15 0 -0.1 for the left hip; the method is told the nominal right hip")
    parser.add_argument("--suit-rate", type=float, default=d.suit_rate_hz, metavar="HZ",
                        help="a rig variant: the suit's IMUs and odometry at this rate; the method is told 100 Hz")
    parser.add_argument("--body-scale", type=float, metavar="X",
                        help="a rig variant: the wearer X times the contract skeleton's size (the rig draws 0.9-1.1 "
                             "per seed)")
    parser.add_argument("--suit-noise-scale", type=float, default=d.suit_noise_scale, metavar="X",
                        help="a rig variant: the suit's IMU errors (noise, biases, tilt and heading errors) X times "
                             "the rig's DOT-like ones")
    parser.add_argument("--sway", type=float, default=d.sway_deg, metavar="DEG",
                        help="a rig variant: the wearer sways in the A-pose, the pelvis turning by up to DEG about "
                             "each axis (the rig's own stands perfectly still)")
    parser.add_argument("--odometry-axes", choices=ODOMETRY_AXES, default=d.odometry_axes,
                        help="a rig variant: the axes of /mocap/odometry's orientation: the pelvis segment's (model: "
                             "x left, y up, z forward) or a ROS base_link's (x forward, y left, z up)")
    parser.add_argument("--scene", choices=SCENES, default=d.scene,
                        help="a rig variant: what the site holds besides the ground and the walk's terrace, stairs and "
                             "ramp: all the rig's own objects (site), the facades along its edges only (sparse), "
                             "nothing (open)")


def site_capture_config(args: argparse.Namespace, seed: int) -> SiteCaptureConfig:
    """The capture of ``seed`` with the options of :func:`add_site_arguments`."""
    return SiteCaptureConfig(seed=seed, seconds=args.seconds, columns=args.columns, rate_hz=args.rate, beams=args.beams,
                             mount_tilt_up_deg=args.mount_tilt_up, mount_spin_deg=args.mount_spin,
                             mount_lever_m=args.mount_lever and tuple(args.mount_lever), suit_rate_hz=args.suit_rate,
                             suit_noise_scale=args.suit_noise_scale, body_scale=args.body_scale,
                             scene=args.scene, sway_deg=args.sway, odometry_axes=args.odometry_axes)
