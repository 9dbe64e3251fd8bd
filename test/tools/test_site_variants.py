"""The HSC4D rig's capture options shared by ``lip_rig site-bag`` and ``hsc4d_eval`` (lip_ros.tools.site_variants)."""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import pytest

from lip_ros.core.rotations import quat_to_matrix
from lip_ros.core.skeleton import load_skeleton
from lip_ros.rig.site_capture import SiteCapture, SiteCaptureConfig
from lip_ros.tools.site_variants import add_site_arguments, site_capture_config


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_site_arguments(parser)
    return parser.parse_args(argv)


def test_no_options_are_the_rigs_own_capture_and_each_option_sets_its_variant():
    """Without options the capture of a seed is the rig's own (SiteCaptureConfig's defaults); each option sets the
    field it names, so a bag (``lip_rig site-bag``) and the ROS-free evaluation (``hsc4d_eval``) of the same
    options and seed are the same capture."""
    assert site_capture_config(_parse([]), 3) == SiteCaptureConfig(seed=3)
    args = _parse(["--seconds", "20", "--columns", "512", "--rate", "20", "--beams", "32", "--mount-tilt-up", "15",
                   "--mount-spin", "180", "--mount-lever", "0.15", "0", "-0.1", "--suit-rate", "240",
                   "--suit-noise-scale", "4", "--body-scale", "1.2", "--scene", "open", "--sway", "0.5",
                   "--odometry-axes", "base_link"])
    assert site_capture_config(args, 1000) == SiteCaptureConfig(
        seed=1000, seconds=20.0, columns=512, rate_hz=20.0, beams=32, mount_tilt_up_deg=15.0, mount_spin_deg=180.0,
        mount_lever_m=(0.15, 0.0, -0.1), suit_rate_hz=240.0, suit_noise_scale=4.0, body_scale=1.2,
        scene="open", sway_deg=0.5, odometry_axes="base_link")


def test_the_beams_and_size_variants_are_the_hip_lidars_and_the_wearers():
    """``beams`` gives the capture's LiDAR that many beams over the same field of view (an OS1-16 / -32 / -128 for
    the contract's OS1-64); ``body_scale`` the wearer that size of the contract skeleton, in the motion and the body
    the rays meet; other counts and sizes are refused."""
    capture = SiteCapture(SiteCaptureConfig(seed=0, seconds=14.0, columns=512, beams=32, body_scale=1.2))
    own = SiteCapture(SiteCaptureConfig(seed=0, seconds=14.0, columns=512))
    assert (capture.lidar.beams, own.lidar.beams) == (32, 64)
    assert capture.lidar.vertical_fov_deg == own.lidar.vertical_fov_deg
    contract = load_skeleton().offsets
    assert np.allclose(capture.motion.skeleton.offsets, 1.2 * contract)
    assert capture.body.skeleton is capture.motion.skeleton
    assert not np.allclose(own.motion.skeleton.offsets, 1.2 * contract)  # the seed's own: 0.9-1.1
    assert SiteCapture(SiteCaptureConfig(seed=0, seconds=14.0, scene="sparse")).terrain.layout["scene"] == "sparse"
    for bad in ({"beams": 48}, {"body_scale": 1.6}, {"body_scale": 0.4}, {"scene": "forest"}, {"sway_deg": 3.5},
                {"sway_deg": -0.1}, {"odometry_axes": "enu"}):
        with pytest.raises(ValueError):
            SiteCaptureConfig(**bad)


def test_the_odometry_axes_variant_turns_only_the_suit_odometrys_orientation():
    """``odometry_axes="base_link"``: the suit's /mocap/odometry gives the pelvis's orientation in a ROS base_link's
    axes (x forward, y left, z up: the model axes' z, x, y) and its velocity in them; its stamps and positions are
    the rig's own."""
    config = SiteCaptureConfig(seed=0, seconds=14.0, columns=512)
    own = SiteCapture(config).suit_odometry()
    turned = SiteCapture(replace(config, odometry_axes="base_link")).suit_odometry()
    np.testing.assert_array_equal(turned.stamp_ns, own.stamp_ns)
    np.testing.assert_array_equal(turned.position, own.position)
    R_own, R_turned = quat_to_matrix(own.quat), quat_to_matrix(turned.quat)
    np.testing.assert_allclose(R_turned[:, :, 0], R_own[:, :, 2], atol=1e-9)  # base_link's x: the pelvis's forward
    np.testing.assert_allclose(R_turned[:, :, 1], R_own[:, :, 0], atol=1e-9)  # y: its left
    np.testing.assert_allclose(R_turned[:, :, 2], R_own[:, :, 1], atol=1e-9)  # z: its up
    np.testing.assert_allclose(turned.velocity, own.velocity[:, [2, 0, 1]], atol=1e-9)
