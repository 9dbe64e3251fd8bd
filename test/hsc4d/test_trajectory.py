"""The HSC4D trajectory on rig captures: the jump from each sweep's ground (lip_ros.hsc4d.sweep_height), the map
frame (lip_ros.hsc4d.map_frame), and the whole live pipeline with its refinement against the truth and the
baselines (lip_ros.hsc4d.trajectory, lip_ros.hsc4d.evaluation)."""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace

import numpy as np
import pytest

from lip_ros.core.frames import R_L_M_FACING_X
from lip_ros.core.metrics import align_yaw_translation
from lip_ros.core.rotations import axis_angle_to_matrix, geodesic_angle, rot_x, rot_z
from lip_ros.hsc4d.evaluation import (
    ABLATIONS,
    METHODS,
    body_metrics,
    capture_sweeps,
    map_metrics,
    run_capture,
    trajectory_metrics,
)
from lip_ros.hsc4d.jump_sync import JumpSync
from lip_ros.hsc4d.lidar_odometry import LidarOdometry, OdometryConfig, WearerFilter
from lip_ros.hsc4d.map_frame import estimate_map_frame
from lip_ros.hsc4d.mount import HipMountPrior, SpinCheckConfig
from lip_ros.hsc4d.refinement import CaptureRefiner, RefinementConfig
from lip_ros.hsc4d.suit_track import SuitTrack, axes_columns, odometry_axes
from lip_ros.hsc4d.sweep_height import sweep_height
from lip_ros.hsc4d.trajectory import PINNED, TrajectoryConfig, TrajectoryPipeline
from lip_ros.rig.site_capture import SiteCapture, SiteCaptureConfig


def _cloud(frame) -> tuple[np.ndarray, np.ndarray]:
    """Returns (N, 3) in L and their times (ns) of a rig frame."""
    p = frame.points.ravel()
    ok = np.isfinite(p["x"])
    return (np.stack([p["x"][ok], p["y"][ok], p["z"][ok]], 1).astype(np.float64),
            frame.stamp_ns + p["t"][ok].astype(np.int64))


@pytest.mark.parametrize("seed, tilt_deg", [(0, 30.0), (11, 30.0), (0, 15.0)])
def test_each_sweeps_ground_gives_the_jump_and_the_suits_clock(seed, tilt_deg):
    """The sensor's height above the ground from each sweep alone (no odometry, no IMU) follows the truth
    through the A-pose, the jump and the first steps: median error under 3 mm, at most 4 cm (at the landing,
    whose sweep sees the ground from heights 0.1 m apart; measured 0.5 mm and 3.2 cm), and the jump sync on it
    finds the suit's clock offset within 10 ms (measured 0.8 and 2.8 ms). Also with the hip LiDAR mounted 19.5
    deg off the nominal tilt the method is told (the rig variant at 15 deg, seed 0; the sync lost it before the
    ground's search cone was widened from 20 to 35 deg)."""
    capture = SiteCapture(SiteCaptureConfig(seed=seed, seconds=14.0, columns=512, mount_tilt_up_deg=tilt_deg))
    pelvis = capture.suit_streams()["pelvis"]
    offset = int(round(capture.suit.clock_offset_s * 1e9))
    wearer, sync, rng = WearerFilter(), JumpSync(), np.random.default_rng(0)
    fed, errors = 0, []
    for k, frame in capture.frames(0, 90):
        arrival = capture.frame_stamp_ns(k) + capture.lidar.period_ns + offset
        while fed < len(pelvis.stamp_ns) and pelvis.stamp_ns[fed] <= arrival:
            sync.add_suit(int(pelvis.stamp_ns[fed]), pelvis.accel[fed])
            fed += 1
        points, point_ns = _cloud(frame)
        keep = wearer.keep(points)
        t_ns, height = sweep_height(points[keep], point_ns[keep], rng)
        sync.add_lidar(t_ns, height)
        T_W_L = capture.lidar_poses(np.array([t_ns]))[0]
        errors.append(height - (T_W_L[2, 3] - capture.terrain.surface_height(T_W_L[None, :2, 3])[0]))
    assert np.median(np.abs(errors)) < 0.003 and np.abs(errors).max() < 0.04
    assert sync.offset_ns is not None and abs(sync.offset_ns - offset) < 10_000_000


