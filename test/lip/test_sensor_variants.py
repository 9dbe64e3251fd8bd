"""The LIP pipeline on rig captures that break the rig's own conventions, against the same capture recorded the
rig's default way: accuracy within 1.3x (issue "LIP on real sensors"). Each variant is the same motion, body, scene
and IMUs (same seed); only what the variant changes differs.

Variants so far: ouster-ros's ``os_lidar`` frame (column 0 along +x) with the performer straight ahead, across the
sweep's seam; a mounting yaw with the performer to the side; a tripod pitched 8 deg down and rolled 3 deg; a tripod
at 0.6 m; one at 2.5 m, pitched and rolled; performers of 1.45 m and 2.0 m; DOTs with inertial headings of their
own; DOTs stamped on arrival, each 20-60 ms late (their latencies configured, or estimated online); all of them at
once. These compare the network's translation; the surface fit's (the default) is tested on each variant at the end.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest

from lip_ros.core import metrics
from lip_ros.core.imu_sync import SyncConfig
from lip_ros.lip.batch import process_bag_batch
from lip_ros.lip.dot_latency import LatencyConfig
from lip_ros.lip.evaluation.captures import load_capture
from lip_ros.lip.nets.lip_model import LipModel
from lip_ros.lip.pipeline import LipPipeline, PipelineConfig
from lip_ros.lip.surface_fit import SURFACE_FIT
from lip_ros.rig.bag import write_capture_bag
from lip_ros.rig.capture import CaptureConfig, CaptureSession

pytestmark = pytest.mark.usefixtures("one_torch_thread")

#: The standard capture: a 14 s walk at 7 m, 512 columns, the rig's default column convention (column 0 along -x).
STANDARD = CaptureConfig(scenario="walk", seconds=14.0, seed=4, columns=512, distance_m=7.0)
VARIANTS = {
    "os_lidar, performer across the seam": {"column0_azimuth_deg": 0.0, "bearing_deg": 0.0},
    "mounting yaw 37 deg, performer to the side": {"column0_azimuth_deg": 37.0, "bearing_deg": -60.0},
    "tripod pitched 8 deg down, rolled 3 deg": {"lidar_pitch_deg": 8.0, "lidar_roll_deg": 3.0},
    "tripod at 0.6 m": {"lidar_height_m": 0.6},
    "tripod at 2.5 m, pitched 8 deg, rolled -3 deg": {"lidar_height_m": 2.5, "lidar_pitch_deg": 8.0,
                                                      "lidar_roll_deg": -3.0},
    "performer 1.45 m": {"body_scale": 0.84},
    "performer 2.0 m": {"body_scale": 1.16},
    # an OS1 in a 20 Hz mode: the network, trained at 10 Hz, fed interleaved 10 Hz sequences: 13.3 mm against the
    # standard's 13.0 (as one sequence 18.5 mm, and a 20 s walk at 6 m through lip_process_bag 23.7 mm against
    # 15.6 at 10 Hz; interleaved 15.8; session 40)
    "LiDAR at 20 Hz": {"rate_hz": 20.0},
}
#: DOTs stamped on arrival: each its own latency, plus jitter.
LATE_DOTS = {"imu_latency_ms": (20.0, 60.0), "imu_latency_jitter_ms": 5.0}
MAX_RATIO = 1.3


#: With the surface fit, a variant's translation error within this many times the standard capture's (it takes
#: the standard capture from 1.9 to 0.8 cm, the variants from 1.8-2.5 to 0.8-1.3 cm; docs/lip/transfer.md).
MAX_RATIO_FITTED = 1.6


@functools.cache
def _model(surface_fit: bool) -> LipModel:
    return LipModel.load(surface_fit=SURFACE_FIT if surface_fit else None)


@functools.cache
def errors(changes: tuple[tuple[str, float], ...], out: Path, dot_latency: bool = False, estimate: bool = True,
           surface_fit: bool = False) -> tuple[float, float, int]:
    """MPJPE (mm), root translation error (cm) and posed frames of the capture ``STANDARD`` with ``changes``,
    after the calibration poses, through the batch pipeline (``dot_latency``: told the DOTs' true latencies;
    ``estimate``: the DOT latencies estimated online). The conventions' tests compare the network's translation
    (``surface_fit`` False): the fit's own accuracy on each variant has its test below."""
    bag = out / "_".join(f"{k}{v}" for k, v in changes) if changes else out / "standard"
    session = CaptureSession(dataclasses.replace(STANDARD, **dict(changes)))
    if not bag.exists():
        write_capture_bag(session, bag, progress=False)
    capture = load_capture(bag)
    latency = tuple(round(s.latency_s * 1e9) for s in session.imu_truth.specs) if dot_latency else ()
    config = PipelineConfig(sync=SyncConfig(latency_ns=latency), latency=LatencyConfig(enabled=estimate))
    model = _model(surface_fit)  # set for the training's rate: the pose stage measures the LiDAR's from the stamps
    results = list(process_bag_batch(LipPipeline(model, config, pose_batch=64), bag))
    posed = [r for r in results if r.pose is not None and r.pose.stamp_ns >= capture.motion_start_ns]
    gt = np.array([np.abs(capture.gt_stamp_ns - r.pose.stamp_ns).argmin() for r in posed])
    joints = np.stack([r.pose.joint_pos for r in posed])
    return (1000.0 * float(metrics.mpjpe(joints, capture.gt_joint_pos[gt]).mean()),
            100.0 * float(metrics.translation_error(joints[:, 0], capture.gt_joint_pos[gt, 0]).mean()), len(posed))


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("variants")


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_variant_poses_as_accurately_as_the_standard_capture(name, bags):
    mpjpe, trans, posed = errors(tuple(sorted(VARIANTS[name].items())), bags)
    mpjpe0, trans0, posed0 = errors((), bags)
    print(f"\n{name}: MPJPE {mpjpe:.1f} mm, translation {trans:.2f} cm, {posed} posed "
          f"(standard: {mpjpe0:.1f} mm, {trans0:.2f} cm, {posed0} posed)")
    assert posed >= posed0 - 2  # locked and calibrated as early, never lost
    assert mpjpe <= MAX_RATIO * mpjpe0, f"{mpjpe:.1f} mm vs {mpjpe0:.1f} mm"


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_variant_places_the_body_as_accurately_as_the_standard_capture(name, bags):
    _, trans, _ = errors(tuple(sorted(VARIANTS[name].items())), bags)
    _, trans0, _ = errors((), bags)
    assert trans <= MAX_RATIO * trans0, f"{trans:.2f} cm vs {trans0:.2f} cm"


