"""The compiled sums along the rays give numpy's bits: ``pairwise_sum`` against ``ndarray.sum``,
``ray_moment_sums`` against ``ray_moments``' earlier numpy form (kept here), ``pixel_ray_moments``
against that form of ``ray_terms`` of the pixels (``crease_line``'s search is in test_crease_cuts.py)."""

import numpy as np
import pytest

from rangeseg_o3d.kernels.rays import pairwise_sum, ray_moment_sums
from rangeseg_o3d.ray_planes import pixel_moments, ray_moments, ray_terms


def _terms(rng, n):
    points = rng.normal(size=(n, 3)) * [2.0, 1.0, 0.5] + [0.3, -0.2, 4.0]
    return ray_terms(points, rng.uniform(0.001, 0.05, n))


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 127, 128, 129, 135, 256, 1000, 8193, 100003])
def test_pairwise_sum_is_numpys_sum(n):
    rng = np.random.default_rng(n)
    a = rng.lognormal(size=n + 7) * 1e5
    assert pairwise_sum(a, 3, n) == a[3:3 + n].sum()
    assert pairwise_sum(a, 0, n) == a[:n].sum()


def test_pairwise_sum_differs_from_a_running_sum():
    # the test above would not notice a plain running sum if the two always agreed
    a = np.random.default_rng(1).lognormal(size=100003) * 1e5
    assert pairwise_sum(a, 0, a.size) != float(np.cumsum(a)[-1])


def _numpy_moments(rays, inverse, weight):
    # ray_moments before the kernel: the (N, 3, 3) products summed by numpy
    terms = (weight[:, None, None] * rays[:, :, None] * rays[:, None, :], (weight * inverse)[:, None] * rays,
             weight * inverse * inverse)
    return tuple(term.sum(axis=0)[None] for term in terms)


@pytest.mark.parametrize("n", [0, 1, 5, 64, 129, 1000, 40000, 250000])
def test_ray_moments_are_numpys_bits(n):
    rays, inverse, weight = _terms(np.random.default_rng(100 + n), n)
    want = _numpy_moments(rays, inverse, weight)
    got = ray_moments(rays, inverse, weight)
    assert [g.shape for g in got] == [(1, 3, 3), (1, 3), (1,)]
    for g, w in zip(got, want):
        assert np.array_equal(g, w)
    outer, first, second = ray_moment_sums(rays, inverse, weight)
    assert np.array_equal(outer, want[0][0]) and np.array_equal(first, want[1][0]) and second == want[2][0]
    if n > 1:
        assert second > 0.0 and outer[2, 2] > 0.0


@pytest.mark.parametrize("n", [0, 1, 9, 300, 5000, 120000])
def test_pixel_moments_are_the_moments_of_the_pixels_terms(n):
    rng = np.random.default_rng(200 + n)
    xyz = rng.normal(size=(n + 50, 3)) * [2.0, 1.0, 0.5] + [0.3, -0.2, 4.0]
    sigma = rng.uniform(0.001, 0.05, n + 50)
    xyz[:3] = [0.0, 0.0, 0.0]  # at the origin: the floored range
    sigma[3:6] = 0.0  # no noise: the floored sigma
    pixels = np.sort(rng.choice(n + 50, n, replace=False)) if n else np.empty(0, np.int64)
    want = _numpy_moments(*ray_terms(xyz[pixels], sigma[pixels]))
    got = pixel_moments(xyz, sigma, pixels)
    for g, w in zip(got, want):
        assert np.array_equal(g, w)
    # NaN stays NaN, as numpy's terms keep it
    xyz[pixels[:1]] = np.nan
    assert (np.isnan(pixel_moments(xyz, sigma, pixels)[2]).all() if n else True)


def test_box_ray_terms_are_the_numpy_terms_of_a_box_of_the_frame():
    # claim_along_rays' box before the kernel: copies, validity, np.where and ray_terms
    from rangeseg_o3d.kernels.rays import box_ray_terms

    rng = np.random.default_rng(7)
    h, w = 60, 80
    xyz = rng.normal(size=(h, w, 3)) * [1.0, 1.0, 0.2] + [0.0, 0.0, 3.0]
    sigma = rng.uniform(0.001, 0.05, (h, w))
    valid = rng.uniform(size=(h, w)) > 0.1
    xyz[5, 7] = np.nan  # a NaN point marked valid: not valid
    valid[5, 7] = True
    xyz[9, 30] = 0.0  # at the origin: the floored range
    r0, r1, c0, c1 = 3, 41, 5, 70  # a view, not contiguous
    points = xyz[r0:r1, c0:c1].reshape(-1, 3)
    want_valid = valid[r0:r1, c0:c1].reshape(-1) & np.isfinite(points).all(axis=1)
    want = ray_terms(np.where(want_valid[:, None], points, 1.0), sigma[r0:r1, c0:c1].reshape(-1))
    got_valid, *got = box_ray_terms(xyz[r0:r1, c0:c1], sigma[r0:r1, c0:c1], valid[r0:r1, c0:c1])
    assert np.array_equal(got_valid, want_valid) and not got_valid[(5 - r0) * (c1 - c0) + 7 - c0]
    assert 0.05 < 1.0 - got_valid.mean() < 0.2
    for g, wv in zip(got, want):
        assert g.shape == wv.shape and np.array_equal(g, wv)
