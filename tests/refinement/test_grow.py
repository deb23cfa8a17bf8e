"""The grow step and its kernel call: edge-band pixels go back to the surface that explains them."""

import numpy as np

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.refinement.grow import grow_into_edges, grow_regions
from refinement_helpers import plane_grid


def _flat_grid(h=12, w=16, z=2.0):
    v, u = np.mgrid[0:h, 0:w].astype(float)
    return np.dstack([u * 0.05, v * 0.05, np.full((h, w), z)])


def test_grow_hands_band_pixels_to_the_surface_that_explains_them():
    xyz = _flat_grid()
    xyz[:, 8:, 2] = 2.0 + (xyz[:, 8:, 0] - 0.4)  # a 45 degree crease at column 8
    labels = np.zeros((12, 16), np.int32)
    labels[:, :6] = 1
    labels[:, 10:] = 2
    models = {1: fit_plane(xyz[:, :6].reshape(-1, 3)), 2: fit_plane(xyz[:, 10:].reshape(-1, 3))}
    sigma = np.full((12, 16), 0.002)
    grown = grow_into_edges(xyz, labels, models, sigma, xyz[..., 2], iterations=5, k_sigma=3.0)
    assert (grown[:, :8] == 1).all()
    # Column 8 lies on both planes (the crease line); the rest must go to its own side.
    assert (grown[:, 9:] == 2).all()
    assert (grown[:, 8] > 0).all()


def test_grow_does_not_cross_jumps_or_take_far_points():
    xyz = _flat_grid()
    xyz[:, 8:, 2] = 3.0  # a parallel plane 1 m behind: a jump, not the same surface
    labels = np.zeros((12, 16), np.int32)
    labels[:, :6] = 1
    models = {1: fit_plane(xyz[:, :6].reshape(-1, 3))}
    grown = grow_into_edges(xyz, labels, models, np.full((12, 16), 0.002), xyz[..., 2],
                            iterations=10)
    assert (grown[:, :8] == 1).all() and (grown[:, 8:] == 0).all()


def test_grow_regions_grows_then_refits_the_planes_that_grew(context):
    xyz = plane_grid(20, 30, slope=0.3, noise=0.002, seed=3)
    cloud = rs.OrganizedCloud(xyz)
    labels = np.zeros(cloud.shape, np.int32)
    labels[:, :12] = 1  # a third of the plane; the rest is an edge band to grow into
    first = fit_plane(xyz[:, :12].reshape(-1, 3))
    ctx = context(cloud, sigma=np.full(cloud.shape, 0.002))
    grown, fits = grow_regions(ctx, labels, {1: first}, xyz=xyz, ranges=cloud.range_image(),
                               sigma=np.full(cloud.shape, 0.002), iterations=30, k_sigma=3.0,
                               jump_ratio=0.08, jump_min=0.05)
    assert (labels[:, 12:] == 0).all()  # the input is left alone
    assert (grown > 0).mean() > 0.97
    # refitted on the grown region: the plane of all its pixels, not the first third's
    refit = fit_plane(xyz[grown == 1])
    assert fits[1] != first
    np.testing.assert_allclose(fits[1].normal, refit.normal, atol=1e-9)
    assert abs(fits[1].d - refit.d) < 1e-9


def test_grow_regions_without_iterations_changes_nothing(context):
    xyz = plane_grid(10, 10)
    labels = np.zeros((10, 10), np.int32)
    labels[:, :5] = 1
    fits = {1: fit_plane(xyz[:, :5].reshape(-1, 3))}
    out = grow_regions(context(rs.OrganizedCloud(xyz)), labels, fits, xyz=xyz, ranges=xyz[..., 2],
                       sigma=np.full((10, 10), 0.002), iterations=0, k_sigma=3.0, jump_ratio=0.08,
                       jump_min=0.05)
    assert out[0] is labels and out[1] is fits


def test_settle_gives_a_band_back_to_the_surface_that_explains_it_clearly_better(context):
    from rangeseg_o3d.refinement.grow import SETTLE_MARGIN, settle_regions

    # two planes at a 30-degree crease (column 30); region 1 took 4 columns of plane 2
    noise = 0.002
    xyz = plane_grid(30, 60, noise=noise, seed=4)
    xyz[:, 30:, 2] += np.tan(np.radians(30.0)) * (xyz[:, 30:, 0] - xyz[0, 30, 0])
    cloud = rs.OrganizedCloud(xyz)
    truth = np.where(np.arange(60) < 30, 1, 2)[None, :].repeat(30, axis=0)
    labels = truth.astype(np.int32).copy()
    labels[:, 30:34] = 1
    fits = {1: fit_plane(xyz[:, :30].reshape(-1, 3)), 2: fit_plane(xyz[:, 34:].reshape(-1, 3))}
    sigma = np.full(cloud.shape, noise)
    growth = dict(xyz=xyz, ranges=np.linalg.norm(xyz, axis=2), sigma=sigma, k_sigma=3.0,
                  jump_ratio=0.1, jump_min=0.05)
    out, out_fits = settle_regions(context(cloud, sigma=sigma), labels, fits, iterations=6, **growth)
    assert (labels[:, 30:34] == 1).all()  # the input is left alone
    # column 31 is 0.02 tan(30 deg) = 11.5 mm = 5.8 sigma off plane 1: every pixel beyond
    # the crease column by more than the margin goes back to plane 2
    assert SETTLE_MARGIN == 1.0
    assert (out[:, 31:] == 2).all() and (out[:, :30] == 1).all()
    assert out_fits[2].rms < 1.3 * noise and out_fits[1].rms < 1.3 * noise


def test_settle_leaves_a_border_both_surfaces_explain(context):
    from rangeseg_o3d.refinement.grow import settle_regions

    # one plane cut into two regions anywhere: no pixel is explained clearly better
    noise = 0.002
    xyz = plane_grid(20, 40, noise=noise, seed=5)
    cloud = rs.OrganizedCloud(xyz)
    labels = np.where(np.arange(40) < 17, 1, 2)[None, :].repeat(20, axis=0).astype(np.int32)
    fits = {k: fit_plane(xyz[labels == k]) for k in (1, 2)}
    sigma = np.full(cloud.shape, noise)
    out, out_fits = settle_regions(context(cloud, sigma=sigma), labels, fits, iterations=6, xyz=xyz,
                                   ranges=np.linalg.norm(xyz, axis=2), sigma=sigma, k_sigma=3.0,
                                   jump_ratio=0.1, jump_min=0.05)
    assert (out == labels).mean() > 0.99 and out_fits.keys() == fits.keys()
