"""Creases where the noise is comparable to the point spacing, and the measured angular grid."""

import numpy as np
import pytest

from rangeseg_o3d.segmentation.edges import angular_steps, crease_edges
from rangeseg_o3d.segmentation.residual import residual_image


def _roof(noise: float, seed: int = 0):
    """Two planes meeting at a 90-degree ridge (column 40), 40 x 80 points 2 cm apart, 3 m away."""
    v, u = np.mgrid[0:40, 0:80].astype(float)
    x, y = (u - 40) * 0.02, (v - 20) * 0.02
    z = 3.0 - np.abs(x) + np.random.default_rng(seed).normal(0.0, noise, x.shape)
    return np.dstack([x, y, z])


def test_angular_steps_measure_the_grid_from_directions():
    beams = np.radians(np.arange(60, 121, 0.5))
    tilts = np.radians(np.arange(-10, 10.01, 0.25))
    b, t = np.meshgrid(beams, tilts)
    rays = np.dstack([np.sin(b) * np.cos(t), np.cos(b) * np.cos(t), np.sin(t)])
    ranges = np.random.default_rng(0).uniform(1.0, 5.0, b.shape)[..., None]
    rows, cols = angular_steps(rays * ranges)  # ranges vary: directions do not
    assert np.nanmedian(rows) == pytest.approx(np.radians(0.25), rel=1e-6)
    # a beam step of 0.5 deg spans 0.5 cos(tilt) deg of arc
    assert np.nanmedian(cols) == pytest.approx(np.radians(0.5) * np.cos(np.radians(5.0)), rel=2e-3)


def test_angular_steps_reject_a_flat_array():
    with pytest.raises(ValueError, match="shape"):
        angular_steps(np.zeros((4, 3)))


def test_a_ridge_the_residual_misses_is_found_by_the_window_normals():
    noise = 0.03  # larger than the point spacing (2 cm)
    xyz = _roof(noise)
    ranges = np.linalg.norm(xyz, axis=2)
    residual, _ = residual_image(xyz, ranges=ranges, sigma0=noise, with_normals=False)
    ridge = np.abs(np.arange(80) - 40) <= 1
    # the paper's 3x3 residual (threshold 4 noise variances) sees under half of the ridge
    assert (residual[:, ridge] > 4.0).mean() < 0.5
    creases, window = crease_edges(xyz, ranges, np.full(ranges.shape, noise))
    assert window >= 5
    core = slice(window, 40 - window)  # rows whose windows lie inside the grid
    assert creases[core, 39:42].all()
    far = np.abs(np.arange(80) - 40) > window + 1
    assert creases[core][:, far].mean() < 0.02


def test_no_crease_test_where_the_residual_sees_creases():
    xyz = _roof(0.001)
    ranges = np.linalg.norm(xyz, axis=2)
    creases, window = crease_edges(xyz, ranges, np.full(ranges.shape, 0.001))
    assert window == 0 and not creases.any()


def _column(noise: float, seed: int = 0):
    """A vertical cylinder (radius 0.22 m, axis 2.2 m ahead) seen by a spinning lidar's grid:
    40 rows 0.7 deg apart, the columns 0.35 deg apart across its visible half."""
    radius, distance = 0.22, 2.2
    elevations = np.radians(np.linspace(10, -17, 40))[:, None]
    half = np.arcsin(radius / distance) * 0.95  # the silhouette itself is a jump edge
    azimuths = np.arange(-half, half, np.radians(0.352))[None, :]
    # the nearer intersection of each horizontal ray with the circle, then up the elevation
    flat = distance * np.cos(azimuths) - np.sqrt(radius**2 - (distance * np.sin(azimuths)) ** 2)
    ranges = flat / np.cos(elevations)
    ranges = ranges + np.random.default_rng(seed).normal(0.0, noise, ranges.shape)
    directions = np.dstack(np.broadcast_arrays(np.cos(elevations) * np.cos(azimuths),
                                               np.cos(elevations) * np.sin(azimuths), np.sin(elevations)))
    return ranges[..., None] * directions, ranges


