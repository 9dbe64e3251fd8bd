"""Capture bags: rosbag2 MCAP layout, readable by rosbags and mcap, deterministic, truthful ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import DEMO_BAG
from mcap.reader import make_reader

from lip_msgs_py import (
    OUSTER_ORIGINAL_DTYPE,
    cloud_dtype,
    cloud_to_array,
    msg_to_imu,
    msg_to_joint_state,
    msg_to_pose_array,
    msg_to_pose_stamped,
    read_header,
)
from lip_ros.bagio import bag_topics, read_messages
from lip_ros.core.rotations import quat_to_matrix
from lip_ros.core.skeleton import forward_kinematics, joint_angles_to_local_rotations, joint_state_names
from lip_ros.lip.sensors import LIDAR_TOPIC
from lip_ros.outputs import GT_TOPICS
from lip_ros.rig.bag import LABELS_FILE, TRUTH_FILE, write_capture_bag
from lip_ros.rig.capture import CaptureConfig, CaptureSession
from lip_ros.rig.inspect import summarize_bag
from lip_ros.tools.rig import main as lip_rig

CONFIG = CaptureConfig(scenario="walk", seconds=13.0, seed=5, columns=512, second_person=True)


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bags") / "walk"
    write_capture_bag(CaptureSession(CONFIG), out, progress=False)
    return out


def _session_from_sidecar(bag: Path) -> CaptureSession:
    with open(bag / TRUTH_FILE, encoding="utf-8") as f:
        cfg = yaml.safe_load(f)["config"]
    return CaptureSession(CaptureConfig(**cfg))


def test_bag_layout_and_topics(bag: Path) -> None:
    with open(bag / "metadata.yaml", encoding="utf-8") as f:
        meta = yaml.safe_load(f)["rosbag2_bagfile_information"]
    assert meta["storage_identifier"] == "mcap"
    assert [Path(p).suffix for p in meta["relative_file_paths"]] == [".mcap"]
    topics = bag_topics(bag)
    session = CaptureSession(CONFIG)
    n = session.num_frames
    assert topics[LIDAR_TOPIC].count == n and topics[LIDAR_TOPIC].reliability == "best_effort"
    for t in (GT_TOPICS.joint_states, GT_TOPICS.root_pose, GT_TOPICS.joint_poses):
        assert topics[t].count == n and topics[t].reliability == "reliable"
    for name in ("left_wrist", "right_wrist", "left_ankle", "right_ankle"):
        info = topics[f"/dot/{name}/imu"]
        assert info.msgtype == "sensor_msgs/msg/Imu"
        assert 0.97 * 60 * CONFIG.seconds < info.count < 1.01 * 60 * CONFIG.seconds


def test_mcap_reader_sees_the_same_messages(bag: Path) -> None:
    mcap_file = next(bag.glob("*.mcap"))
    with open(mcap_file, "rb") as f:
        reader = make_reader(f)
        counts: dict[str, int] = {}
        log_times = []
        for schema, channel, message in reader.iter_messages():
            assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            log_times.append(message.log_time)
    assert counts == {t: i.count for t, i in bag_topics(bag).items()}
    assert log_times == sorted(log_times)


def test_clouds_are_organized_ouster_original(bag: Path) -> None:
    msgs = list(read_messages(bag, [LIDAR_TOPIC]))
    period = int(1e9 / CONFIG.rate_hz)
    stamps = [read_header(m.msg)[0] for m in msgs]
    assert np.all(np.diff(stamps) == period)
    m = msgs[len(msgs) // 2]
    assert m.log_ns > stamps[len(msgs) // 2] + period  # published after the sweep ends
    msg = m.msg
    assert (msg.height, msg.width, msg.point_step) == (128, 512, 48)
    assert msg.header.frame_id == "os_lidar" and not msg.is_dense
    assert cloud_dtype(msg) == OUSTER_ORIGINAL_DTYPE
    pts = cloud_to_array(msg)
    np.testing.assert_array_equal(pts["ring"], np.arange(128)[:, None] * np.ones((1, 512)))
    assert np.all(np.diff(pts["t"][0].astype(np.int64)) > 0) and pts["t"][0, -1] < period
    none = ~np.isfinite(pts["x"])
    assert none.any() and np.all(pts["range"][none] == 0)
    ok = ~none
    r = np.sqrt(pts["x"][ok].astype(float) ** 2 + pts["y"][ok] ** 2 + pts["z"][ok] ** 2)
    np.testing.assert_allclose(r, pts["range"][ok] * 1e-3, atol=1e-5 * r.max())


def _check_labelled_points(bag: Path, step: int) -> None:
    """Every ``step``-th frame: performer points on the true body surface, truth stamped when scanned."""
    session = _session_from_sidecar(bag)
    clouds = list(read_messages(bag, [LIDAR_TOPIC]))
    truth = [msg_to_pose_array(m.msg) for m in read_messages(bag, [GT_TOPICS.joint_poses])]
    assert len(clouds) == len(truth) == session.num_frames
    with np.load(bag / LABELS_FILE, allow_pickle=False) as z:
        offsets, pixel, actor = z["offsets"], z["pixel"], z["actor"]
        assert np.array_equal(z["frame_stamp_ns"], [read_header(c.msg)[0] for c in clouds])
    for k in range(0, len(clouds), step):
        a, b = offsets[k], offsets[k + 1]
        flat = cloud_to_array(clouds[k].msg).reshape(-1)[pixel[a:b][actor[a:b] == 0]]
        assert len(flat) > 20
        xyz = np.stack([flat["x"], flat["y"], flat["z"]], axis=1).astype(np.float64)
        gt = truth[k]
        d = session.body.surface_distance(xyz, quat_to_matrix(gt.quats), gt.positions)
        assert np.abs(d).mean() < 0.02 and np.abs(d).max() < 0.08, (k, np.abs(d).max())
        # the contract's stamp: frame stamp + mean per-point time of the performer's points
        expected = read_header(clouds[k].msg)[0] + flat["t"].astype(np.float64).mean()
        assert abs(gt.stamp_ns - expected) <= 1


def test_labelled_points_lie_on_the_true_body_and_truth_is_stamped_when_scanned(bag: Path) -> None:
    with np.load(bag / LABELS_FILE, allow_pickle=False) as z:
        assert set(np.unique(z["actor"])) == {0, 1}  # performer and bystander
    _check_labelled_points(bag, step=17)


def test_bundled_demo_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The demo bag replays: the rig's claims hold for it, and `lip_rig inspect --plot` reports and draws it."""
    _check_labelled_points(DEMO_BAG, step=13)
    summary = summarize_bag(DEMO_BAG)
    assert summary.cloud_shape == (128, 512)
    assert min(summary.performer_points) > 50
    assert len(summary.imu_rest_norm) == 4
    for topic, norm in summary.imu_rest_norm.items():
        assert norm == pytest.approx(9.81, abs=0.1) and summary.imu_rest_up[topic] > 0.999
    png = tmp_path / "demo.png"
    assert lip_rig(["inspect", str(DEMO_BAG), "--plot", str(png)]) == 0
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"
    assert "/ouster/points" in capsys.readouterr().out


