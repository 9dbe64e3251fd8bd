"""The scan layout derived from the cloud: any column-0 azimuth, either sweep direction, per-row offsets, the
rows' elevations of OS0, OS1 and OS2 models, windows that cover what the rays see, and clouds that fit no sweep."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from lip_ros.core.scan_layout import destagger, fit_scan_layout, returns_per_square_degree
from lip_ros.rig.lidar import OusterModel


def _cloud(lidar: OusterModel, rng: np.random.Generator, valid: float = 0.6
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y, z (H, W) of the lidar's rays at random ranges, NaN where there is no return."""
    d = lidar.directions
    points = d * rng.uniform(1.0, 40.0, d.shape[:2])[..., None]
    points[rng.random(d.shape[:2]) > valid] = np.nan
    return points[..., 0], points[..., 1], points[..., 2]


@pytest.mark.parametrize("column0", [180.0, 0.0, 37.0, -123.0])
@pytest.mark.parametrize("columns", [512, 1024, 2048])
def test_fit_finds_column0_and_the_clockwise_sweep(column0, columns):
    lidar = OusterModel.os1_128(columns=columns, column0_azimuth_deg=column0)
    fit = fit_scan_layout(*_cloud(lidar, np.random.default_rng(columns)))
    assert fit is not None and fit.direction == -1 and fit.width == columns and fit.agreement > 0.999
    assert abs((np.degrees(fit.column0_rad) - column0 + 180.0) % 360.0 - 180.0) < 1e-3
    np.testing.assert_allclose(fit.row_offset_rad, 0.0, atol=1e-6)
    for j in (0, columns // 3, columns - 1):
        assert fit.column(lidar.azimuth[j]) == pytest.approx(j, abs=1e-3)


def test_fit_finds_a_counter_clockwise_sweep_and_row_offsets():
    offsets = (0.3, -0.1, 0.2, -0.4)
    lidar = OusterModel.os1_64(column0_azimuth_deg=90.0, beam_azimuth_deg=offsets)
    x, y, z = _cloud(lidar, np.random.default_rng(1))
    fit = fit_scan_layout(x, -y, z)  # mirrored: azimuth grows with the column
    assert fit.direction == 1
    true = np.radians(-90.0 - np.resize(offsets, 64))  # where column 0 of each row looks, mirrored
    got = fit.column0_rad + fit.row_offset_rad
    np.testing.assert_allclose((got - true + np.pi) % (2 * np.pi) - np.pi, 0.0, atol=1e-6)


@pytest.mark.parametrize("column0, centre", [(0.0, (8.0, 0.3)), (180.0, (-3.0, 6.0)), (37.0, (2.0, -15.0))])
def test_window_holds_every_column_whose_rays_pass_near(column0, centre):
    lidar = OusterModel.os1_128(columns=1024, column0_azimuth_deg=column0, beam_azimuth_deg=(0.15, -0.05, 0.1))
    fit = fit_scan_layout(*_cloud(lidar, np.random.default_rng(7)))
    radius = 1.2
    d = lidar.directions[..., :2]
    horizontal = d / np.linalg.norm(d, axis=-1, keepdims=True)
    along = horizontal @ np.asarray(centre)
    miss = np.abs(horizontal[..., 0] * centre[1] - horizontal[..., 1] * centre[0])  # ray to centre, seen from above
    near = np.unique(np.nonzero((along > 0) & (miss <= radius))[1])
    window = fit.window(np.asarray(centre), radius)
    assert set(near) <= set(window)
    assert len(window) <= len(near) + 4  # a column of rounding on either side, and the rows' offsets


def test_window_is_every_column_around_the_sensor():
    fit = fit_scan_layout(*_cloud(OusterModel.os1_128(), np.random.default_rng(3)))
    assert fit.window(np.array([0.5, 0.2]), 1.0) is None


def test_clouds_that_fit_no_sweep_give_none():
    rng = np.random.default_rng(5)
    assert fit_scan_layout(*rng.normal(size=(3, 64, 512))) is None  # unorganized
    assert fit_scan_layout(*_cloud(OusterModel.os1_64(columns=512), rng, valid=0.001)) is None  # too few returns
    assert fit_scan_layout(*np.full((3, 4, 8), np.nan)) is None
    x, y, z = _cloud(OusterModel.os1_64(columns=512), rng)
    x[1::2], y[1::2], z[1::2] = np.nan, np.nan, np.nan  # every other row dark: no two neighbouring rows
    assert fit_scan_layout(x, y, z) is None


@pytest.mark.parametrize("model, fov_deg", [(OusterModel.os1_128, 45.0), (OusterModel.os0_128, 90.0),
                                            (OusterModel.os2_128, 22.5), (OusterModel.os1_64, 45.0)])
def test_rows_elevations_and_spacing_of_each_model(model, fov_deg):
    lidar = model(columns=512)
    fit = fit_scan_layout(*_cloud(lidar, np.random.default_rng(2)))
    np.testing.assert_allclose(fit.row_elevation_rad, lidar.elevation, atol=1e-6)
    assert np.degrees(fit.row_spacing_rad) == pytest.approx(fov_deg / (lidar.beams - 1), rel=1e-4)
    assert "between rows" in fit.describe()


@pytest.mark.parametrize("direction", [-1, 1])
def test_a_staggered_cloud_is_lined_up_by_its_row_shifts(direction):
    """Rows degrees apart in azimuth (a staggered Ouster cloud): the fit gives each row's shift in whole columns, and
    destaggering by it leaves the rows less than half a column apart, as a destaggered cloud; -shift undoes it."""
    beams = (4.2, 1.4, -1.4, -4.2)
    lidar = OusterModel.os1_64(columns=1024, beam_azimuth_deg=beams)
    x, y, z = _cloud(lidar, np.random.default_rng(3))
    y = y * -direction  # direction +1: mirrored, the sweep counter-clockwise
    fit = fit_scan_layout(x, y, z)
    assert fit.direction == direction
    column = 2 * np.pi / 1024
    np.testing.assert_array_equal(fit.row_shift, np.rint(fit.direction * fit.row_offset_rad / column))
    assert np.abs(fit.row_shift).max() == 12  # 4.2 deg from the rows' mean of 0
    lined = fit_scan_layout(*(destagger(a, fit.row_shift) for a in (x, y, z)))
    assert np.abs(lined.row_offset_rad).max() < 0.5 * column and not lined.row_shift.any()
    image = np.arange(64 * 1024).reshape(64, 1024)
    np.testing.assert_array_equal(destagger(destagger(image, fit.row_shift), -fit.row_shift), image)
    assert destagger(image, fit.row_shift)[0, 5] == image[0, (5 - fit.row_shift[0]) % 1024]


def _grid_sweep(beams: int, columns: int, keep: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
                ) -> tuple[np.ndarray, float]:
    """Points (N, 3) of a beams x columns grid over 45 deg of elevation at random ranges (those ``keep(elevation,
    azimuth)`` says, all if None), any order, and the grid's returns per square degree."""
    elevation, azimuth = np.meshgrid(np.radians(np.linspace(-22.5, 22.5, beams)),
                                     np.linspace(-np.pi, np.pi, columns, endpoint=False), indexing="ij")
    dirs = np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], -1)
    points = dirs * np.random.default_rng(0).uniform(1.0, 30.0, elevation.shape)[..., None]
    if keep is not None:
        points = points[keep(elevation, azimuth)]
    points = np.random.default_rng(1).permutation(points.reshape(-1, 3))
    return points, columns / 360.0 * (beams - 1) / 45.0