def test_dots_with_headings_of_their_own_pose_as_accurately_once_walking_gave_the_ankles(bags):
    """DOTs not heading-reset together (each within +-90 deg of the others): the wrists calibrate from the poses,
    the ankles from the first strides of walking; from then on poses within MAX_RATIO of the same capture with the
    headings reset (20 s captures: the standard one's walk is too short to leave time after the strides)."""
    longer = (("seconds", 20.0),)
    mpjpe, trans, posed = errors((("imu_heading_spread_deg", 90.0), *longer), bags)
    mpjpe0, trans0, posed0 = errors(longer, bags)
    print(f"\nown headings: MPJPE {mpjpe:.1f} mm, translation {trans:.2f} cm, {posed} posed "
          f"(reset: {mpjpe0:.1f} mm, {trans0:.2f} cm, {posed0} posed)")
    assert posed >= posed0 - 70  # calibrated within 7 s of walking (10 Hz)
    assert mpjpe <= MAX_RATIO * mpjpe0 and trans <= MAX_RATIO * trans0


def test_late_dots_pose_as_accurately_with_their_latencies_configured(bags):
    """DOTs stamped on arrival 20-60 ms late (each its own latency, jittered): with ``dot_latency_s`` (here the
    rig's true latencies) within MAX_RATIO (the 14 s capture is too short for the online estimate)."""
    changes = tuple(sorted(LATE_DOTS.items()))
    mpjpe, trans, posed = errors(changes, bags, dot_latency=True, estimate=False)
    mpjpe0, trans0, posed0 = errors((), bags)
    print(f"\nlate DOTs: MPJPE {mpjpe:.1f} mm configured (standard {mpjpe0:.1f} mm)")
    assert posed >= posed0 - 2
    assert mpjpe <= MAX_RATIO * mpjpe0 and trans <= MAX_RATIO * trans0


