"""The LIP graph's parameter file: one shipped default per node parameter, agreeing with the ROS-free code's
defaults and topic names, and the checks of user parameter files."""

from __future__ import annotations

import inspect

import pytest
import yaml

from lip_ros.core.imu_sync import SyncConfig
from lip_ros.core.skeleton import load_skeleton
from lip_ros.lip.dot_latency import LatencyConfig
from lip_ros.lip.pipeline import PipelineConfig
from lip_ros.lip.segmentation import SegmentationConfig
from lip_ros.lip.sensors import IMU_NAMES, IMU_TOPICS, LIDAR_TOPIC
from lip_ros.lip.stages import MAX_PENDING_FRAMES, MAX_POSE_GAP_NS, MAX_SILENT_NS, ImuStage, PoseStage
from lip_ros.nodes.base import ParameterError, check_params_files, node_defaults
from lip_ros.nodes.lip import LIP_PARAMS_FILE
from lip_ros.nodes.lip.graph import LIP_GRAPH
from lip_ros.resources import params_path

NS = 1_000_000_000


def test_every_node_parameter_has_one_shipped_default():
    doc = yaml.safe_load(params_path(LIP_PARAMS_FILE).read_text())
    for node in LIP_GRAPH:
        defaults = node_defaults(LIP_PARAMS_FILE, node.NAME)
        assert set(defaults) == node.parameter_names(), node.NAME
        assert all(node.PARAMS[k].description for k in node.PARAMS)
    assert set(doc) == {"/**", *(n.NAME for n in LIP_GRAPH)}


def test_params_files_are_checked(tmp_path):
    known = {n.NAME: n.parameter_names() for n in LIP_GRAPH}
    good = tmp_path / "good.yaml"
    good.write_text("pose_node:\n  ros__parameters:\n    weights: /x\n    use_sim_time: true\n"
                    "/**:\n  ros__parameters:\n    diagnostics_period_s: 2.0\nother_node:\n  ros__parameters:\n"
                    "    anything: 1\n")
    check_params_files(["fusion_node", "--ros-args", "--params-file", str(good)], known)
    bad = tmp_path / "bad.yaml"
    bad.write_text("pose_node:\n  ros__parameters:\n    wieghts: /x\n")
    with pytest.raises(ParameterError, match="wieghts"):
        check_params_files(["x", "--ros-args", "--params-file", str(bad)], known)
    with pytest.raises(ParameterError, match="cannot read"):
        check_params_files(["x", "--ros-args", "--params-file", str(tmp_path / "missing.yaml")], known)


def test_shipped_defaults_agree_with_the_ros_free_defaults():
    """The nodes read their defaults from lip.yaml, the batch tools from the config dataclasses: the same values."""
    cal, pose = node_defaults(LIP_PARAMS_FILE, "calibration_node"), node_defaults(LIP_PARAMS_FILE, "pose_node")
    sync = SyncConfig()
    assert round(cal["max_imu_gap_s"] * NS) == sync.max_gap_ns
    assert round(cal["max_imu_hold_s"] * NS) == sync.max_hold_ns
    assert round(cal["imu_wait_s"] * NS) == sync.wait_ns
    assert round(cal["max_clock_gap_s"] * NS) == sync.max_clock_gap_ns
    assert tuple(cal["dot_latency_s"]) == sync.latency_ns == ()
    assert cal["estimate_dot_latency"] == LatencyConfig().enabled == PipelineConfig().latency.enabled
    assert cal["max_pending_frames"] == MAX_PENDING_FRAMES == PipelineConfig().max_pending_frames
    assert round(cal["max_silent_dot_s"] * NS) == MAX_SILENT_NS == PipelineConfig().max_silent_ns
    assert round(pose["max_pose_gap_s"] * NS) == MAX_POSE_GAP_NS
    seg, segmentation = node_defaults(LIP_PARAMS_FILE, "segmentation_node"), SegmentationConfig()
    assert seg["lock_rule"] == segmentation.lock_rule
    assert (tuple(seg["expected_xy"]) or None) == segmentation.expected_xy
    assert seg["expected_radius_m"] == segmentation.expected_radius_m
    assert (tuple(seg["ground_plane"]) or None) == segmentation.ground_plane
    # the stages take those constants as their defaults
    assert inspect.signature(ImuStage).parameters["max_pending"].default == MAX_PENDING_FRAMES
    assert inspect.signature(ImuStage).parameters["max_silent_ns"].default == MAX_SILENT_NS
    assert inspect.signature(PoseStage).parameters["max_gap_ns"].default == MAX_POSE_GAP_NS


def test_shipped_topics_agree_with_lip_sensors_and_the_contract():
    """One home for the DOT order and the default topics (lip_ros.lip.sensors); lip.yaml and the contract
    skeleton's ``lip_imus`` restate them."""
    seg, cal = node_defaults(LIP_PARAMS_FILE, "segmentation_node"), node_defaults(LIP_PARAMS_FILE, "calibration_node")
    pose = node_defaults(LIP_PARAMS_FILE, "pose_node")
    assert seg["lidar_topic"] == LIDAR_TOPIC
    assert cal["imu_topics"] == [IMU_TOPICS[n] for n in IMU_NAMES]
    assert cal["bone_topics"] == pose["bone_topics"] == [f"/lip/bones/{n}/imu" for n in IMU_NAMES]
    assert seg["performer_topic"] == cal["performer_topic"] == pose["performer_topic"]
    assert seg["ground_topic"] == cal["ground_topic"] == pose["ground_topic"]
    lip_imus = load_skeleton().lip_imus
    assert tuple(lip_imus) == IMU_NAMES
    assert {n: s["topic"] for n, s in lip_imus.items()} == IMU_TOPICS
