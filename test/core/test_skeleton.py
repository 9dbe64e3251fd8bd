"""Skeleton loading, forward kinematics (numpy and torch), rotation conversions, URDF."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from lip_ros.core import rotations as rot
from lip_ros.core import torch_kinematics as tk
from lip_ros.core.skeleton import (
    NUM_JOINTS,
    forward_kinematics,
    joint_angles_to_local_rotations,
    joint_state_names,
    load_skeleton,
    local_rotations_to_joint_angles,
)
from lip_ros.core.urdf import URDF_FILE, skeleton_urdf
from lip_ros.resources import params_path


@pytest.fixture(scope="module")
def skel():
    return load_skeleton()


def random_local(rng: np.random.Generator, shape: tuple[int, ...] = ()) -> np.ndarray:
    return rot.axis_angle_to_matrix(rng.normal(scale=0.6, size=shape + (NUM_JOINTS, 3)))


def test_skeleton_matches_contract(skel):
    assert skel.names[0] == "pelvis" and skel.names[23] == "right_hand"
    assert skel.names[skel.parents[20]] == "left_elbow"
    np.testing.assert_allclose(skel.offsets[4], [0.0343, -0.3752, -0.0045])
    assert skel.lip_imus["left_wrist"]["bone_joint"] == "left_elbow"
    assert len(skel.suit_imus) == 17
    assert set(skel.calibration_poses) == {"a_pose", "t_pose"}


def test_fk_by_hand(skel):
    """Rest pose: positions are sums of offsets; a 90 deg knee bend swings the ankle forward."""
    local = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
    glob, pos = forward_kinematics(skel, local, root_pos=np.array([1.0, 2.0, 3.0]))
    expected_ankle = np.array([1.0, 2.0, 3.0]) + skel.offsets[1] + skel.offsets[4] + skel.offsets[7]
    np.testing.assert_allclose(pos[7], expected_ankle)
    np.testing.assert_allclose(glob, local)

    knee = skel.index("left_knee")
    local[knee] = rot.rot_x(np.pi / 2)  # flexion: a positive turn about the body's left axis (x)
    _, pos = forward_kinematics(skel, local)
    shank = pos[7] - pos[4]
    off = skel.offsets[7]
    np.testing.assert_allclose(shank, [off[0], -off[2], off[1]], atol=1e-12)
    assert shank[2] < -0.3  # the ankle went behind the knee


def test_a_pose_arm_points_down_60_degrees(skel):
    _, pos = forward_kinematics(skel, skel.pose_local_rotations("a_pose"))
    for side, sign in (("left", 1.0), ("right", -1.0)):
        arm = pos[skel.index(side + "_wrist")] - pos[skel.index(side + "_shoulder")]
        horizontal = np.hypot(arm[0], arm[2])
        elevation = np.degrees(np.arctan2(arm[1], horizontal))
        assert elevation == pytest.approx(-60.0, abs=1.0)  # the rest arm is within 0.5 deg of horizontal
        assert np.sign(arm[0]) == sign
    _, t_pos = forward_kinematics(skel, skel.pose_local_rotations("t_pose"))
    t_arm = t_pos[20] - t_pos[16]
    assert abs(t_arm[1]) < 0.01  # T-pose: the arm is horizontal


def test_fk_batched_equals_loop(skel):
    rng = np.random.default_rng(0)
    local = random_local(rng, (2, 3))
    root = rng.normal(size=(2, 3, 3))
    glob, pos = forward_kinematics(skel, local, root)
    for a in range(2):
        for b in range(3):
            g1, p1 = forward_kinematics(skel, local[a, b], root[a, b])
            np.testing.assert_allclose(glob[a, b], g1)
            np.testing.assert_allclose(pos[a, b], p1)


def test_torch_fk_matches_numpy(skel):
    rng = np.random.default_rng(1)
    local = random_local(rng, (5,))
    root = rng.normal(size=(5, 3))
    scale = 1.1
    glob, pos = forward_kinematics(skel, local, root, offsets=skel.offsets * scale)
    st = tk.SkeletonTensors(skel, dtype=torch.float64)
    tglob, tpos = tk.forward_kinematics(st, torch.from_numpy(local), torch.from_numpy(root), st.offsets * scale)
    np.testing.assert_allclose(tglob.numpy(), glob, atol=1e-12)
    np.testing.assert_allclose(tpos.numpy(), pos, atol=1e-12)


def test_rotation_round_trips():
    rng = np.random.default_rng(2)
    r = rot.axis_angle_to_matrix(rng.normal(size=(50, 3)))
    np.testing.assert_allclose(rot.quat_to_matrix(rot.matrix_to_quat(r)), r, atol=1e-12)
    np.testing.assert_allclose(rot.axis_angle_to_matrix(rot.matrix_to_axis_angle(r)), r, atol=1e-12)
    np.testing.assert_allclose(rot.six_d_to_matrix(rot.matrix_to_six_d(r)), r, atol=1e-12)
    np.testing.assert_allclose(rot.euler_zyx_to_matrix(rot.matrix_to_euler_zyx(r)), r, atol=1e-12)
    t6 = tk.matrix_to_six_d(torch.from_numpy(r))
    np.testing.assert_allclose(tk.six_d_to_matrix(t6 + 0.0).numpy(), r, atol=1e-12)
    np.testing.assert_allclose(t6.numpy(), rot.matrix_to_six_d(r))
    # 6D of a perturbed matrix is projected back onto SO(3)
    noisy = rot.six_d_to_matrix(rot.matrix_to_six_d(r) + rng.normal(scale=0.05, size=(50, 6)))
    np.testing.assert_allclose(noisy @ np.swapaxes(noisy, -1, -2), np.broadcast_to(np.eye(3), noisy.shape), atol=1e-12)
    # Z-Y-X means Rz @ Ry @ Rx and matches scipy's intrinsic 'ZYX'
    a = np.array([0.3, -0.4, 1.1])
    np.testing.assert_allclose(rot.euler_zyx_to_matrix(a), rot.rot_z(a[0]) @ rot.rot_y(a[1]) @ rot.rot_x(a[2]),
                               atol=1e-12)
    assert rot.geodesic_angle(rot.rot_x(0.0), rot.rot_x(0.7)) == pytest.approx(0.7)


def test_joint_state_encoding_round_trip(skel):
    names = joint_state_names(skel)
    assert len(names) == 69 and names[:3] == ["left_hip_rz", "left_hip_ry", "left_hip_rx"]
    rng = np.random.default_rng(3)
    local = random_local(rng, (4,))
    angles = local_rotations_to_joint_angles(local)
    assert angles.shape == (4, 69)
    back = joint_angles_to_local_rotations(angles, root_rot=local[:, 0])
    np.testing.assert_allclose(back, local, atol=1e-10)


def _urdf_fk(root: ET.Element, angles: dict[str, float]) -> dict[str, np.ndarray]:
    """Link origins from the URDF alone, by walking its joints from the root link."""
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}
    poses: dict[str, tuple[np.ndarray, np.ndarray]] = {"pelvis": (np.eye(3), np.zeros(3))}

    def pose(link: str) -> tuple[np.ndarray, np.ndarray]:
        if link not in poses:
            j = joints[link]
            r_p, p_p = pose(j.find("parent").get("link"))
            xyz = np.array([float(v) for v in j.find("origin").get("xyz").split()])
            axis = np.array([float(v) for v in j.find("axis").get("xyz").split()])
            r_j = Rotation.from_rotvec(axis * angles[j.get("name")]).as_matrix()
            poses[link] = (r_p @ r_j, p_p + r_p @ xyz)
        return poses[link]

    return {link: pose(link)[1] for link in list(joints) + ["pelvis"]}


def test_urdf_matches_fk_and_joint_state_names(skel):
    root = ET.fromstring(skeleton_urdf(skel))
    revolute = [j.get("name") for j in root.findall("joint") if j.get("type") == "revolute"]
    names = joint_state_names(skel)
    assert sorted(revolute) == sorted(names)
    rng = np.random.default_rng(4)
    local = random_local(rng)
    local[0] = np.eye(3)
    angles = local_rotations_to_joint_angles(local)
    link_pos = _urdf_fk(root, dict(zip(names, angles)))
    _, pos = forward_kinematics(skel, local)
    for j, name in enumerate(skel.names):
        np.testing.assert_allclose(link_pos[name], pos[j], atol=1e-5, err_msg=name)


def test_urdf_bone_visuals_point_at_children(skel):
    root = ET.fromstring(skeleton_urdf(skel))
    pelvis = next(link for link in root.findall("link") if link.get("name") == "pelvis")
    for visual in pelvis.findall("visual")[1:]:
        origin = visual.find("origin")
        mid = np.array([float(v) for v in origin.get("xyz").split()])
        rpy = [float(v) for v in origin.get("rpy").split()]
        length = float(visual.find("geometry/cylinder").get("length"))
        axis = Rotation.from_euler("xyz", rpy).as_matrix()[:, 2]
        np.testing.assert_allclose(axis * length / 2, mid, atol=1e-5)


def test_shipped_urdf_is_up_to_date(skel):
    shipped = params_path(URDF_FILE).read_text(encoding="utf-8")
    assert shipped == skeleton_urdf(skel), "run: python -m lip_ros.tools.make_urdf"