def test_the_map_frame_stands_on_the_ground_under_the_first_pelvis_position():
    """After 1.5 s of the A-pose: up within 0.2 deg of gravity (the suit's, through the nominal mounting, is
    3-5 deg off; measured 0.03), the origin's height under the pelvis within 4 cm (the mounting's lever arm is
    off by up to 3 cm), x level and forward; the same points turned by 18 deg (a mounting that far off its
    nominal tilt) still give up from the ground, within 0.2 deg; turned by 35 deg (no longer the suit's gravity,
    as a start on a steep slope) they make it fall back to the suit's gravity, and say so."""
    capture = SiteCapture(SiteCaptureConfig(seed=3, seconds=14.0, columns=512))
    odometry = capture.suit_odometry()
    track = SuitTrack(capacity=len(odometry.stamp_ns))
    track.set_offset(int(round(capture.suit.clock_offset_s * 1e9)))
    for s, p, q in zip(odometry.stamp_ns, odometry.position, odometry.quat):
        track.add(s, p, q)
    lidar = LidarOdometry()
    half = capture.lidar.period_ns // 2
    for _, frame in capture.frames(0, 15):
        lidar.register(*_cloud(frame), frame.stamp_ns + half, None, track)
    first = capture.frame_stamp_ns(0) + half
    T_O_P0 = track.mount.T_L_M
    frame = estimate_map_frame(lidar.map_points(), T_O_P0, track.up_in_lidar(first), np.random.default_rng(0))
    assert frame.up_source == "ground" and 2.0 < frame.ground_vs_suit_deg < 6.0
    T_W_L0 = capture.lidar_poses(np.array([first]))[0]
    T_O_map = np.linalg.inv(frame.T_map_O)
    up_true = T_W_L0[:3, :3].T @ [0.0, 0.0, 1.0]
    assert np.degrees(np.arccos(T_O_map[:3, 2] @ up_true)) < 0.2
    pelvis = capture.truth(np.array([(first - capture.epoch_ns) * 1e-9])).pelvis[0]
    true_height = pelvis[2] - capture.terrain.surface_height(pelvis[None, :2])[0]
    assert abs(frame.pelvis_height_m - true_height) < 0.04
    assert abs(T_O_map[:3, 0] @ up_true) < 0.01 and T_O_map[:3, 0] @ T_O_P0[:3, 2] > 0.9
    turn = rot_x(np.radians(18.0))  # the same sensor mounted 18 deg further off the nominal tilt
    turned = estimate_map_frame(lidar.map_points() @ turn.T, T_O_P0, track.up_in_lidar(first),
                                np.random.default_rng(0))
    assert turned.up_source == "ground" and 8.0 < turned.ground_vs_suit_deg < 25.0  # 8: the old limit
    assert np.degrees(np.arccos(np.linalg.inv(turned.T_map_O)[:3, 2] @ (turn @ up_true))) < 0.2
    tilted = lidar.map_points() @ rot_x(np.radians(35.0)).T
    fallback = estimate_map_frame(tilted, T_O_P0, track.up_in_lidar(first), np.random.default_rng(0))
    assert fallback.up_source == "suit" and fallback.ground_vs_suit_deg > 25.0