@pytest.mark.parametrize("beams", [16, 32, 64, 128])
@pytest.mark.parametrize("columns", [512, 1024, 2048])
def test_how_densely_returns_sample_the_view_is_read_from_the_points_alone(beams, columns):
    """Rows and columns unequally far apart (up to 16 times), in any order, the upper half without returns but
    within 1 rad of azimuth (the sky): within 5 %, 15 % at 16 x 2048; a third of the returns lost is a third fewer
    a square degree."""
    def sky(elevation: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
        return (elevation < 0.0) | (np.abs(azimuth) < 1.0)

    def lost(elevation: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
        return np.random.default_rng(2).random(elevation.shape) > 1.0 / 3.0

    low = 0.84 if (beams, columns) == (16, 2048) else 0.95
    for keep, share in ((None, 1.0), (sky, 1.0), (lost, 2.0 / 3.0)):
        points, density = _grid_sweep(beams, columns, keep)
        assert low * share <= returns_per_square_degree(points) / density <= 1.05 * share


def test_too_few_returns_give_no_density():
    """64 returns and fewer (NaN and zero points left out) are too few; 65 give a density."""
    points, _ = _grid_sweep(16, 512)
    points[64:70] = np.nan
    points[70:75] = 0.0
    assert np.isnan(returns_per_square_degree(points[:75])) and np.isnan(returns_per_square_degree(np.zeros((0, 3))))
    assert returns_per_square_degree(points[:76]) > 0.0
