"""The split step on its own: a region no model explains comes back as all its surfaces."""

from dataclasses import fields

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.primitives import FitFailure
from rangeseg_o3d.refinement.split import split_regions
from refinement_helpers import best_overlap, folded_strip


def test_a_region_of_three_planes_is_split_into_three(context):
    xyz, truth, normals = folded_strip(noise=0.001)
    cloud = rs.OrganizedCloud(xyz)
    labels = np.ones(cloud.shape, np.int32)
    fits = {1: FitFailure("plane", "rms over the limit")}
    out_labels, out_fits = split_regions(context(cloud, min_size=10), labels, fits, [1])
    # the inputs are left alone
    assert (labels == 1).all() and list(fits) == [1] and not fits[1]
    found = set()
    for k in (1, 2, 3):
        best, share = best_overlap(out_labels, truth, k)
        assert best > 0 and share >= 0.9
        assert (truth[out_labels == best] == k).mean() >= 0.9
        model = out_fits[best]
        assert model.kind == "plane" and abs(float(model.normal @ normals[k])) >= np.cos(np.radians(1.0))
        found.add(best)
    # the first surface keeps the region's label, the others are numbered after the largest
    assert found == {1, 2, 3}


def test_regions_not_named_failed_are_untouched(context):
    xyz, truth, _ = folded_strip(noise=0.001)
    cloud = rs.OrganizedCloud(xyz)
    labels = truth.astype(np.int32)
    fits = {1: FitFailure("plane", "pretend"), 2: FitFailure("plane", "pretend"), 3: FitFailure("plane", "x")}
    out_labels, out_fits = split_regions(context(cloud), labels, fits, [2])
    assert (out_labels[truth != 2] == truth[truth != 2]).all()
    assert not out_fits[1] and not out_fits[3] and out_fits[2].kind == "plane"


def test_a_region_of_pure_noise_keeps_its_failure(context):
    rng = np.random.default_rng(1)
    v, u = np.mgrid[0:30, 0:30].astype(float)
    cloud = rs.OrganizedCloud(np.dstack([u * 0.02, v * 0.02, 3.0 + rng.uniform(-0.3, 0.3, u.shape)]))
    failure = FitFailure("plane", "rms over the limit")
    labels, fits = split_regions(context(cloud), np.ones(cloud.shape, np.int32), {1: failure}, [1])
    assert fits == {1: failure} and (labels == 1).all()


def test_split_with_the_failed_regions_pixels_given_equals_the_split_that_finds_them(context):
    xyz, truth, _ = folded_strip(noise=0.001)
    cloud = rs.OrganizedCloud(xyz)
    labels = truth.astype(np.int32)
    fits = {k: FitFailure("plane", "pretend") for k in (1, 2, 3)}
    pixels = {k: np.flatnonzero(labels.ravel() == k) for k in (3, 1)}
    ctx = context(cloud)
    want_labels, want_fits = split_regions(ctx, labels, fits, [3, 1])
    got_labels, got_fits = split_regions(ctx, labels, fits, [3, 1], pixels=pixels)
    assert np.array_equal(got_labels, want_labels)
    assert got_fits.keys() == want_fits.keys()
    for k, model in got_fits.items():
        assert type(model) is type(want_fits[k])
        for f in fields(model):  # a failure's rms is NaN in both
            mine, theirs = getattr(model, f.name), getattr(want_fits[k], f.name)
            assert np.array_equal(mine, theirs) or (mine != mine and theirs != theirs), f.name


def test_a_split_of_the_callers_own_labels_changes_them_in_place_and_finds_the_same(context):
    xyz, truth, _ = folded_strip(noise=0.001)
    cloud = rs.OrganizedCloud(xyz)
    fits = {1: FitFailure("plane", "rms over the limit")}
    ctx = context(cloud, min_size=10)
    want_labels, want_fits = split_regions(ctx, np.ones(cloud.shape, np.int32), fits, [1])
    own = np.ones(cloud.shape, np.int32)
    got_labels, got_fits = split_regions(ctx, own, fits, [1], own=True)
    assert got_labels is own  # no copy: the caller handed over its own array
    assert np.array_equal(got_labels, want_labels) and len(np.unique(want_labels)) >= 3
    assert got_fits.keys() == want_fits.keys() and list(fits) == [1]
    for k, model in got_fits.items():
        assert model.kind == want_fits[k].kind and model.rms == want_fits[k].rms


def _narrow_corner(seed: int, half_width: int = 22, noise: float = 0.03):
    # two faces at 45 degrees meeting in a convex corner that points at the sensor,
    # ``half_width`` columns (1.5 cm each) wide each, ``noise`` range noise: a 32-row
    # lidar's box at 2.5 m; returns the cloud and each pixel's face (0 left, 1 right)
    h, w = 17, 2 * half_width
    v, u = np.mgrid[0:h, 0:w].astype(float)
    x = (u - (half_width - 0.5)) * 0.015
    z = 2.5 + np.abs(x) + np.random.default_rng(seed).normal(0.0, noise, x.shape)
    return rs.OrganizedCloud(np.dstack([x, v * 0.015, z])), (u >= half_width).astype(int)


@pytest.mark.parametrize("seed", [0, 1])  # the noise draws of test_context's corner
def test_a_split_with_the_face_band_gives_each_face_of_a_narrow_corner_its_own_pixels(seed):
    # Neither trimmed search explains the corner (its best three-point plane by a
    # three-sigma band is the diagonal one, which the fitter refuses); the one-sigma face
    # band finds one face with a strip of the other along the corner, and the other face is
    # found in what is left. The strip goes back to the plane it lies nearest: each region
    # holds its own face.
    from rangeseg_o3d.refinement.context import Context

    cloud, face = _narrow_corner(seed)
    pipeline = rs.Pipeline("spinning_lidar")
    ctx = Context(cloud, pipeline.fitter, np.full(cloud.shape, 0.03), 20)
    labels = np.ones(cloud.shape, np.int32)
    fits = {1: FitFailure("plane", "rms over the limit")}
    assert split_regions(ctx, labels, fits, [1])[1] == fits  # no face without the band
    out, found = split_regions(ctx, labels, fits, [1], face_band=True)
    assert sorted(found) == [1, 2] and all(found[k].kind == "plane" for k in (1, 2))
    for k in (1, 2):
        mine = face[out == k]
        side = np.bincount(mine).argmax()
        normal = np.array([1.0, 0.0, -1.0 if side else 1.0]) / np.sqrt(2.0)
        assert abs(found[k].normal @ normal) > np.cos(np.radians(5.0))
        # of the other face at most the corner's column on either side (noise along the rays)
        assert (mine == side).mean() > 0.93 and (mine == side).sum() > 0.8 * (face == side).sum()