def test_the_live_trajectory_and_its_refinement_track_the_pelvis_far_better_than_the_suit():
    """A 24 s capture at 512 columns played in arrival order: the pipeline holds the sweeps until the jump, finds the
    suit's clock within 10 ms, and its live and refined pelvis trajectories stay within 10 cm of the truth (ATE after
    the yaw + translation fit on the 5 s after the landing), while the suit alone and kiss-icp alone (the baselines) are
    more than twice as far off. The body on them, live and optimised with the scene (the standing feet of each held):
    checkpoints within 10 cm, foot contact within 5 cm, MPJPE under 20 mm, sliding no worse than the suit's own (the
    issue's targets are 10 cm, 3 cm, 20 mm and 1 cm a frame over held-out 90 s walks, measured by hsc4d_eval; this short
    one at 512 columns is looser). The site map
    rebuilt from the refined trajectory (S_opt) is, drift forgiven, no farther from the true surface than the live
    one (median / p90 1.44 / 4.21 against 1.51 / 4.37 cm; 1.56 / 4.30 when each sweep moved by the refined pelvis
    less the live fused one, before session 35). The body's size from the standing pelvis's height is 1.3 % off
    the truth here; the legs' length from the walk within 1 %: the live graph's body at its end, the optimised and
    refined bodies' (measured 0.4, 0.6 and 0.4 %)."""
    capture = SiteCapture(SiteCaptureConfig(seed=0, seconds=24.0, columns=512))
    run = run_capture(capture)
    assert abs(run.offset_ns - run.true_offset_ns) < 10_000_000
    assert run.hand_eye is not None and np.degrees(geodesic_angle(run.hand_eye, run.true_mount[:3, :3])) < 1.5
    assert run.t_s[0] < 0.2  # the held sweeps were registered too, from the first
    metrics = trajectory_metrics(run)
    assert metrics["live"]["ate_m"] < 0.1 and metrics["refined"]["ate_m"] < 0.1
    assert metrics["baseline1_suit"]["ate_m"] > 2.0 * metrics["live"]["ate_m"]
    assert metrics["baseline2_lidar"]["ate_m"] > 2.0 * metrics["live"]["ate_m"]  # kiss-icp alone: 16 cm here
    assert np.isfinite([v for m in metrics.values() for v in m.values() if not np.isnan(v)]).all()
    body = body_metrics(run, capture.terrain)
    assert set(body) == set(METHODS + ABLATIONS) | {"truth"}
    for name in ("live", "live_optimised", "refined"):  # their standing feet held
        assert body[name]["checkpoint_m"] < 0.1 and body[name]["contact_m"] < 0.05 and body[name]["mpjpe_mm"] < 20
        assert body[name]["sliding_m"] <= body["baseline1_suit"]["sliding_m"]
    for baseline in ("baseline1_suit", "baseline2_lidar"):
        assert body[baseline]["contact_m"] > 2.0 * body["refined"]["contact_m"], baseline
    assert 0.0 < run.sole_m < 0.1 and len(run.window_s) >= 2
    size = {name: abs(v / run.body_scales["truth"] - 1.0) for name, v in run.body_scales.items()}
    assert size["height"] > 0.01  # the walk's legs, from the second window on:
    assert size["live"] < 0.01 and size["live_optimised"] < 0.01 and size["refined"] < 0.01
    scene = map_metrics(run, capture.terrain)
    for name in ("live", "refined"):
        m = scene[name]
        assert m["map_median_m"] < 0.05 and m["map_p90_m"] < 0.2 and m["map_far_fraction"] < 0.05, (name, m)
        assert 0.0 < m["map_shape_median_m"] < 0.05 and m["map_shape_p90_m"] < 0.2, (name, m)
    assert scene["live"]["map_points"] == scene["refined"]["map_points"]  # S_opt: S_live's points, each sweep moved
    for stat in ("map_shape_median_m", "map_shape_p90_m"):  # drift forgiven, S_opt no blurrier than S_live
        assert scene["refined"][stat] <= scene["live"][stat], (stat, scene)
    assert 0.0 < run.refine_s < run.t_s[-1] - run.t_s[0]  # faster than the capture


