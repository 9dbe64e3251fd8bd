"""The capsule body model: dimensions, scaling, signed distance, surface sampling, ray casting."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.core.body import BodyModel
from lip_ros.core.capsule_rays import first_hits
from lip_ros.core.skeleton import forward_kinematics, load_skeleton


@pytest.fixture(scope="module")
def skeleton():
    return load_skeleton()


def rest(skeleton, pose: str = "t_pose"):
    """Global rotations and joint positions of a calibration pose, in M (pelvis at the origin)."""
    return forward_kinematics(skeleton, skeleton.pose_local_rotations(pose))


def extent(body: BodyModel, pose) -> tuple[np.ndarray, np.ndarray]:
    a, b, r = body.capsules(*pose)
    ends = np.concatenate([a, b])
    rr = np.concatenate([r, r])[:, None]
    return (ends - rr).min(axis=0), (ends + rr).max(axis=0)


def test_rest_pose_looks_like_a_person(skeleton):
    body = BodyModel(skeleton)
    lo, hi = extent(body, rest(skeleton))
    assert lo[1] == pytest.approx(-skeleton.pelvis_height, abs=0.01)  # soles on the floor
    assert 1.65 < hi[1] - lo[1] < 1.8  # stature
    assert 1.6 < hi[0] - lo[0] < 1.8  # T-pose arm span
    assert 0.25 < hi[2] - lo[2] < 0.35  # depth: the feet stick out in front
    pelvis = body.radius[body.names.index("pelvis")]
    assert pelvis > body.radius[body.names.index("left_thigh")] > body.radius[body.names.index("left_forearm")]


def test_scale_and_girth(skeleton):
    pose = rest(skeleton, "a_pose")
    a, b, r = BodyModel(skeleton).capsules(*pose)
    big = skeleton.scaled(1.1)
    a2, b2, r2 = BodyModel(big).capsules(*forward_kinematics(big, big.pose_local_rotations("a_pose")))
    np.testing.assert_allclose(a2, 1.1 * a, atol=1e-12)
    np.testing.assert_allclose(b2, 1.1 * b, atol=1e-12)
    np.testing.assert_allclose(r2, 1.1 * r)
    a3, b3, r3 = BodyModel(skeleton, girth=1.3).capsules(*pose)
    np.testing.assert_allclose(a3, a)
    np.testing.assert_allclose(r3, 1.3 * r)
    with pytest.raises(ValueError):
        BodyModel(skeleton, girth=0.0)


def test_capsules_follow_the_pose(skeleton):
    body = BodyModel(skeleton)
    glob, pos = rest(skeleton, "a_pose")
    rot = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    shift = np.array([4.0, 1.0, -0.3])
    a, b, r = body.capsules(glob, pos)
    a2, b2, _ = body.capsules(rot @ glob, pos @ rot.T + shift)
    np.testing.assert_allclose(a2, a @ rot.T + shift, atol=1e-12)
    np.testing.assert_allclose(b2, b @ rot.T + shift, atol=1e-12)
    batched = body.capsules(np.stack([glob, rot @ glob]), np.stack([pos, pos @ rot.T + shift]))[0]
    np.testing.assert_allclose(batched[1], a2)
    i = body.names.index("left_forearm")
    elbow, wrist = skeleton.index("left_elbow"), skeleton.index("left_wrist")
    np.testing.assert_allclose([a[i], b[i]], [pos[elbow], pos[wrist]])


def test_surface_distance_sign_and_value(skeleton):
    body = BodyModel(skeleton)
    glob, pos = rest(skeleton)
    inside = pos[[skeleton.index(j) for j in ("pelvis", "spine2", "neck", "head", "left_knee", "left_elbow")]]
    assert np.all(body.surface_distance(inside, glob, pos) < 0.0)
    a, b, r = body.capsules(glob, pos)
    head = body.names.index("head")
    top = b[head] + np.array([0.0, r[head], 0.0])
    above = top + np.array([[0.0, 0.2, 0.0], [0.0, 1e-3, 0.0]])
    np.testing.assert_allclose(body.surface_distance(above, glob, pos), [0.2, 1e-3], atol=1e-12)
    assert body.surface_distance(top - [0.0, 0.01, 0.0], glob, pos)[0] == pytest.approx(-0.01)


def test_sample_surface_on_the_outer_surface(skeleton):
    body = BodyModel(skeleton)
    pose = rest(skeleton, "a_pose")
    pts = body.sample_surface(*pose, n=5000, rng=np.random.default_rng(1))
    assert pts.shape == (5000, 3)
    # zero distance: on some capsule, and inside none (no buried points where capsules overlap)
    np.testing.assert_allclose(body.surface_distance(pts, *pose), 0.0, atol=1e-9)
    again = body.sample_surface(*pose, n=5000, rng=np.random.default_rng(1))
    np.testing.assert_array_equal(pts, again)
    centre, radius = body.bounding_sphere(*pose)
    assert np.all(np.linalg.norm(pts - centre, axis=1) <= radius + 1e-9)
    assert radius < 1.1


def test_sample_surface_is_uniform_by_area(skeleton):
    body = BodyModel(skeleton)
    pose = rest(skeleton)
    pts = body.sample_surface(*pose, n=200_000, rng=np.random.default_rng(2))
    a, b, r = body.capsules(*pose)

    def end_cap(name: str) -> int:
        """Samples on the free hemisphere at the b end of a capsule."""
        k = body.names.index(name)
        axis = (b[k] - a[k]) / np.linalg.norm(b[k] - a[k])
        return int(np.sum((np.abs(np.linalg.norm(pts - b[k], axis=1) - r[k]) < 1e-9) & ((pts - b[k]) @ axis > 0.0)))

    head, hand = end_cap("head"), end_cap("left_hand")
    expected = (r[body.names.index("head")] / r[body.names.index("left_hand")]) ** 2
    assert hand > 300
    assert head / hand == pytest.approx(expected, rel=0.15)


def test_raycast_agrees_with_the_distance(skeleton):
    body = BodyModel(skeleton)
    rot = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # facing a LiDAR at the origin
    glob, pos = rest(skeleton, "a_pose")
    glob, pos = rot @ glob, pos @ rot.T + [4.0, 0.0, 0.0]
    rng = np.random.default_rng(3)
    targets = pos[0] + rng.uniform([-0.3, -1.0, -1.0], [0.3, 1.0, 0.9], (1500, 3))
    dirs = targets / np.linalg.norm(targets, axis=1, keepdims=True)
    t, cos, refl = body.raycast(np.zeros(3), dirs, glob, pos)
    hit = np.isfinite(t)
    assert 0.1 < hit.mean() < 0.5
    np.testing.assert_allclose(body.surface_distance(t[hit, None] * dirs[hit], glob, pos), 0.0, atol=1e-9)
    assert np.all((cos[hit] > 0.0) & (cos[hit] <= 1.0)) and np.all(cos[~hit] == 0.0)
    assert set(np.unique(refl[hit])) <= set(body.reflectivity) and np.all(refl[~hit] == 0.0)
    # nothing of the body lies on a ray before its hit, nor anywhere on a missed ray
    s = np.linspace(3.0, 5.0, 250)
    steps = s[None, :] * np.ones((len(dirs), 1))
    before = np.where(np.isfinite(t)[:, None], steps < t[:, None] - 1e-6, True)
    march = steps[..., None] * dirs[:, None, :]
    sd = body.surface_distance(march[before], glob, pos)
    assert sd.min() > -1e-9


def test_raycast_head_on(skeleton):
    body = BodyModel(skeleton)
    glob, pos = rest(skeleton)
    a, b, r = body.capsules(glob, pos)
    k = body.names.index("head")
    centre = 0.5 * (a[k] + b[k])
    origin = centre + np.array([0.0, 0.0, 5.0])  # in front of the face
    t, cos, refl = body.raycast(origin, np.array([[0.0, 0.0, -1.0]]), glob, pos)
    assert t[0] == pytest.approx(5.0 - r[k])
    assert cos[0] == pytest.approx(1.0)
    assert refl[0] == body.reflectivity[k]


def test_first_hits_meets_the_nearest_capsule_and_of_equal_ones_the_last():
    a = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 0.0], [3.0, -1.0, 0.0]])
    b = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [3.0, 1.0, 0.0]])  # 0 and 1 share an end sphere; 2 behind them
    r = np.array([0.2, 0.2, 0.5])
    dirs = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
    origins = [np.array([-5.0, 0.0, 0.0]), np.array([-5.0, -0.5, 0.0]), np.array([-5.0, 0.0, 0.0]),
               np.array([-5.0, 0.0, 0.0])]
    got = [first_hits(o, d[None], a, b, r) for o, d in zip(origins, dirs, strict=True)]
    assert got[0][0][0] == pytest.approx(4.8) and got[0][1][0] == 1  # the shared sphere: the later capsule
    assert got[1][0][0] == pytest.approx(4.8) and got[1][1][0] == 0  # capsule 0's side, not 2's behind it
    assert [g[0][0] for g in got[2:]] == [np.inf, np.inf] and [g[1][0] for g in got[2:]] == [-1, -1]  # past, behind


def test_first_hits_refuses_capsules_of_mismatched_shapes():
    a = np.zeros((3, 3))
    with pytest.raises(ValueError, match="r \\(K,\\)"):
        first_hits(np.zeros(3), np.array([[1.0, 0.0, 0.0]]), a, a + 1.0, np.ones(2))  # compiled: no bounds checks
