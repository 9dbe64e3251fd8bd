"""What a point cloud's surfaces pin down of a registration's motion (lip_ros.core.surface_constraint), on synthetic
scenes seen from a sensor at the origin: an open field, a room, a corridor."""

from __future__ import annotations

import numpy as np
import pytest

from lip_ros.core.surface_constraint import registration_constraint


def _plane(rng: np.random.Generator, centre, u, v, half: float, n: int) -> np.ndarray:
    """(n, 3) points spread over a square of ``2 half`` side on the plane through ``centre`` spanned by ``u``, ``v``."""
    a, b = rng.uniform(-half, half, (2, n, 1))
    return np.asarray(centre) + a * np.asarray(u, dtype=float) + b * np.asarray(v, dtype=float)


def _field(rng: np.random.Generator, half: float = 20.0, n: int = 4000) -> np.ndarray:
    return _plane(rng, [0.0, 0.0, -1.0], [1, 0, 0], [0, 1, 0], half, n)


def _room(rng: np.random.Generator) -> np.ndarray:
    """A floor and four walls 3 m high (each seen over 6 m of its length), the sensor off the middle."""
    walls = [_plane(rng, [x, 0.0, 0.5], [0, 1, 0], [0, 0, 1], 3.0, 800) for x in (-8.0, 6.0)]
    walls += [_plane(rng, [0.0, y, 0.5], [1, 0, 0], [0, 0, 1], 3.0, 800) for y in (-5.0, 7.0)]
    return np.concatenate([_field(rng, 6.0, 2000), *walls])


def _corridor(rng: np.random.Generator) -> np.ndarray:
    walls = [_plane(rng, [0.0, y, 0.0], [1, 0, 0], [0, 0, 1], 1.0, 1500) for y in (-1.5, 1.5)]
    return np.concatenate([_plane(rng, [0.0, 0.0, -1.0], [1, 0, 0], [0, 1, 0], 1.0, 1500), *walls])


def _along(values: np.ndarray, vectors: np.ndarray, motion: np.ndarray) -> float:
    """The information of the unit ``motion`` (6,: turn times scale, shift)."""
    motion = motion / np.linalg.norm(motion)
    return float(motion @ (vectors * values) @ vectors.T @ motion)


def test_an_open_field_pins_the_height_and_tilt_and_nothing_across_it():
    """The ground alone: a shift along x or y and a turn about z have no information; a shift along z and a tilt
    have most of it."""
    values, vectors, scale = registration_constraint(_field(np.random.default_rng(0)))
    assert scale == pytest.approx(np.sqrt(1.0 + 2 * 20.0**2 / 3), rel=0.05)
    unit = np.eye(6)
    for free in (unit[3], unit[4], unit[2]):  # x, y, turn about z
        assert _along(values, vectors, free) < 1e-6
    for pinned in (unit[5], unit[0], unit[1]):  # z, roll, pitch
        assert _along(values, vectors, pinned) > 0.2
    assert values[:3].max() < 1e-6


def test_a_room_pins_every_motion_and_a_corridor_all_but_the_shift_along_it():
    room, _, _ = registration_constraint(_room(np.random.default_rng(1)))
    assert room[0] > 0.02
    values, vectors, _ = registration_constraint(_corridor(np.random.default_rng(2)))
    assert _along(values, vectors, np.eye(6)[3]) < 1e-6  # along x
    assert _along(values, vectors, np.eye(6)[4]) > 0.2 and _along(values, vectors, np.eye(6)[5]) > 0.2
    assert values[1] > 0.02  # the one free motion only


def test_the_information_is_per_point_and_needs_enough_points():
    """Twice as dense a sampling of the same room reads the same (a sensor's point count does not count); up to
    ``neighbours`` points read nothing."""
    rng = np.random.default_rng(3)
    sparse, _, _ = registration_constraint(_room(rng))
    dense = np.concatenate([_room(rng), _room(rng)])
    np.testing.assert_allclose(registration_constraint(dense)[0], sparse, rtol=0.1, atol=2e-3)
    values, vectors, scale = registration_constraint(np.zeros((10, 3)))
    assert not values.any() and np.array_equal(vectors, np.eye(6)) and scale == 1.0