def test_a_mounting_far_off_its_nominal_tilt_is_levelled_before_the_first_output():
    """The rig variant with the hip LiDAR mounted 19.5 deg off the nominal tilt the method is told (seed 0 at 15
    deg): the map frame's up comes from the ground, levelling puts the body's axis within 0.5 deg of where the
    true mounting has it (the turn about it comes from the walk, over more than this capture's 5 m), and every
    output, the first ones included (registered before the map frame was fixed), is posed through the levelled
    mounting: the odometry's pelvis is its sensor pose through the mounting of 2 s in, and the first one stands
    within 3 cm of the true pelvis height (the lever arm's vertical part, up to 3 cm off, stays nominal). Before,
    the sweeps of the first second kept the nominal mounting's pelvis, 3.6 cm lower, and the body was scaled
    from it. The walk's turns (hand-eye) agree with the levelled mounting within the 3 deg the status allows;
    a mounting levelled 5 deg off (as on a sloping start) is reported."""
    capture = SiteCapture(SiteCaptureConfig(seed=0, seconds=24.0, columns=512, mount_tilt_up_deg=15.0))
    refiner = CaptureRefiner()
    pipeline, steps = refiner.pipeline, []
    for _, stamp_ns, points, point_ns in capture_sweeps(capture, refiner):
        steps += pipeline.add_sweep(points, point_ns, stamp_ns)
    frame = pipeline.map_frame
    assert frame is not None and frame.up_source == "ground" and frame.ground_vs_suit_deg > 15.0
    true_R = capture.mount.R_M_L
    assert np.degrees(geodesic_angle(HipMountPrior().R_M_L, true_R)) > 19.0
    # the mounting (T_L_M) each output was posed through; at 2 s, registered after levelling, before the walk
    mounts = [np.linalg.inv(s.lidar) @ s.lidar_pelvis for s in steps]
    levelled = mounts[next(k for k, s in enumerate(steps) if s.stamp_ns - steps[0].stamp_ns > 2e9)]
    axis = np.array([0.0, 1.0, 0.0])  # the body's axis in the pelvis frame, as the sensor sees it
    assert np.degrees(np.arccos(np.clip((levelled[:3, :3] @ axis) @ (true_R.T @ axis), -1.0, 1.0))) < 0.5
    first = [T for T, s in zip(mounts, steps, strict=True) if s.stamp_ns - steps[0].stamp_ns < 1e9]
    assert len(first) >= 9
    for T_L_M in first:
        np.testing.assert_allclose(T_L_M, levelled, atol=1e-9)
    t_s = (steps[0].stamp_ns - capture.epoch_ns) * 1e-9
    pelvis = capture.truth(np.array([t_s])).pelvis[0]
    true_height = pelvis[2] - capture.terrain.surface_height(pelvis[None, :2])[0]
    assert abs(steps[0].pelvis[2, 3] - true_height) < 0.03
    assert abs(frame.pelvis_height_m - steps[0].pelvis[2, 3]) < 1e-9
    assert pipeline.mount_disagreement_deg is not None and pipeline.mount_disagreement_deg < 3.0
    assert pipeline.status == "tracking"
    pipeline._set_mount_rotation(pipeline.T_L_M[:3, :3].T @ rot_x(np.radians(5.0)))
    assert 2.0 < pipeline.mount_disagreement_deg < 8.0 and "that ground was not level" in pipeline.status


@pytest.mark.parametrize("how", ["told", "found", "not found"])
def test_a_lidar_worn_spun_about_its_axis_is_found_from_the_ground_and_reported(how):
    """A hip LiDAR worn spun 180 deg about its own axis (its +x, the connector, to the back: the same tilt, another
    way round). Told so (``HipMountPrior.spin_deg``), it is tracked as the rig's own: the live pelvis within 6 cm
    of the truth after the ATE's alignment, nearly every registration believed, the status "tracking". Not told,
    the ground of the first sweeps shows the spin (:class:`SpinCheck`), the mounting is spun by it before the jump
    sync, and the capture is tracked as well, with the status naming ``mount_spin_deg`` (a WARN on the node).
    With the check off, levelling and the walk's yaw correct a few degrees, not 180: the suit's motion through
    the mounting points the wrong way, most registrations are not believed, and the status says so (measured:
    told 2.3 cm, 96 % believed at least over 5 s; found 3.0 cm; not found 33 % believed over 5 s at the least,
    47 % the median)."""
    capture = SiteCapture(SiteCaptureConfig(seed=0, seconds=20.0, columns=512, mount_spin_deg=180.0))
    check = SpinCheckConfig(min_error_deg=360.0) if how == "not found" else SpinCheckConfig()
    refiner = CaptureRefiner(RefinementConfig(trajectory=TrajectoryConfig(
        mount=HipMountPrior(spin_deg=180.0 if how == "told" else 0.0), spin_check=check)))
    pipeline, steps, shares, warned = refiner.pipeline, [], [], False
    for _, stamp_ns, points, point_ns in capture_sweeps(capture, refiner):
        steps += pipeline.add_sweep(points, point_ns, stamp_ns)
        if pipeline.believed_share is not None:
            shares.append(pipeline.believed_share)
            warned |= "mount_spin_deg" in pipeline.status
    t = np.array([(s.stamp_ns - capture.epoch_ns) * 1e-9 for s in steps])
    assert len(steps) > 150 and shares
    if how == "not found":
        assert min(shares) < 0.5 and warned
        return
    landing = next((b - capture.epoch_ns) * 1e-9 for name, _, b in capture.phases_ns() if name == "jump")
    truth = capture.truth(t).pelvis
    position = np.array([s.pelvis[:3, 3] for s in steps])
    T = align_yaw_translation(position, truth, (t >= landing) & (t <= landing + 5.0))
    error = np.linalg.norm(position @ T[:3, :3].T + T[:3, 3] - truth, axis=1)
    assert np.sqrt(np.mean(error**2)) < 0.06
    assert min(shares) > 0.9
    assert np.degrees(geodesic_angle(np.linalg.inv(pipeline.T_L_M)[:3, :3], capture.mount.R_M_L)) < 3.0
    if how == "told":
        assert pipeline.spin.correction_deg == 0.0 and pipeline.status == "tracking" and not warned
    else:
        assert abs(abs(pipeline.spin.correction_deg) - 180.0) < 10.0
        assert warned and pipeline.status.startswith("tracking; the ground at the start shows the LiDAR spun")


