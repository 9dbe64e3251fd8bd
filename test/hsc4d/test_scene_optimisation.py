"""The scene-aware optimisation on a synthetic walk whose ground, stance and true feet are known."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest

from lip_ros.hsc4d.background_optimiser import BackgroundOptimiser
from lip_ros.hsc4d.leg_scale import LegScale, standing_steps
from lip_ros.hsc4d.scene_optimisation import (
    TERMS,
    NoGroundYet,
    SceneOptimisationConfig,
    SceneOptimiser,
    feet_offsets,
    fit_foot_planes,
    optimise_sequence,
    sole_height,
    stance_from_suit,
    stance_runs,
    walk_leg_ratio,
    without,
)

RATE_HZ = 10.0
SOLE_M = 0.03  # the foot joint above its sole
SPEED = 1.0  # m/s


def _walk(seconds: float = 10.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Times (N,), the true pelvis (N, 3), the true feet (N, 2, 3) and which foot stands (N, 2) of a straight walk
    on z = 0: each foot stands 0.6 s and swings 0.6 s (moving 1.2 m), the other out of phase."""
    t = np.arange(0.0, seconds, 1.0 / RATE_HZ)
    pelvis = np.column_stack([SPEED * t, np.zeros_like(t), np.full_like(t, 0.95)])
    feet = np.zeros((len(t), 2, 3))
    stance = np.zeros((len(t), 2), dtype=bool)
    for foot, (phase, side) in enumerate(((0.0, 0.1), (0.6, -0.1))):
        cycle = ((t + phase) % 1.2) / 1.2  # 0..0.5 stance, 0.5..1 swing
        plant = SPEED * (t + phase - cycle * 1.2) + 0.3  # where this cycle's stance stands
        swing = np.clip((cycle - 0.5) / 0.5, 0.0, 1.0)
        feet[:, foot, 0] = plant + 1.2 * swing
        feet[:, foot, 1] = side
        feet[:, foot, 2] = SOLE_M + 0.1 * np.sin(np.pi * swing)
        stance[:, foot] = cycle < 0.5
    return t, pelvis, feet, stance


def _ground(rng: np.random.Generator) -> np.ndarray:
    """The map: ground points on z = 0 every 10 cm, 5 mm of noise."""
    x, y = np.meshgrid(np.arange(-1.0, 12.0, 0.1), np.arange(-1.0, 1.0, 0.1))
    points = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    return points + rng.normal(0.0, 0.005, points.shape)


def _poses(positions: np.ndarray) -> np.ndarray:
    out = np.tile(np.eye(4), (len(positions), 1, 1))
    out[:, :3, 3] = positions
    return out