def test_truth_topics_agree(bag: Path) -> None:
    session = _session_from_sidecar(bag)
    names = joint_state_names(session.motion.skeleton)
    roots = [msg_to_pose_stamped(m.msg) for m in read_messages(bag, [GT_TOPICS.root_pose])]
    joints = [msg_to_pose_array(m.msg) for m in read_messages(bag, [GT_TOPICS.joint_poses])]
    states = [msg_to_joint_state(m.msg, names) for m in read_messages(bag, [GT_TOPICS.joint_states])]
    for r, j, s in zip(roots[::20], joints[::20], states[::20]):
        assert r.stamp_ns == j.stamp_ns == s.stamp_ns
        np.testing.assert_allclose(r.position, j.positions[0])
        local = joint_angles_to_local_rotations(s.positions, root_rot=quat_to_matrix(r.quat))
        glob, pos = forward_kinematics(session.motion.skeleton, local, r.position)
        np.testing.assert_allclose(pos, j.positions, atol=1e-6)
        np.testing.assert_allclose(glob, quat_to_matrix(j.quats), atol=1e-6)


def test_imus_at_rest_read_gravity_up(bag: Path) -> None:
    with open(bag / TRUTH_FILE, encoding="utf-8") as f:
        truth = yaml.safe_load(f)
    a_pose = next(p for p in truth["phases"] if p["name"] == "a_pose")
    forces: dict[str, list[np.ndarray]] = {}
    for m in read_messages(bag, [f"/dot/{n}/imu" for n in ("left_wrist", "right_wrist", "left_ankle", "right_ankle")]):
        s = msg_to_imu(m.msg)
        if a_pose["start_ns"] + 2e8 < s.stamp_ns < a_pose["end_ns"] - 2e8:
            forces.setdefault(m.topic, []).append(quat_to_matrix(s.quat) @ s.accel)
    assert len(forces) == 4
    for topic, f in forces.items():
        mean = np.mean(f, axis=0)
        assert np.linalg.norm(mean) == pytest.approx(9.81, abs=0.1), topic
        assert mean[2] / np.linalg.norm(mean) > 0.999, topic


def _records(bag: Path) -> list[tuple[str, int, bytes]]:
    with open(next(bag.glob("*.mcap")), "rb") as f:
        return [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages()]


def test_same_seed_same_bag(tmp_path: Path, bag: Path) -> None:
    again = tmp_path / "again"
    write_capture_bag(CaptureSession(CONFIG), again, progress=False)
    assert _records(bag) == _records(again)  # the files differ only in the bag's name
    assert (bag / TRUTH_FILE).read_bytes() == (again / TRUTH_FILE).read_bytes()
    with np.load(bag / LABELS_FILE) as a, np.load(again / LABELS_FILE) as b:
        assert a.files == b.files and all(np.array_equal(a[k], b[k]) for k in a.files)
    other = tmp_path / "other"
    lip_rig(["make-bag", "--scenario", "walk", "--seconds", "13", "--seed", "6", "--columns", "512", "--quiet",
             "--out", str(other)])
    assert _records(other) != _records(bag)


def test_cli_refuses_existing_output(bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert lip_rig(["make-bag", "--out", str(bag), "--quiet"]) == 2
    assert "exists" in capsys.readouterr().err