@pytest.mark.parametrize("check_hip", [True, False])
def test_a_lidar_worn_on_the_other_hip_is_found_from_the_wearers_body(check_hip):
    """"About 0.15 m to the side" does not say which hip, and the lever arm shows only when the body turns about the
    vertical (the rig's walks: at their first corner, 19-20 s in on seed 0; the live start stood 0.3 m aside
    until then, live ATE 19 cm on 30 s captures). Worn on the left hip with the nominal lever arm on the right, the
    ground and the site are seen in the first sweeps where the wearer's torso and thighs would stand on the right
    hip (:class:`SideCheck`): the lever arm is mirrored before the jump sync, the wearer's filter and the lever's
    estimate start from there, the capture is tracked as the left hip's, and the status names ``mount_lever_m``
    (measured: 3.1 cm). With the check off (``check_hip`` false) the lever arm stays on the right hip through
    these 20 s (8.1 cm)."""
    capture = SiteCapture(SiteCaptureConfig(seed=3, seconds=20.0, columns=512, mount_lever_m=(0.15, 0.0, -0.1)))
    statuses: list[str] = []
    ate, steps, pipeline = _live_ate(capture, TrajectoryConfig(check_hip=check_hip),
                                     lambda p: statuses.append(p.status))
    warned = any("mount_lever_m" in status for status in statuses)
    assert steps > 150
    if not check_hip:
        assert not pipeline.side.mirrored and not warned and pipeline.lever_m[0] < -0.1 and ate > 0.05
        assert "check_mount_hip false" in pipeline.side.status and "as configured (the ground" in pipeline.spin.status
        return
    assert pipeline.side.mirrored and pipeline.side.lever_m == (0.15, 0.0, -0.1) and warned
    assert pipeline.odometry.wearer.T_M_L[0, 3] > 0.1 and abs(pipeline.lever_m[0] - capture.mount.lever_m[0]) < 0.05
    assert ate < 0.06


def _live_ate(capture: SiteCapture, config: TrajectoryConfig, watch: Callable[[TrajectoryPipeline], None] | None = None
              ) -> tuple[float, int, TrajectoryPipeline]:
    """The live pelvis's ATE (m; the 4-DoF fit on the 5 s after the landing) over ``capture``, the steps posed and
    the pipeline (``watch`` sees it after each sweep)."""
    refiner = CaptureRefiner(RefinementConfig(trajectory=config))
    pipeline, steps = refiner.pipeline, []
    for _, stamp_ns, points, point_ns in capture_sweeps(capture, refiner):
        steps += pipeline.add_sweep(points, point_ns, stamp_ns)
        if watch is not None:
            watch(pipeline)
    t = np.array([(s.stamp_ns - capture.epoch_ns) * 1e-9 for s in steps])
    landing = next((b - capture.epoch_ns) * 1e-9 for name, _, b in capture.phases_ns() if name == "jump")
    truth = capture.truth(t).pelvis
    position = np.array([s.pelvis[:3, 3] for s in steps])
    T = align_yaw_translation(position, truth, (t >= landing) & (t <= landing + 5.0))
    ate = float(np.sqrt(np.mean(np.linalg.norm(position @ T[:3, :3].T + T[:3, 3] - truth, axis=1) ** 2)))
    return ate, len(steps), pipeline


