"""The recover step's compiled passes (kernels.leftovers, kernels.leftover_blobs for
leftover_candidates) against the numpy and OpenCV forms they replace, on random grids and on
the grids the LMS200 suite's recovery sees (its scans' labels when the step starts)."""

import pickle

import cv2
import numpy as np
import pytest

import rangeseg_o3d as rs
import rangeseg_o3d.refinement as refinement
import rangeseg_o3d.refinement.recover as recover
from rangeseg_o3d._numeric import rows_at
from rangeseg_o3d.fitting.region_fitter import fresh_label, model_table
from rangeseg_o3d.kernels import first_ring_grows, grow_rings
from rangeseg_o3d.kernels.leftovers import free_near_planes_reach, strip_pool
from rangeseg_o3d.synthetic.suite import lms200_suite
from refinement_helpers import leftover_candidates_numpy


@pytest.fixture(scope="module")
def suite_calls():
    """The recovery's inputs on the LMS200 suite (seed 0): ``(ctx, labels, fits, keywords)``
    per scan, as refine_regions passes them to recover_leftovers."""
    calls = []
    real = refinement.recover_leftovers

    def capture(ctx, labels, fits, **kw):
        calls.append((ctx, labels.copy(), dict(fits), kw))
        return real(ctx, labels, fits, **kw)

    pipeline = rs.Pipeline("lms200")
    refinement.recover_leftovers = capture
    try:
        for _, scan in lms200_suite(seed=0):
            pipeline.run(scan.cloud)
    finally:
        refinement.recover_leftovers = real
    assert len(calls) == 10
    return calls


def _same_fits(a: dict, b: dict) -> bool:
    # the same labels with the same models, to the bit (their pickles: arrays and floats)
    return a.keys() == b.keys() and all(pickle.dumps(a[k]) == pickle.dumps(b[k]) for k in a)


def _numpy_strips(labels, valid, candidates, min_size):
    # claim_thin_strips' pool in OpenCV and numpy (before kernels.leftovers.strip_pool)
    free = valid & (labels == 0) & (candidates == 0)
    n, strips = cv2.connectedComponents(free.astype(np.uint8), connectivity=4, ltype=cv2.CV_32S)
    kept = np.bincount(strips.ravel(), minlength=n) >= min_size
    kept[0] = False
    return np.flatnonzero(kept[strips].ravel())


def _random_grid(seed, shape=(45, 70)):
    rng = np.random.default_rng(seed)
    labels = rng.integers(1, 5, shape).astype(np.int32)
    labels[rng.random(shape) < rng.uniform(0.05, 0.5)] = 0
    for _ in range(rng.integers(1, 8)):  # blobs and strips of every width, some on the border
        r, c = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        labels[r:r + rng.integers(1, 15), c:c + rng.integers(1, 15)] = 0
    valid = rng.random(shape) > 0.05
    jumps = rng.random(shape) < 0.04
    return labels, valid, jumps


@pytest.mark.parametrize("seed", range(12))
def test_leftover_candidates_and_strips_equal_the_opencv_form_on_random_grids(seed):
    labels, valid, jumps = _random_grid(seed)
    for min_size, first in ((1, 5), (5, 9), (20, 3), (60, 11)):
        expected = leftover_candidates_numpy(labels, valid, jumps, min_size, first)
        got = recover.leftover_candidates(labels, valid, jumps, min_size=min_size, first_label=first)
        assert got.dtype == np.int32
        np.testing.assert_array_equal(got, expected)
        pool = strip_pool(labels, valid, expected, min_size)
        np.testing.assert_array_equal(pool, _numpy_strips(labels, valid, expected, min_size))


def test_leftover_candidates_and_strips_equal_the_opencv_form_on_the_suite(suite_calls):
    found = strips = 0
    for ctx, labels, fits, kw in suite_calls:
        first = fresh_label(labels, fits)
        expected = leftover_candidates_numpy(labels, kw["valid"], kw["jumps"], ctx.min_size, first)
        got = recover.leftover_candidates(labels, kw["valid"], kw["jumps"], min_size=ctx.min_size, first_label=first)
        np.testing.assert_array_equal(got, expected)
        pool = strip_pool(np.ascontiguousarray(labels), kw["valid"], got, ctx.min_size)
        expected_pool = _numpy_strips(labels, kw["valid"], got, ctx.min_size)
        np.testing.assert_array_equal(pool, expected_pool)
        found += int(got.any())
        strips += int(pool.size > 0)
    assert found >= 8 and strips >= 5  # (the suite's scans have blobs and strips to compare)


def _numpy_near_count(labels, valid, xyz, sigma, normals, offsets, rms, k_sigma):
    # claim_occluded_strips' count of free pixels within the noise of some plane (numpy)
    free = np.flatnonzero((valid & (labels == 0)).ravel())
    within = np.abs(rows_at(xyz, free) @ normals.T - offsets) <= k_sigma * np.maximum(sigma[free, None], rms)
    return int(within.any(axis=1).sum())


