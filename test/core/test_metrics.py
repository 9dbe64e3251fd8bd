"""Evaluation metrics on hand-made cases: each has a known answer."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.core import metrics
from lip_ros.core.body import BodyModel
from lip_ros.core.body_surface import BodySurface
from lip_ros.core.rotations import axis_angle_to_matrix, rot_z
from lip_ros.core.skeleton import NUM_JOINTS, forward_kinematics, load_skeleton

RNG = np.random.default_rng(7)
SKELETON = load_skeleton().scaled(1.04)
BODY = BodyModel(SKELETON, girth=1.1)
REST_ROT = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))


@pytest.fixture(scope="module")
def surface() -> BodySurface:
    return BodySurface(BODY, 1500, seed=3)


def random_pose(scale: float = 0.4) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations and joint positions of a random pose of the test skeleton, pelvis at (3, 1, 0)."""
    local = axis_angle_to_matrix(RNG.normal(size=(NUM_JOINTS, 3)) * scale)
    return forward_kinematics(SKELETON, local, np.array([3.0, 1.0, 0.0]))


def test_mpjpe_is_root_relative_and_averages_over_joints():
    _, pos = random_pose()
    np.testing.assert_allclose(metrics.mpjpe(pos[None] + [1.0, 2.0, 3.0], pos[None]), [0.0], atol=1e-12)
    moved = pos.copy()
    moved[5] += [0.0, 0.24, 0.0]
    np.testing.assert_allclose(metrics.mpjpe(moved[None], pos[None]), [0.24 / NUM_JOINTS])


def test_pa_mpjpe_of_a_rotated_scaled_shifted_copy_is_zero():
    _, pos = random_pose()
    copy = 1.3 * pos @ axis_angle_to_matrix(np.array([0.3, -1.2, 0.5])).T + [4.0, -2.0, 1.0]
    np.testing.assert_allclose(metrics.pa_mpjpe(copy[None], pos[None]), [0.0], atol=1e-9)
    assert metrics.mpjpe(copy[None], pos[None])[0] > 0.05
    bent = copy.copy()
    bent[20] += [0.1, 0.0, 0.0]  # a deformation no similarity removes
    assert 0.0 < metrics.pa_mpjpe(bent[None], pos[None])[0] < metrics.mpjpe(bent[None], pos[None])[0]


def test_pa_mpjpe_does_not_reflect():
    _, pos = random_pose()
    mirrored = pos * [-1.0, 1.0, 1.0]  # a reflection is not a rotation: the error stays
    assert metrics.pa_mpjpe(mirrored[None], pos[None])[0] > 0.01


def test_angular_error_is_the_geodesic_angle():
    glob, _ = random_pose()
    turned = rot_z(np.deg2rad(30.0)) @ glob
    np.testing.assert_allclose(np.rad2deg(metrics.angular_error(turned[None], glob[None])), [30.0])
    wrapped = rot_z(np.deg2rad(350.0)) @ glob  # the short way round
    np.testing.assert_allclose(np.rad2deg(metrics.angular_error(wrapped[None], glob[None])), [10.0])


def test_translation_error():
    np.testing.assert_allclose(metrics.translation_error(np.array([[3.0, 4.0, 0.0]]), np.zeros((1, 3))), [5.0])


def test_jitter_of_constant_velocity_is_zero_and_of_a_cubic_its_jerk():
    t = np.arange(20) * 0.1
    start = RNG.normal(size=(1, NUM_JOINTS, 3))
    velocity = RNG.normal(size=(1, NUM_JOINTS, 3))
    assert metrics.jitter(start + t[:, None, None] * velocity, 0.1) == pytest.approx(0.0, abs=1e-6)
    cubic = np.zeros((20, NUM_JOINTS, 3))
    cubic[..., 2] = t[:, None] ** 3  # jerk 6 m/s^3 along z
    assert metrics.jitter(cubic, 0.1) == pytest.approx(6.0)
    assert np.isnan(metrics.jitter(cubic[:3], 0.1))


def test_surface_chamfer_is_zero_on_the_surface_and_the_offset_off_it(surface):
    _, rest_pos = forward_kinematics(SKELETON, REST_ROT)
    on = surface.points(REST_ROT, rest_pos)
    assert metrics.surface_chamfer(on, BODY, REST_ROT, rest_pos) == pytest.approx(0.0, abs=1e-9)
    out = on + 0.02 * surface.normals(REST_ROT)
    assert metrics.surface_chamfer(out, BODY, REST_ROT, rest_pos) == pytest.approx(0.02, rel=0.05)
    with pytest.raises(ValueError):
        metrics.surface_chamfer(np.zeros((0, 3)), BODY, REST_ROT, rest_pos)


def test_icp_recovers_a_known_offset(surface):
    glob, pos = random_pose(0.2)
    body = surface.points(glob, pos)
    facing = np.einsum("nc,nc->n", surface.normals(glob), -body) > 0.0  # the side a LiDAR at the origin sees
    offset = np.array([0.09, -0.06, 0.04])
    seen = body[facing][RNG.permutation(int(facing.sum()))[:300]] + offset
    np.testing.assert_allclose(metrics.icp_translation(seen, body[facing], iterations=30), offset, atol=2e-3)


def test_body_surface_rests_on_the_capsules_and_moves_rigidly_with_the_body(surface):
    _, rest_pos = forward_kinematics(SKELETON, REST_ROT)
    np.testing.assert_allclose(BODY.surface_distance(surface.points(REST_ROT, rest_pos), REST_ROT, rest_pos), 0.0,
                               atol=1e-9)
    glob, pos = random_pose()
    turn, shift = axis_angle_to_matrix(np.array([0.2, 1.0, -0.4])), np.array([1.0, -2.0, 0.5])
    moved = surface.points(turn @ glob, pos @ turn.T + shift)
    np.testing.assert_allclose(moved, surface.points(glob, pos) @ turn.T + shift, atol=1e-9)
    # posed, the points stay on (or within a few cm of) the surface: exact on one-bone capsules
    assert np.median(np.abs(BODY.surface_distance(surface.points(glob, pos), glob, pos))) < 1e-6


def test_body_surface_points_follow_their_bones(surface):
    glob, pos = random_pose()
    bent = glob.copy()
    bent[SKELETON.index("left_wrist")] = axis_angle_to_matrix(np.array([0.0, 0.0, 1.0])) @ bent[
        SKELETON.index("left_wrist")]
    moved = np.linalg.norm(surface.points(bent, pos) - surface.points(glob, pos), axis=1) > 1e-9
    assert 0 < moved.sum() < 0.1 * surface.count  # only the hand's points move