def test_a_curved_surface_turning_steadily_is_no_crease():
    # 1.5 cm noise over 1.3 cm spacing: the residual is blind, the crease test runs, and
    # its flanking windows 8 columns apart tilt by ~28 deg on this column (over the 20-deg
    # limit); the windows further out tilt alike, so nothing there is a crease
    noise = 0.015
    xyz, ranges = _column(noise)
    creases, window = crease_edges(xyz, ranges, np.full(ranges.shape, noise))
    assert window == 9
    assert creases.mean() < 0.02



def _check_blind_spacing(xyz, ranges, sigma, ratio):
    # kernels.blind_spacing's pixels and values must be those of
    # range x fmin(angular_steps) < ratio x sigma; returns (blind, clear) pixel counts
    from rangeseg_o3d.kernels import blind_spacing

    with np.errstate(invalid="ignore"):
        spacing = ranges * np.fmin(*angular_steps(xyz))
        blind = np.isfinite(spacing) & (spacing > 0) & (spacing < ratio * sigma)
    got, count = blind_spacing(xyz, ranges, sigma, ratio)
    assert count == np.count_nonzero(blind)
    assert np.array_equal(~np.isnan(got), blind)
    assert np.array_equal(got[blind], spacing[blind])
    return count, np.count_nonzero(np.isfinite(spacing) & ~blind)


def test_blind_spacing_equals_the_spacing_from_the_angular_steps_bit_for_bit():
    # kernels.blind_spacing skips the square roots and arc sines where a bound already
    # clears the limit: random points, some without direction, odd ranges and noise
    rng = np.random.default_rng(5)
    blind_pixels = clear_pixels = 0
    for shape in ((12, 17), (1, 9), (9, 1), (2, 2), (1, 1), (30, 40)):
        xyz = rng.normal(0.0, 1.0, (*shape, 3)) + (0.0, 0.0, 3.0)
        xyz[rng.random(shape) < 0.2] = np.nan
        xyz[rng.random(shape) < 0.1] = 0.0  # no direction
        factor = rng.choice([1.0, -1.0, 0.0, np.inf], p=[0.85, 0.05, 0.05, 0.05], size=shape)
        with np.errstate(invalid="ignore"):
            ranges = np.linalg.norm(xyz, axis=2) * factor
        sigma = rng.uniform(0.0, 4.0, shape)
        sigma[rng.random(shape) < 0.05] = np.nan
        count, clear = _check_blind_spacing(xyz, ranges, sigma, float(rng.uniform(0.1, 3.0)))
        blind_pixels += count
        clear_pixels += clear
    assert blind_pixels > 100 and clear_pixels > 100  # both branches were taken


def test_blind_spacing_on_a_scanner_grid_equals_the_angular_steps_bit_for_bit():
    # a nodding scanner's grid: steps of ~0.01 rad, where the sine bound decides nearly every
    # pixel (near-duplicate points, whose sines are below the trusted floor, take the exact path)
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    xyz = np.array(simulate_lms200(default_scene(), seed=0).cloud.xyz)
    xyz[5, 7] = xyz[5, 6] * (1.0 + 1e-9)  # an angle of ~0 to its neighbour
    ranges = np.linalg.norm(xyz, axis=2)
    sigma = np.full(ranges.shape, 0.005)
    for ratio in (0.5, 1.0, 3.0, 10.0, 100.0):
        _check_blind_spacing(xyz, ranges, sigma, ratio)


def test_crease_edges_want_ranges_and_sigma_of_the_grid():
    # the compiled passes read ranges and sigma at the grid's pixels without a bounds check:
    # a smaller range image was read past its end
    xyz = np.dstack([*np.meshgrid(np.arange(10.0), np.arange(12.0)), np.full((12, 10), 2.0)])
    with pytest.raises(ValueError, match=r"ranges must have the shape of the grid \(12, 10\); got \(11, 10\)"):
        crease_edges(xyz, np.ones((11, 10)), 0.01)
    with pytest.raises(ValueError, match=r"sigma must broadcast to the \(12, 10\) grid; got \(11, 10\)"):
        crease_edges(xyz, np.ones((12, 10)), np.full((11, 10), 0.01))
    mask, _ = crease_edges(xyz, np.linalg.norm(xyz, axis=2), 0.01)  # one sigma for all: as before
    assert mask.shape == (12, 10)