def _legs(offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Straight legs (identity joint rotations) whose four bones split each foot's offset from the pelvis (N, 2, 3)
    evenly: the legs' rotations (N, 2, 3, 3, 3) and bones (N, 2, 4, 3)."""
    legs = np.tile(np.eye(3), offsets.shape[:2] + (3, 1, 1))
    return legs, np.repeat(offsets[:, :, None, :] / 4.0, 4, axis=2)


def _errors(feet: np.ndarray, stance: np.ndarray) -> tuple[float, float]:
    """Mean |height above the ground - the sole's| and mean step of a standing foot (m)."""
    contact = float(np.abs(feet[..., 2] - SOLE_M)[stance].mean())
    both = stance[1:] & stance[:-1]
    return contact, float(np.linalg.norm(np.diff(feet, axis=0)[both], axis=-1).mean())


@pytest.fixture(scope="module")
def walk():
    rng = np.random.default_rng(0)
    t, pelvis, feet, stance = _walk()
    fused = pelvis + rng.normal(0.0, 0.015, pelvis.shape) + [0.0, 0.0, 0.03]  # LiDAR jitter, 3 cm too high
    suit = pelvis @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T * 1.03  # turned, 3 % long
    return t, pelvis, feet, stance, fused, suit, _ground(rng)


def test_stance_from_the_suit_is_the_still_foot(walk):
    t, _, feet, stance, *_ = walk
    found = stance_from_suit(feet, t, SceneOptimisationConfig().stance_speed_mps)
    assert not (found[:, 0] & found[:, 1]).any()  # one foot at a time, the slower
    assert (found == stance).mean() > 0.9  # central differences blur the first and last frame of a stance


def test_planes_fitted_under_standing_feet_on_a_ramp():
    rng = np.random.default_rng(1)
    slope = np.tan(np.radians(10.0))
    x, y = np.meshgrid(np.arange(0.0, 4.0, 0.1), np.arange(-1.0, 1.0, 0.1))
    points = np.column_stack([x.ravel(), y.ravel(), slope * x.ravel()])
    feet = np.array([[[1.0, 0.1, slope + SOLE_M], [2.0, -0.1, 2 * slope + 0.2]]])
    stance = np.array([[True, False]])
    planes, supported = fit_foot_planes(feet, stance, points, rng, SceneOptimisationConfig())
    assert supported.tolist() == [[True, False]]
    normal = planes[0, 0, :3]
    assert np.degrees(np.arccos(normal[2])) == pytest.approx(10.0, abs=0.5)
    assert normal @ feet[0, 0] + planes[0, 0, 3] == pytest.approx(SOLE_M * np.cos(np.radians(10.0)), abs=0.005)
    assert np.isnan(planes[0, 1]).all()  # not standing: no plane
    nothing, supported = fit_foot_planes(feet, stance, points[:0], rng, SceneOptimisationConfig())
    assert np.isnan(nothing).all() and not supported.any()


def test_a_plane_counts_as_measured_under_the_foot_only_with_ground_points_near_it():
    """An early map (the wearer's body hid the ground they stood on): an arc of ground points 0.45-0.6 m to one
    side, on a 5 deg slope, gives a plane 4 cm above the true ground under the foot: not supported, so the sole
    height waits for a later map; the whole patch's is."""
    rng = np.random.default_rng(2)
    slope = np.tan(np.radians(5.0))
    r, a = np.meshgrid(np.arange(0.0, 0.6, 0.05), np.radians(np.arange(-180.0, 180.0, 10.0)))
    points = np.column_stack([(r * np.cos(a)).ravel(), (r * np.sin(a)).ravel(), np.zeros(r.size)])
    points[:, 2] = slope * (0.5 - points[:, 0])  # rising toward the foot: the true ground (z = 0) at 0.5 m only
    feet = np.array([[[0.0, 0.0, SOLE_M], [1.0, 0.0, 0.2]]])
    stance = np.array([[True, False]])
    config = SceneOptimisationConfig()
    arc = points[(np.hypot(points[:, 0], points[:, 1]) >= 0.45) & (points[:, 0] > 0.2)]
    planes, supported = fit_foot_planes(feet, stance, arc, rng, config)
    assert planes[0, 0, :3] @ feet[0, 0] + planes[0, 0, 3] < SOLE_M - 0.03  # extrapolated: the foot under it
    assert not supported.any() and np.isnan(sole_height(feet, stance & supported, planes))
    flat = points.copy()
    flat[:, 2] = 0.0
    planes, supported = fit_foot_planes(feet, stance, flat, rng, config)
    assert supported.tolist() == [[True, False]]
    assert sole_height(feet, stance & supported, planes) == pytest.approx(SOLE_M, abs=0.002)


def test_sole_height_is_the_median_standing_height(walk):
    t, _, feet, stance, *_ = walk
    planes = np.zeros(stance.shape + (4,))
    planes[..., 2] = 1.0  # z = 0
    assert sole_height(feet, stance, planes) == pytest.approx(SOLE_M)
    assert np.isnan(sole_height(feet, np.zeros_like(stance), planes))


def test_optimisation_puts_the_feet_on_the_ground_and_stops_them_sliding(walk):
    t, pelvis, feet, stance, fused, suit, ground = walk
    offsets = feet - pelvis[:, None]
    start = fused[:, None] + offsets
    config = replace(SceneOptimisationConfig(), window=50)  # two windows: the second continues the first
    result = optimise_sequence(t, _poses(fused), *_legs(offsets), suit, feet, lambda k: ground, config, sole_m=SOLE_M)
    before, after = _errors(start, stance), _errors(result.feet, stance)
    assert before[0] > 0.025 and before[1] > 0.015  # 3 cm high, 1.5 cm of jitter
    # not all of it: the prior (weight 1) holds the pelvis where the landmarks put it against contact (weight 1)
    assert after[0] < 0.75 * before[0]
    assert after[1] < 0.6 * before[1]
    assert np.linalg.norm(result.pelvis[:, :3, 3] - pelvis, axis=1).mean() < np.linalg.norm(fused - pelvis,
                                                                                             axis=1).mean()
    for window in result.windows:  # each term the optimisation weighs went down or stayed
        assert sum(getattr(config, k) * window.after[k] for k in TERMS) < sum(
            getattr(config, k) * window.before[k] for k in TERMS)
    assert np.allclose(np.linalg.det(result.pelvis[:, :3, :3]), 1.0)


def test_each_term_does_its_part(walk):
    """The ablation on the synthetic walk: without contact the feet stay high; without sliding they slide more."""
    t, pelvis, feet, stance, fused, suit, ground = walk
    legs_bones = _legs(feet - pelvis[:, None])
    full = SceneOptimisationConfig()

    def errors(config: SceneOptimisationConfig) -> tuple[float, float]:
        return _errors(optimise_sequence(t, _poses(fused), *legs_bones, suit, feet, lambda k: ground, config,
                                         sole_m=SOLE_M).feet, stance)

    both = errors(full)
    assert errors(without(full, "contact"))[0] > 1.4 * both[0]
    assert errors(without(full, "sliding"))[1] > 1.2 * both[1]


def test_the_legs_bend_to_stop_a_standing_foot_the_suit_moves(walk):
    """The pelvis is where it truly is, but the suit's hips swing each leg 2 deg back and forth (a knee and ankle
    sensor error would do the same): the standing feet slide, 1.7 cm a frame. Turning the legs' joints back holds
    them (the pose prior keeps the rest); with the legs kept as the suit has them (a very high pose weight) they
    slide on. (At 3 deg the stiff legs' steps, 2.6 cm, are mostly beyond the sliding term's Huber bound, which
    pulls their body less: the pelvis 0.71 cm off the truth against 0.83 with a squared term.)"""
    t, pelvis, feet, stance, _, suit, ground = walk
    legs, bones = _legs(feet - pelvis[:, None])
    wobble = np.radians(2.0) * np.sin(2.0 * np.pi * 1.7 * t)  # about y: the foot moves along the walk
    legs[:, :, 0] = _about_y(wobble)[:, None]
    moved = pelvis[:, None] + feet_offsets(np.tile(np.eye(3), (len(t), 1, 1)), legs, bones)
    # the legs' length as given: a wobble of the legs' sensors in step with the walk misleads the walk's ratio (over
    # these 10 s, 1.06 at 2 deg, 1.015 at 1: leg_scale.py)
    config = replace(SceneOptimisationConfig(), window=50, legs_from_walk=False)
    bent = optimise_sequence(t, _poses(pelvis), legs, bones, suit, feet, lambda k: ground, config, sole_m=SOLE_M)
    stiff = optimise_sequence(t, _poses(pelvis), legs, bones, suit, feet, lambda k: ground,
                              replace(config, pose=1e6), sole_m=SOLE_M)
    slide = {name: _errors(f, stance)[1] for name, f in (("suit", moved), ("bent", bent.feet), ("stiff", stiff.feet))}
    assert slide["suit"] > 0.015
    assert slide["bent"] < 0.75 * slide["stiff"]
    # the legs took the suit's error, not the pelvis: it stays nearer the truth, the feet nearer their true offsets
    off = {name: np.linalg.norm(r.pelvis[:, :3, 3] - pelvis, axis=1).mean() for name, r in (("bent", bent),
                                                                                              ("stiff", stiff))}
    assert off["bent"] < 0.65 * off["stiff"]
    true = feet - pelvis[:, None]
    assert (np.linalg.norm(bent.feet - bent.pelvis[:, None, :3, 3] - true, axis=-1).mean()
            < 0.75 * np.linalg.norm(moved - pelvis[:, None] - true, axis=-1).mean())
    assert np.allclose(np.linalg.det(bent.legs), 1.0)


def test_a_foot_the_suit_calls_standing_as_it_lifts_does_not_drag_the_body(walk):
    """The pelvis and legs as they truly are, but the suit's feet two frames late: the stance the suit tells runs two
    frames into each swing, where the foot lifts 20-40 cm a frame. Holding those steps to nothing drags the body
    (squared, as first built: 1.8 cm on average, 7.5 at worst); the sliding term's Huber loss (linear beyond 1 cm a
    frame) bounds their pull (0.7 and 2.2 cm), and the truly standing feet stay nearer the ground."""
    t, pelvis, feet, stance, _, _, ground = walk
    late = np.concatenate([feet[:1], feet[:1], feet[:-2]])
    assert (stance_from_suit(late, t, SceneOptimisationConfig().stance_speed_mps) & ~stance).sum() >= 25
    legs, bones = _legs(feet - pelvis[:, None])
    config = replace(SceneOptimisationConfig(), window=50, legs_from_walk=False)  # the edges alone
    off, contact = {}, {}
    for name, huber_m in (("huber", config.sliding_huber_m), ("squared", 100.0)):
        result = optimise_sequence(t, _poses(pelvis), legs, bones, pelvis, late, lambda k: ground,
                                   replace(config, sliding_huber_m=huber_m), sole_m=SOLE_M)
        error = np.linalg.norm(result.pelvis[:, :3, 3] - pelvis, axis=1)
        off[name], contact[name] = (error.mean(), error.max()), _errors(result.feet, stance)[0]
    assert off["squared"][0] > 0.01  # the edges drag a squared term's body: this test can tell the two apart
    assert off["huber"][0] < 0.6 * off["squared"][0] and off["huber"][1] < 0.5 * off["squared"][1]
    assert contact["huber"] < 0.6 * contact["squared"]


@pytest.mark.parametrize("size", [1.04, 0.96])
def test_the_legs_take_their_length_from_the_walk(walk, size):
    """The body given a size 4 % off (the standing pelvis's height through a lever arm 3-4 cm off): its bones are
    the true legs' over ``size``. From the walk the optimiser finds the legs' length (after the first window: its
    40 pairs are fewer than a ratio needs) and the sole height follows it (the pelvis's height above the ground
    is what was seen): the standing feet where they truly are within 1 mm in the second window, the sole within
    1 mm of the truth (measured 0.3 mm and 0.3 mm). With the bones as given: the feet 4 cm off, the sole 3.5 cm."""
    t, pelvis, feet, stance, _, suit, ground = walk
    legs, bones = _legs((feet - pelvis[:, None]) / size)
    config = replace(SceneOptimisationConfig(), window=50)
    out = {}
    for from_walk in (True, False):
        result = optimise_sequence(t, _poses(pelvis), legs, bones, suit, feet, lambda k: ground,
                                   replace(config, legs_from_walk=from_walk))
        error = np.linalg.norm(result.feet - feet, axis=-1)[50:][stance[50:]].mean()
        out[from_walk] = result, error
    walked, error = out[True]
    assert np.allclose(walked.leg_ratio[:50], 1.0) and np.allclose(walked.leg_ratio[50:], size, rtol=0.002)
    assert error < 0.001 and walked.sole_m == pytest.approx(SOLE_M, abs=0.001)
    given, error = out[False]
    assert np.allclose(given.leg_ratio, 1.0) and error > 0.03 and abs(given.sole_m - SOLE_M) > 0.03


def test_a_window_tried_again_gives_the_walk_each_pair_once(walk):
    """The first window waits for the ground (no map): tried as a partial window (the node's flush), then again
    with more frames; the walk has each standing pair of its frames once. A whole sequence's ratio at once
    (``walk_leg_ratio``, the refinement's) is the legs' length over the bones'."""
    t, pelvis, feet, stance, _, suit, _ = walk
    legs, bones = _legs((feet - pelvis[:, None]) / 1.04)
    optimiser = SceneOptimiser(replace(SceneOptimisationConfig(), window=50))
    for k in range(30):
        optimiser.add(t[k], _poses(pelvis)[k], legs[k], bones[k], suit[k], feet[k])
    with pytest.raises(ValueError, match="no sole height"):
        optimiser.optimise(np.zeros((0, 3)))
    first = len(optimiser.walk)
    for k in range(30, 50):
        optimiser.add(t[k], _poses(pelvis)[k], legs[k], bones[k], suit[k], feet[k])
    with pytest.raises(ValueError, match="no sole height"):
        optimiser.optimise(np.zeros((0, 3)))
    offsets = feet_offsets(np.tile(np.eye(3), (50, 1, 1)), legs[:50], bones[:50])
    once = LegScale()
    once.add(*standing_steps(pelvis[:50], offsets, stance_from_suit(feet[:50], t[:50],
                                                                   SceneOptimisationConfig().stance_speed_mps)))
    assert 0 < first < len(optimiser.walk) == len(once)
    assert walk_leg_ratio(t, _poses(pelvis), legs, bones, feet) == pytest.approx(1.04, rel=0.002)
    with pytest.raises(ValueError, match="must be > 0"):
        SceneOptimiser(leg_ratio=0.0)


def _about_y(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    out = np.tile(np.eye(3), (len(angle), 1, 1))
    out[:, 0, 0], out[:, 0, 2], out[:, 2, 0], out[:, 2, 2] = c, s, -s, c
    return out


def test_sole_height_needs_a_plane_in_the_first_window(walk):
    t, pelvis, feet, stance, fused, suit, _ = walk
    with pytest.raises(ValueError, match="sole height"):
        optimise_sequence(t, _poses(fused), *_legs(feet - pelvis[:, None]), suit, feet, lambda k: np.zeros((0, 3)))


def test_config_checks():
    with pytest.raises(ValueError):
        SceneOptimisationConfig(window=2)
    with pytest.raises(ValueError):
        SceneOptimisationConfig(contact=-1.0)
    with pytest.raises(ValueError):
        SceneOptimisationConfig(sliding_huber_m=0.0)
    with pytest.raises(ValueError, match="unknown term"):
        without(SceneOptimisationConfig(), "gravity")
    assert without(SceneOptimisationConfig(), "sliding").sliding == 0.0


def test_the_live_optimiser_takes_frames_one_window_at_a_time(walk):
    t, pelvis, feet, stance, fused, suit, ground = walk
    config = replace(SceneOptimisationConfig(), window=50, max_wait_s=0.0)  # frames wait two windows
    legs, bones = legs_bones = _legs(feet - pelvis[:, None])
    optimiser = SceneOptimiser(config, sole_m=SOLE_M)
    with pytest.raises(ValueError, match="no frames"):
        optimiser.optimise(ground)
    out = []
    for k in range(len(t)):
        optimiser.add(t[k], _poses(fused)[k], legs[k], bones[k], suit[k], feet[k])
        if optimiser.full:
            out.append(optimiser.optimise(ground)[0].feet)
    assert len(optimiser) == 0 and len(out) == 2
    whole = optimise_sequence(t, _poses(fused), *legs_bones, suit, feet, lambda k: ground, config, sole_m=SOLE_M)
    assert np.allclose(np.concatenate(out), whole.feet)  # the batch tool runs the same code
    # without a sole height and no ground in the map yet, the window waits for a later map, up to two windows
    waiting = SceneOptimiser(config)
    for k in range(waiting.capacity):
        waiting.add(t[k], _poses(fused)[k], legs[k], bones[k], suit[k], feet[k])
    with pytest.raises(RuntimeError, match="optimise or drop"):
        waiting.add(t[0], _poses(fused)[0], legs[0], bones[0], suit[0], feet[0])
    with pytest.raises(ValueError, match="no sole height"):
        waiting.optimise(np.zeros((0, 3)))
    assert len(waiting) == 100 and waiting.optimise(ground)[0].t.shape == (50, 3) and len(waiting) == 50
    assert waiting.drop(10) == 10 and len(waiting) == 40 and waiting.drop() == 40


def test_frames_wait_for_the_ground_a_window_or_max_wait_s_whichever_is_longer(walk):
    """Two 20-frame windows are 4 s at 10 Hz and 2 s at 20 Hz: with max_wait_s 3 s, 40 frames may wait at 10 Hz
    and 60 at 20 Hz; never more than four windows (at 40 Hz: 80, not 120)."""
    t, pelvis, feet, stance, fused, suit, ground = walk
    config = replace(SceneOptimisationConfig(), window=20, max_wait_s=3.0)
    legs, bones = _legs(feet - pelvis[:, None])
    for rate_hz, capacity in ((10.0, 40), (20.0, 60), (40.0, 80)):
        waiting = SceneOptimiser(config)
        for k in range(capacity):
            waiting.add(k / rate_hz, _poses(fused)[k], legs[k], bones[k], suit[k], feet[k])
        assert waiting.capacity == capacity
        with pytest.raises(RuntimeError, match="optimise or drop"):
            waiting.add(capacity / rate_hz, _poses(fused)[0], legs[0], bones[0], suit[0], feet[0])


def test_the_first_window_waits_for_a_map_with_the_ground_under_its_feet(walk):
    """The start's ground is mapped only once the wearer walked away: the batch run, like the node, keeps the first
    window until a map shows it (at most a window later), else leaves it as fused."""
    t, pelvis, feet, stance, fused, suit, ground = walk
    start = fused[:, None] + (feet - pelvis[:, None])
    config = replace(SceneOptimisationConfig(), window=30, max_wait_s=0.0)  # frames wait two windows
    legs_bones = _legs(feet - pelvis[:, None])

    def run(ground_from: int):
        return optimise_sequence(t, _poses(fused), *legs_bones, suit, feet,
                                 lambda k: ground if k >= ground_from else ground[:0], config)

    late = run(45)  # the first window waits for frame 59, the second window's last, and both are optimised
    assert len(late.windows) == 4 and not np.allclose(late.feet[:30], start[:30])
    too_late = run(75)  # not even a window later: the first window stays as fused, the rest is optimised
    assert np.allclose(too_late.feet[:30], start[:30]) and not np.allclose(too_late.feet[30:], start[30:])
    with pytest.raises(ValueError, match="no sole height"):
        run(len(t))


class _GatedMap:
    """A map whose points are handed over only once :attr:`open` is set: a solve that reads it waits there (what a
    window that takes long looks like to its owner), then gets the points or ``error``."""

    def __init__(self, points: np.ndarray, error: Exception | None = None) -> None:
        self.points, self.error, self.open = points, error, threading.Event()

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        assert self.open.wait(20.0), "the test never opened the gate"
        if self.error is not None:
            raise self.error
        return np.asarray(self.points, dtype=dtype)


def test_windows_solved_on_a_thread_leave_the_owner_free_and_give_the_same_result(walk):
    """The body node's optimiser: while a window is solved (held here until the test lets it go), frames go on
    coming in and wait beside the optimiser; once collected they join, and every window comes out as the optimiser
    alone solves it, each frame's record with it."""
    t, pelvis, feet, stance, fused, suit, ground = walk
    config = replace(SceneOptimisationConfig(), window=30)
    legs, bones = _legs(feet - pelvis[:, None])
    frames = [(t[k], _poses(fused)[k], legs[k], bones[k], suit[k], feet[k]) for k in range(len(t))]
    alone = SceneOptimiser(config)
    expected = []
    for frame in frames:
        alone.add(*frame)
        if alone.full:
            expected.append(alone.optimise(ground)[0])
    live = BackgroundOptimiser(SceneOptimiser(config))
    for k in range(30):
        assert live.add(k, *frames[k]) == []
    assert live.sole_m is None and live.waits_for_map and not live.start()  # no map yet
    gate = _GatedMap(ground)
    live.map = gate
    assert live.start() and live.busy and not live.start()  # one solve at a time
    for k in range(30, 75):  # the solve waits at the gate: the frames wait beside the optimiser
        assert live.add(k, *frames[k]) == []
    assert live.collect() is None and len(live) == 75 and live.beside == 45
    with pytest.raises(RuntimeError, match="being solved"):
        live.drop(1)
    gate.open.set()
    first = live.collect(wait=True)
    assert first.records == list(range(30)) and first.error is None and first.seconds > 0 and not live.busy
    assert np.allclose(first.result.t, expected[0].t) and live.sole_m == alone.sole_m and live.beside == 0
    solved = [first]
    live.map = ground
    for k in range(75, len(t)):
        live.add(k, *frames[k])
        while live.start():
            solved.append(live.collect(wait=True))
    assert [s.records for s in solved] == [list(range(30 * w, 30 * w + 30)) for w in range(3)]
    assert all(np.allclose(s.result.feet, e.feet) for s, e in zip(solved, expected, strict=True))
    assert live.start(flush=True) and live.collect(wait=True).records == list(range(90, 100))
    assert len(live) == 0 and live.collect() is None


def test_a_window_solved_on_a_thread_that_finds_no_ground_keeps_its_frames(walk):
    """No ground under the first window's feet: the answer comes back, the frames wait for a later map (any map
    but that one); a failure of any other kind comes back with the window's frames, dropped; frames beyond what
    the optimiser holds drop its oldest window as they join, beyond four windows beside it the oldest of them (and
    those before: a gap)."""
    t, pelvis, feet, stance, fused, suit, ground = walk
    config = replace(SceneOptimisationConfig(), window=10, max_wait_s=0.0)  # the optimiser holds 20 frames
    legs, bones = _legs(feet - pelvis[:, None])
    frames = [(t[k], _poses(fused)[k], legs[k], bones[k], suit[k], feet[k]) for k in range(len(t))]
    live = BackgroundOptimiser(SceneOptimiser(config))
    for k in range(12):
        live.add(k, *frames[k])
    live.map = np.zeros((0, 3))
    assert live.start()
    refused = live.collect(wait=True)
    assert refused.records == [] and isinstance(refused.error, NoGroundYet) and len(live) == 12
    assert live.waits_for_map and not live.start()  # not on the same map again
    live.map = refusing = _GatedMap(np.zeros((0, 3)))  # a new map, whatever its points: tried
    assert live.start()
    live.map = _GatedMap(ground, np.linalg.LinAlgError("SVD did not converge"))  # another comes meanwhile
    refusing.open.set()
    assert isinstance(live.collect(wait=True).error, NoGroundYet) and not live.waits_for_map  # the later one is tried
    assert live.start()
    for k in range(12, 30):
        live.add(k, *frames[k])
    live.map.open.set()
    failed = live.collect(wait=True)  # a ValueError, but not the optimiser's refusal: a failure
    assert isinstance(failed.error, np.linalg.LinAlgError) and failed.result is None
    assert failed.records == list(range(10))
    assert not live.busy and len(live) == 20 and failed.dropped == []  # the frames beside joined
    live.map = _GatedMap(ground)
    assert live.start()  # 10-19; 20-29 wait in the optimiser
    for k in range(30, 42):
        live.add(k, *frames[k])
    live.map.open.set()
    solved = live.collect(wait=True)  # 30-41 join 20-29: at 20 frames the oldest window goes
    assert solved.records == list(range(10, 20)) and solved.dropped == list(range(20, 30)) and len(live) == 12
    live.map = _GatedMap(ground)
    assert live.start()  # 30-39; 40-41 wait in the optimiser
    for k in range(42, 42 + 45):
        live.add(k, *frames[k])
    assert live.beside == 40
    live.map.open.set()
    # of the 45 beside, the oldest 5 went, and those before them; of the 40 that join, the oldest two windows go
    solved = live.collect(wait=True)
    assert solved.records == list(range(30, 40)) and solved.dropped == list(range(40, 67))
    assert len(live) == 20 and live.drop() == list(range(67, 87))


def test_a_one_frame_window_at_the_end_gives_a_finite_pose(walk):
    t, pelvis, feet, stance, fused, suit, ground = walk
    optimiser = SceneOptimiser(replace(SceneOptimisationConfig(), window=30), sole_m=SOLE_M)
    legs, bones = _legs(feet - pelvis[:, None])
    optimiser.add(t[0], _poses(fused)[0], legs[0], bones[0], suit[0], feet[0])
    result = optimiser.optimise(ground)[0]
    assert np.isfinite(result.t).all() and np.isfinite(result.R).all()


def test_axis_angle_matrices_agree_with_the_numpy_ones():
    import torch

    from lip_ros.core.rotations import axis_angle_to_matrix as numpy_version
    from lip_ros.core.torch_kinematics import axis_angle_to_matrix

    v = np.random.default_rng(2).normal(size=(20, 3))
    v[0] = 0.0
    v[1] = 1e-8
    assert np.allclose(axis_angle_to_matrix(torch.as_tensor(v)).numpy(), numpy_version(v), atol=1e-12)


def test_each_run_of_standing_frames_is_one_stance_for_the_contact_term():
    """The contact term holds each stance's mean height on its plane (the foot joint rises and falls as the foot
    rolls within one): runs numbered across both feet, -1 where a foot does not stand."""
    stance = np.array([[1, 0], [1, 0], [0, 1], [1, 1], [1, 0]], dtype=bool)
    assert stance_runs(stance).tolist() == [[0, -1], [0, -1], [-1, 2], [1, 2], [1, -1]]
