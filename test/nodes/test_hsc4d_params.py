"""The HSC4D graph's parameter file and fusion_node's choice of branch: one shipped default per node parameter,
agreeing with the ROS-free code's defaults and the contract's topics."""

from __future__ import annotations

import subprocess

import pytest
import yaml
from helpers import console_script

from lip_ros.core.skeleton import load_skeleton
from lip_ros.hsc4d import sensors
from lip_ros.hsc4d.mount import HipMountPrior
from lip_ros.hsc4d.scene_optimisation import SceneOptimisationConfig
from lip_ros.hsc4d.suit_body import SuitBodyConfig
from lip_ros.hsc4d.trajectory import TrajectoryConfig
from lip_ros.nodes.base import SUIT_QUEUE_S, node_defaults, suit_input
from lip_ros.nodes.fusion_node import BRANCHES, branch_of
from lip_ros.nodes.hsc4d import HSC4D_PARAMS_FILE
from lip_ros.nodes.hsc4d.graph import HSC4D_GRAPH
from lip_ros.resources import params_path


def test_every_node_parameter_has_one_shipped_default():
    doc = yaml.safe_load(params_path(HSC4D_PARAMS_FILE).read_text())
    for node in HSC4D_GRAPH:
        assert set(node_defaults(HSC4D_PARAMS_FILE, node.NAME)) == node.parameter_names(), node.NAME
        assert all(node.PARAMS[k].description for k in node.PARAMS)
    assert set(doc) == {"/**", *(n.NAME for n in HSC4D_GRAPH)}


@pytest.mark.parametrize("rate_hz", [60.0, 100.0, 240.0])
def test_the_suit_buffers_hold_the_same_seconds_at_any_suit_rate(rate_hz: float):
    """A suit at 60 or 240 Hz (real suits run at either): the trajectory's and the body's buffers still cover the
    sweeps held until the jump across the largest clock offset, and the subscriptions' queues the same seconds."""
    config = TrajectoryConfig(suit_rate_hz=rate_hz)
    assert config.suit_capacity / rate_hz >= config.hold_s + config.jump.max_offset_s
    assert suit_input(rate_hz).depth / rate_hz == pytest.approx(SUIT_QUEUE_S, abs=1.0 / rate_hz)


def test_shipped_defaults_agree_with_the_ros_free_defaults_and_the_contract():
    trajectory = node_defaults(HSC4D_PARAMS_FILE, "hsc4d_trajectory_node")
    body = node_defaults(HSC4D_PARAMS_FILE, "hsc4d_body_node")
    config, mount = TrajectoryConfig(), HipMountPrior()
    assert tuple(trajectory["mount_lever_m"]) == mount.lever_m
    assert trajectory["mount_tilt_up_deg"] == mount.tilt_up_deg
    assert trajectory["mount_spin_deg"] == mount.spin_deg and trajectory["check_mount"] == config.check_mount
    assert trajectory["check_mount_hip"] == config.check_hip
    assert trajectory["hold_s"] == config.hold_s and trajectory["map_after_s"] == config.map_after_s
    assert trajectory["max_registration_hz"] == config.odometry.max_rate_hz
    assert tuple(trajectory["pinned_information"]) == config.odometry.pinned_information
    assert tuple(trajectory["pinned_tilt_information"]) == config.odometry.pinned_tilt_information
    assert trajectory["suit_rate_hz"] == body["suit_rate_hz"] == config.suit_rate_hz
    assert trajectory["lidar_topic"] == sensors.HIP_LIDAR_TOPIC
    assert trajectory["suit_odometry_topic"] == body["suit_odometry_topic"] == sensors.SUIT_ODOMETRY_TOPIC
    assert trajectory["pelvis_imu_topic"] == sensors.suit_imu_topic("pelvis")
    assert trajectory["odometry_topic"] == body["odometry_topic"] == sensors.ODOMETRY_TOPIC
    assert trajectory["offset_topic"] == body["offset_topic"] == sensors.SUIT_CLOCK_OFFSET_TOPIC
    assert trajectory["map_topic"] == body["map_topic"] == sensors.MAP_TOPIC
    assert body["optimise_window"] == SceneOptimisationConfig().window
    assert trajectory["frame_id"] == sensors.MAP_FRAME and trajectory["child_frame_id"] == sensors.PELVIS_FRAME
    assert body["suit_imu_topics"] == [sensors.suit_imu_topic(s) for s in load_skeleton().suit_imus]
    assert round(body["max_imu_gap_s"] * 1e9) == SuitBodyConfig().max_gap_ns


def test_fusion_node_branch_comes_from_its_parameter():
    assert next(iter(BRANCHES)) == "lip"
    assert branch_of(["fusion_node"]) == ("lip", ["fusion_node"])
    assert branch_of(["fusion_node", "--ros-args", "-p", "branch:=hsc4d", "-p", "x:=1"]) == (
        "hsc4d", ["fusion_node", "--ros-args", "-p", "x:=1"])
    assert branch_of(["f", "--ros-args", "--param", "branch:=lip"])[0] == "lip"
    assert branch_of(["f", "-p", "branch:=hsc4d"])[0] == "lip"  # not a ROS argument
    with pytest.raises(ValueError, match="branch must be one of lip, hsc4d"):
        branch_of(["f", "--ros-args", "-p", "branch:=nope"])


@pytest.mark.ros
@pytest.mark.parametrize("args, message", [
    (["-p", "branch:=nope"], "branch must be one of"),
    (["-p", "branch:=hsc4d", "-p", "mount_lever_m:=[0.1]"], "mount_lever_m must be a list of 3 finite numbers"),
    (["-p", "branch:=hsc4d", "-p", "body_scale:=-1.0"], "body_scale must be >= 0"),
    (["-p", "branch:=hsc4d", "-p", "pinned_information:=[0.03, 0.01]"], "invalid OdometryConfig"),
])
def test_bad_parameters_stop_the_hsc4d_graph_with_one_line(args, message):
    proc = subprocess.run([console_script("fusion_node"), "--ros-args", *args], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert message in proc.stderr
