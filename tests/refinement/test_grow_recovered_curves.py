"""refinement.grow_recovered_curves: the cylinders and spheres the recovery found grow into the
free pixels their models explain, ring after ring until none joins; other regions do not."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_cylinder, fit_plane
from rangeseg_o3d.refinement import grow_recovered_curves
from rangeseg_o3d.refinement.context import Context

SIGMA = 0.002  # the noise_2mm row's range noise


def _column_before_a_wall(seed: int):
    """A 40 x 40 grid of rays 1 degree apart, 2 mm range noise: a wall 6 m away and an upright
    column of radius 0.15 m whose axis is 4.5 m away (rows 0-39, three or four columns of returns).
    Labels: the column's rows 25-39 are region 1 (a cylinder), the wall region 2 (a plane); the
    column's rows 0-24 are free. ``(context, labels, on_column, growth)``."""
    rng = np.random.default_rng(seed)
    focal = 1.0 / np.tan(np.radians(1.0))
    v, u = np.mgrid[0:40, 0:40].astype(float)
    rays = np.dstack([(u - 19.5) / focal, (v - 19.5) / focal, np.ones((40, 40))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    ranges = 6.0 / rays[..., 2]
    across, depth = rays[..., 0], rays[..., 2]
    a, b = across ** 2 + depth ** 2, -4.5 * depth
    disc = b * b - a * (4.5 ** 2 - 0.15 ** 2)
    on = disc > 0
    ranges[on] = ((-b - np.sqrt(np.maximum(disc, 0.0))) / a)[on]
    ranges += rng.normal(0.0, SIGMA, ranges.shape)
    xyz = rays * ranges[..., None]
    labels = np.zeros((40, 40), np.int32)
    labels[25:][on[25:]] = 1
    wall = ~on
    wall[:, :] &= np.abs(u - 19.5) > 4  # the wall's region leaves a free band about the column
    labels[wall] = 2
    pipeline = rs.Pipeline(rs.load_config("lms200", overrides={"sensor.sigma0": SIGMA}))
    ctx = Context(rs.OrganizedCloud(xyz), pipeline.fitter, np.full((40, 40), SIGMA), 10)
    growth = dict(xyz=xyz, ranges=ranges, sigma=np.full((40, 40), SIGMA), k_sigma=3.0, jump_ratio=0.08,
                  jump_min=0.05)
    return ctx, labels, on, growth


@pytest.mark.parametrize("seed", [0, 1])
def test_a_recovered_column_grows_along_itself_until_no_pixel_joins(seed):
    ctx, labels, on, growth = _column_before_a_wall(seed)
    assert 3 <= on[20].sum() <= 4  # the premise: a column three or four grid columns wide
    fits = {1: fit_cylinder(ctx.xyz[labels.ravel() == 1]), 2: fit_plane(ctx.xyz[labels.ravel() == 2])}
    assert fits[1].kind == "cylinder" and abs(fits[1].radius - 0.15) < 0.05
    grown, new_fits = grow_recovered_curves(ctx, labels, fits, before={2}, **growth)
    # the column 25 rows up from the region's top (the grow step's rings are 3) but for a few
    # returns beyond the model's three sigmas, and nothing of the wall: the band between them
    # is a range jump of 1.4 m
    assert not np.any((grown == 1) & ~on)
    assert np.count_nonzero((grown == 1) & on) >= 0.95 * np.count_nonzero(on)
    assert np.count_nonzero(grown[:5] == 1) >= 0.9 * np.count_nonzero(on[:5])  # (up to the grid's top row)
    assert np.array_equal(grown == 2, labels == 2)
    assert new_fits[1].kind == "cylinder"
    assert labels[:25][on[:25]].max() == 0  # (the input is left alone)


def test_regions_found_before_the_recovery_and_planes_do_not_grow():
    ctx, labels, on, growth = _column_before_a_wall(0)
    fits = {1: fit_cylinder(ctx.xyz[labels.ravel() == 1]), 2: fit_plane(ctx.xyz[labels.ravel() == 2])}
    same, _ = grow_recovered_curves(ctx, labels, fits, before={1, 2}, **growth)
    assert np.array_equal(same, labels)  # the cylinder was there before the recovery
    # a plane the recovery found does not grow here (recover.claim_thin_strips is its step)
    free = labels.copy()
    free[labels == 1] = 0
    band = (labels == 0) & ~on
    band_region = free.copy()
    band_region[band] = 3
    plane_fits = {2: fits[2], 3: fit_plane(ctx.xyz[band.ravel()])}
    unchanged, _ = grow_recovered_curves(ctx, band_region, plane_fits, before={2}, **growth)
    assert np.array_equal(unchanged, band_region)