@pytest.mark.parametrize(("scene", "pinned"), [("open", True), ("open", False), ("site", True)])
def test_on_an_open_field_the_registrations_keep_the_prediction_across_the_ground(scene, pinned):
    """An open field (the rig's "open" scene: the ground, the terrace, its stairs and ramp, nothing else) pins down a
    sweep's height and tilt, not its shifts across the ground nor its turn about the vertical: there the odometry
    keeps the prediction (the pelvis IMU's turn, the suit's steps) and counts the registrations that left a shift
    wholly to it (measured on seed 3, 30 s at 512 columns: ATE 6.0 cm, 286 of 300; the rig's own site: 4.3 cm,
    none); with every registration kept as registered (both bands (0, 0)), ICP slides across the stair flight and
    the terrace (18.8 cm)."""
    odometry = OdometryConfig() if pinned else OdometryConfig(pinned_information=(0.0, 0.0),
                                                              pinned_tilt_information=(0.0, 0.0))
    capture = SiteCapture(SiteCaptureConfig(seed=3, seconds=30.0, columns=512, scene=scene))
    ate, _, pipeline = _live_ate(capture, TrajectoryConfig(odometry=odometry))
    if not pinned:
        assert ate > 0.15
    elif scene == "open":
        assert ate < 0.10 and pipeline.counts[PINNED] > 200
    else:
        assert ate < 0.10 and not pipeline.counts[PINNED]