def _plane_scene(seed):
    # a 40 x 60 grid of points near three planes, noise 2-8 mm, some pixels free
    rng = np.random.default_rng(seed)
    h, w = 40, 60
    v, u = np.mgrid[0:h, 0:w].astype(float)
    rays = np.dstack([(u - w / 2) / 60.0, (v - h / 2) / 60.0, np.ones((h, w))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    normals = rng.normal(size=(3, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[:, 2] = -np.abs(normals[:, 2]) - 0.3
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    offsets = -rng.uniform(2.0, 5.0, 3)
    which = (u * 3 // w).astype(int)
    ranges = offsets[which] / np.einsum("hwk,hwk->hw", rays, normals[which])
    sigma = np.full((h, w), rng.uniform(0.002, 0.008))
    xyz = rays * (ranges + rng.normal(0.0, 1.0, (h, w)) * sigma * rng.uniform(0.5, 6.0))[..., None]
    labels = (which + 1).astype(np.int32)
    labels[rng.random((h, w)) < rng.uniform(0.02, 0.4)] = 0
    valid = rng.random((h, w)) > 0.03
    return labels, valid, xyz.reshape(-1, 3), sigma.ravel(), normals, offsets, rng.uniform(0.0, 0.01, 3)


@pytest.mark.parametrize("seed", range(20))
def test_free_near_planes_screen_agrees_with_the_numpy_count(seed):
    labels, valid, xyz, sigma, normals, offsets, rms = _plane_scene(seed)
    for k_sigma in (1.0, 3.0):
        count = _numpy_near_count(labels, valid, xyz, sigma, normals, offsets, rms, k_sigma)
        for asked in (0, 1, count - 1, count, count + 1, count + 50):
            got = free_near_planes_reach(labels, valid, xyz, sigma, normals, offsets, rms, k_sigma, asked, 1e-9)
            # (random scenes hold no distance within 1e-9 of its bound: the screen counts numpy's)
            assert got == (count >= asked), (asked, count)


def test_claim_occluded_strips_answers_as_without_its_screen(suite_calls, monkeypatch):
    # on the suite's grids after the recovery's blobs (and on its grids before them): the
    # step's labels and fits with the screen are those of the numpy steps alone
    runs = []
    for ctx, labels, fits, kw in suite_calls:
        recovered = recover.recover_leftovers(ctx, labels, fits, **{**kw, "claim_strips": False})
        runs += [(ctx, labels, fits, kw), (ctx, *recovered, kw)]
    screened = [recover.claim_occluded_strips(ctx, lab, f, valid=kw["valid"], k_sigma=kw["k_sigma"])
                for ctx, lab, f, kw in runs]
    monkeypatch.setattr(recover, "free_near_planes_reach", lambda *args: True)
    claimed = 0
    for (ctx, lab, f, kw), (got_labels, got_fits) in zip(runs, screened):
        want_labels, want_fits = recover.claim_occluded_strips(ctx, lab, f, valid=kw["valid"], k_sigma=kw["k_sigma"])
        np.testing.assert_array_equal(got_labels, want_labels)
        assert _same_fits(got_fits, want_fits)
        claimed += int(not np.array_equal(want_labels, lab))
    assert claimed >= 1  # (the numpy path claims something on some grid: the screen let it through)


@pytest.mark.parametrize("seed", range(6))
def test_first_ring_grows_is_whether_grow_rings_adds_a_pixel(seed):
    labels, valid, xyz, sigma, normals, offsets, rms = _plane_scene(seed)
    from rangeseg_o3d.fitting.primitives import Plane

    xyz = np.where(valid.reshape(-1, 1), xyz, np.nan)
    ranges = np.linalg.norm(xyz, axis=1)
    fits = {k + 1: Plane(normal=normals[k], d=float(offsets[k]), rms=float(rms[k]), inliers=100) for k in range(3)}
    for only in ([1], [2, 3], [1, 2, 3]):
        for k_sigma in (0.01, 0.5, 3.0):
            kinds, params, table_rms = model_table({k: fits[k] for k in only}, int(labels.max()) + 1)
            grown = labels.copy()
            added = grow_rings(xyz, grown, kinds, params, table_rms, sigma, ranges, 1, k_sigma, 0.08, 0.05)
            assert first_ring_grows(xyz, labels, kinds, params, table_rms, sigma, ranges, k_sigma, 0.08, 0.05) == (added > 0)


def test_grow_recovered_curves_answers_as_without_its_screen(suite_calls, monkeypatch):
    # the suite's recovered cylinders (about half its scans) with the screen and with growth run
    runs = []
    for ctx, labels, fits, kw in suite_calls:
        before = set(fits)
        growth = {k: kw[k] for k in ("xyz", "ranges", "sigma", "k_sigma", "jump_ratio", "jump_min")}
        runs.append((ctx, *recover.recover_leftovers(ctx, labels, fits, **kw), before, growth))
    screened = [refinement.grow_recovered_curves(ctx, lab, f, before, **growth) for ctx, lab, f, before, growth in runs]
    monkeypatch.setattr(refinement, "grows_any", lambda *args, **kwargs: True)
    curved = 0
    for (ctx, lab, f, before, growth), (got_labels, got_fits) in zip(runs, screened):
        want_labels, want_fits = refinement.grow_recovered_curves(ctx, lab, f, before, **growth)
        np.testing.assert_array_equal(got_labels, want_labels)
        assert _same_fits(got_fits, want_fits)
        curved += any(m and m.kind != "plane" and k not in before for k, m in f.items())
    assert curved >= 3