#: A 20 s walk at 1024 columns, long enough for the DOT latencies' online estimate (about 6 s of walking).
WALK_1024 = (("columns", 1024), ("seconds", 20.0))


def test_late_dots_pose_as_accurately_with_their_latencies_estimated(bags):
    """The same late DOTs, their latencies not configured but estimated online: within MAX_RATIO of the capture
    with DOTs stamped on time, and better than without the estimate."""
    changes = tuple(sorted(LATE_DOTS.items())) + WALK_1024
    mpjpe, trans, posed = errors(changes, bags)
    unestimated, _, _ = errors(changes, bags, estimate=False)
    mpjpe0, trans0, posed0 = errors(WALK_1024, bags)
    print(f"\nlate DOTs: MPJPE {mpjpe:.1f} mm estimated, {unestimated:.1f} mm not (on time {mpjpe0:.1f} mm)")
    assert posed >= posed0 - 2
    assert mpjpe <= MAX_RATIO * mpjpe0 and trans <= MAX_RATIO * trans0
    assert mpjpe < unestimated


#: Everything at once, as a first real capture would be: ouster-ros's frame, a tripod at 1.6 m tilted 4 / -2 deg,
#: DOTs with headings of their own and stamped 20-60 ms late (not configured: estimated), a 1.92 m performer
#: calibrating turned 20 deg from the sensor, an OS1-128 at its default 1024 columns.
ALL_AT_ONCE = {"column0_azimuth_deg": 0.0, "bearing_deg": 25.0, "lidar_height_m": 1.6, "lidar_pitch_deg": 4.0,
               "lidar_roll_deg": -2.0, "imu_heading_spread_deg": 90.0, "body_scale": 1.12, "facing_deg": 20.0,
               **LATE_DOTS}


def test_everything_at_once_poses_as_accurately_as_the_standard_capture(bags):
    """All the real-sensor conventions in one 20 s walk against the same walk recorded the rig's default way."""
    mpjpe, trans, posed = errors(tuple(sorted(ALL_AT_ONCE.items())) + WALK_1024, bags)
    mpjpe0, trans0, posed0 = errors(WALK_1024, bags)
    print(f"\nall at once: MPJPE {mpjpe:.1f} mm, translation {trans:.2f} cm, {posed} posed "
          f"(standard: {mpjpe0:.1f} mm, {trans0:.2f} cm, {posed0} posed)")
    assert posed >= posed0 - 70  # the ankles' headings need a few strides of walking
    assert mpjpe <= MAX_RATIO * mpjpe0 and trans <= MAX_RATIO * trans0


#: Each variant's changes and those of the standard capture it is compared with.
FITTED = {**{name: (tuple(sorted(changes.items())), ()) for name, changes in VARIANTS.items()},
          "own DOT headings": ((("imu_heading_spread_deg", 90.0), ("seconds", 20.0)), (("seconds", 20.0),)),
          "all at once": (tuple(sorted(ALL_AT_ONCE.items())) + WALK_1024, WALK_1024)}


@pytest.mark.parametrize("name", sorted(FITTED))
def test_the_surface_fit_places_every_variant_better_than_the_network(name, bags):
    """With the surface fit each variant's translation is better than the network's alone and within
    MAX_RATIO_FITTED of the standard capture's with the fit (a 20 s walk for the DOT headings and all at once)."""
    variant, standard = FITTED[name]
    _, fitted, _ = errors(variant, bags, surface_fit=True)
    _, network, _ = errors(variant, bags)
    _, fitted0, _ = errors(standard, bags, surface_fit=True)
    print(f"\n{name}: translation {fitted:.2f} cm with the surface fit, {network:.2f} cm without "
          f"(standard with it: {fitted0:.2f} cm)")
    assert fitted < network
    assert fitted <= MAX_RATIO_FITTED * fitted0, f"{fitted:.2f} cm vs {fitted0:.2f} cm"