def test_the_suit_odometrys_axes_are_told_from_its_pelvis_imu():
    """``odometry_axes``: an odometry within ``max_tilt_deg`` of its pelvis IMU's up is read as it is (None), one in
    a ROS base_link's axes (its pelvis up about 90 deg off; any yaw, a few degrees of error) gives the turn that
    reads it in the segment's (a standing wearer's: the segment's y up), and one tilted by 45 deg, not a turn of
    the axes, is said (its tilt) but not turned."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        R_I_P = rot_z(rng.uniform(-np.pi, np.pi)) @ R_L_M_FACING_X @ rot_x(rng.normal(0.0, 0.1))  # y up, leaning
        error = axis_angle_to_matrix(rng.normal(size=3) * np.radians(2.0))
        tilt, axes = odometry_axes(R_I_P @ error, R_I_P, 10.0)
        assert tilt < 10.0 and axes is None
        tilt, axes = odometry_axes(R_I_P @ error @ R_L_M_FACING_X.T, R_I_P, 10.0)
        assert abs(tilt - 90.0) < 20.0
        np.testing.assert_array_equal(axes, R_L_M_FACING_X)
        tilt, axes = odometry_axes(R_I_P @ rot_x(np.radians(45.0)), R_I_P, 10.0)
        assert abs(tilt - 45.0) < 1e-6 and axes is None
    assert axes_columns(R_L_M_FACING_X) == "+y, +z, +x"


@pytest.mark.parametrize("convention", ["model", "base_link"])
def test_a_suit_odometry_oriented_otherwise_than_the_pelvis_segment_is_reported(convention):
    """The contract gives the suit segments' orientations in its model axes (x left, y up, z forward); it does not
    say how ``/mocap/odometry`` is oriented, and the method takes it for the pelvis segment's. Published in a
    ROS base_link's axes instead (x forward, y left, z up), its pelvis's up is 90 deg from the pelvis IMU's at
    the start: the status says so, and the odometry's orientations are read in the segment's axes from then on
    (the turn of the axes nearest the two orientations' difference), so that the map frame is found and the
    capture tracked as with the rig's own odometry, which agrees with the IMU within a degree (without the
    turn, the map frame was never found: "the first pelvis pose faces straight up or down")."""
    capture = SiteCapture(SiteCaptureConfig(seed=3, seconds=14.0, columns=512, odometry_axes=convention))
    refiner = CaptureRefiner()
    pipeline, steps = refiner.pipeline, []
    for _, stamp_ns, points, point_ns in capture_sweeps(capture, refiner):
        steps += pipeline.add_sweep(points, point_ns, stamp_ns)
    assert pipeline.map_frame is not None and len(steps) > 100
    t = np.array([(s.stamp_ns - capture.epoch_ns) * 1e-9 for s in steps])
    position, truth = np.array([s.pelvis[:3, 3] for s in steps]), capture.truth(t).pelvis
    T = align_yaw_translation(position, truth, np.ones(len(t), dtype=bool))
    assert np.sqrt(np.mean(np.sum((position @ T[:3, :3].T + T[:3, 3] - truth) ** 2, axis=1))) < 0.05
    if convention == "model":
        assert pipeline.odometry_tilt_deg < 1.0 and pipeline.odometry_axes is None
        assert "/mocap/odometry" not in pipeline.status
    else:
        assert abs(pipeline.odometry_tilt_deg - 90.0) < 5.0
        np.testing.assert_array_equal(pipeline.odometry_axes, R_L_M_FACING_X)
        assert "/mocap/odometry" in pipeline.status and "x, y, z: +y, +z, +x" in pipeline.status


@pytest.mark.parametrize("seed, tilt_deg", [(11, 45.0), (5, 30.0)])
def test_a_wearer_standing_still_after_the_landing_stays_where_they_stand(seed, tilt_deg):
    """From 0.5 s before the jump's end to 0.5 s into the walk the wearer stands still: the odometry's pelvis has
    risen or sunk since the A-pose as the truth within 3 cm (measured 0.4 cm with the hip LiDAR tilted up 45 deg,
    seed 11; 1.8 cm on the rig's 30 deg, seed 5), and at most 3 registrations in a row are not believed (0 and 1).
    Without the pelvis IMU's still detector (``still_accel_mps2`` near 0) the 45 deg one sank 15.5 cm there: the
    sensor looking down keeps 180 points after the wearer filter, ICP slid sideways, 14 registrations in a row were
    not believed and the guesses carried on a velocity fitted over the landing. With the speed rule measured from
    the last registered sweep instead of the last believed one, seed 5's guess stood 2-7 cm high and 2 cm aside
    after the landing and 10-14 registrations in a row, to the walk, were refused (each took the guess's error back
    as 0.3-0.4 m/s of motion; the map grew on the guesses)."""
    capture = SiteCapture(SiteCaptureConfig(seed=seed, seconds=30.0, mount_tilt_up_deg=tilt_deg))
    phases = {name: ((a - capture.epoch_ns) * 1e-9, (b - capture.epoch_ns) * 1e-9)
              for name, a, b in capture.phases_ns()}
    refiner = CaptureRefiner()
    steps = []
    for _, stamp_ns, points, point_ns in capture_sweeps(capture, refiner):
        if (stamp_ns - capture.epoch_ns) * 1e-9 > phases["walk"][0] + 1.0:
            break
        steps += refiner.pipeline.add_sweep(points, point_ns, stamp_ns)
    t = np.array([(s.stamp_ns - capture.epoch_ns) * 1e-9 for s in steps])
    position, truth = np.array([s.lidar_pelvis[:3, 3] for s in steps]), capture.truth(t).pelvis
    standing = np.flatnonzero((t > phases["jump"][1] - 0.5) & (t < phases["walk"][0] + 0.5))
    assert len(standing) >= 8
    rise = (position[standing, 2] - position[0, 2]) - (truth[standing, 2] - truth[0, 2])  # since the A-pose
    assert np.abs(rise).max() < 0.03
    in_a_row = longest = 0
    for k in standing:
        in_a_row = in_a_row + 1 if steps[k].rejected else 0
        longest = max(longest, in_a_row)
    assert longest <= 3, [(round(t[k], 2), steps[k].rejected) for k in standing]


def test_without_a_jump_the_pipeline_holds_a_bounded_number_of_sweeps_and_says_why():
    """Sweeps of a flat ground with no jump: nothing is output, at most ``hold_s`` of sweeps are held and the
    rest are dropped and counted, the status says what it waits for; bad suit samples are refused and counted,
    a non-finite point is dropped, a sweep not after the last is refused."""
    rng = np.random.default_rng(0)
    config = TrajectoryConfig(hold_s=1.0)
    pipeline = TrajectoryPipeline(config)
    ground = np.column_stack([rng.uniform(-8.0, 8.0, (4000, 2)), np.zeros(4000)])
    # the sensor 0.95 m up, looking where the nominal mounting says: ground points in L
    R_W_L = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) @ config.mount.R_M_L
    points = (ground - [0.0, 0.0, 0.95]) @ R_W_L
    points[0] = np.nan
    for k in range(30):
        stamp = 10**18 + k * 100_000_000
        assert pipeline.add_sweep(points, np.full(len(points), stamp), stamp) == []
    assert len(pipeline._held) <= 11 and pipeline.counts["sweeps dropped waiting for the jump"] >= 19
    assert "waiting for the jump" in pipeline.status and pipeline.offset_ns is None
    assert pipeline.add_suit_odometry(10**18, [0.0, 0.0, np.nan], [0.0, 0.0, 0.0, 1.0]) == "not finite"
    assert pipeline.counts["suit odometry rejected: not finite"] == 1
    nan_imu = SimpleNamespace(stamp_ns=10**18, quat=np.array([0.0, 0.0, 0.0, 1.0]), gyro=np.zeros(3),
                              accel=np.array([0.0, np.nan, 9.81]))
    assert pipeline.add_pelvis_imu(nan_imu) is not None and not pipeline.jump._suit
    with pytest.raises(ValueError):
        pipeline.add_sweep(points, np.full(len(points), 10**18), 10**18)


def test_the_suit_covers_a_sweep_only_without_gaps_in_its_pelvis_samples():
    """A sweep waits until the pelvis samples cover it all along, not only until the newest is past its end: after
    a window of samples 300 ms late, on-time samples arrive before the late ones."""
    from lip_msgs_py import imu_sample

    pipeline = TrajectoryPipeline()
    offset = 400_000_000  # the suit's clock ahead of the LiDAR's
    pipeline.jump.offset_ns = offset
    pipeline.rotation.set_offset(offset)
    pipeline.suit.set_offset(offset)
    ms = 1_000_000
    sweep = (1000 * ms, 1100 * ms)  # LiDAR clock
    for t in range(1000, 1600, 10):  # suit clock (ms)
        assert pipeline.add_suit_odometry(t * ms, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])) is None
    late = set(range(1300, 1460, 10))  # these pelvis samples come last
    for t in [t for t in range(1000, 1600, 10) if t not in late] + sorted(late):
        if t == min(late):  # the newest samples are past the sweep, the late ones missing
            assert not pipeline.suit_covers(*sweep)
        assert pipeline.add_pelvis_imu(imu_sample(t * ms, "pelvis", quat=(0.0, 0.0, 0.0, 1.0), gyro=(0.0, 0.0, 0.0),
                                                  accel=(0.0, 0.0, 9.81))) is None
    assert pipeline.suit_covers(*sweep)
    assert not pipeline.suit_covers(1100 * ms, 1300 * ms)  # past the newest samples


def test_the_shape_error_forgives_what_the_five_seconds_fit_turned():
    """A trajectory of the right shape, turned 0.5 deg about a point of the fitted seconds plus 1 cm of noise in
    them only: the ATE (fit on those seconds) grows along a 60 m walk, the shape error (fit on the whole) does
    not."""
    from types import SimpleNamespace

    t = np.arange(0.0, 60.0, 0.1)
    truth = np.column_stack([np.where(t < 30, t, 30.0), np.where(t < 30, 0.0, t - 30.0), np.full_like(t, 0.9)])
    yaw = np.radians(0.5)
    turn = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    estimate = (truth - truth[20]) @ turn.T + truth[20]
    estimate[:50, 1] += np.random.default_rng(0).normal(0.0, 0.01, 50)  # the fitted seconds
    run = SimpleNamespace(t_s=t, landing_s=0.0, truth=truth, ground=np.zeros_like(t),
                          positions={"turned": estimate})
    m = trajectory_metrics(run)["turned"]
    assert m["ate_m"] > 0.04 and m["shape_m"] < 0.01
