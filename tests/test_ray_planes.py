"""Planes fitted along the viewing rays (rangeseg_o3d.ray_planes): the exact plane of exact
points, the robust fit's own tests are with the strips it serves (tests/test_strips.py), and
whether a plane is seen near grazing."""

import numpy as np
import pytest

from rangeseg_o3d.ray_planes import ray_fits, ray_moments, ray_plane, ray_terms, seen_near_grazing
from rangeseg_o3d.scales import GRAZING_COSINE


def _on_plane(normal, d, rows=20, cols=30):
    # points of the plane n . p = d along a pinhole camera's rays (f = 100 px, centred grid)
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / 100.0, (v - rows / 2) / 100.0, np.ones((rows, cols))]).reshape(-1, 3)
    return rays * (d / (rays @ normal))[:, None]


def test_the_plane_of_exact_points_is_their_plane_with_no_residual():
    normal = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    d = 5.0
    points = _on_plane(normal, d)
    rays, inverse, weight = ray_terms(points, np.full(len(points), 0.01))
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(inverse, 1.0 / np.linalg.norm(points, axis=1), rtol=1e-12)
    chi2, a = ray_fits(ray_moments(rays, inverse, weight))
    np.testing.assert_allclose(a[0], normal / d, rtol=1e-8)
    assert chi2[0] < 1e-6 * float(np.sum(weight * inverse ** 2))  # (against the sum it starts from)
    plane = ray_plane(a[0], points)
    np.testing.assert_allclose(plane.normal, normal, atol=1e-8)
    assert plane.d == pytest.approx(d, rel=1e-8) and plane.rms < 1e-8 * d and plane.inliers == len(points)


def test_no_plane_from_a_zero_or_undefined_a():
    points = np.ones((5, 3))
    assert ray_plane(np.zeros(3), points) is None
    assert ray_plane(np.array([np.nan, 0.0, 1.0]), points) is None


def test_a_far_floor_is_seen_near_grazing_and_a_head_on_wall_is_not():
    # a floor 0.5 m under the camera seen 4-6 m off (its rays meet it at cosines of about
    # 0.1), a wall 5 m ahead, seen head-on (cosines near 1)
    x, z = np.meshgrid(np.linspace(-1.0, 1.0, 30), np.linspace(4.0, 6.0, 20))
    floor = np.column_stack([x.ravel(), np.full(x.size, 0.5), z.ravel()])
    cosines = np.abs(floor[:, 1]) / np.linalg.norm(floor, axis=1)
    assert np.median(cosines) < GRAZING_COSINE  # the premise
    assert seen_near_grazing(np.array([0.0, 1.0, 0.0]) / 0.5, floor)
    wall = _on_plane(np.array([0.0, 0.0, 1.0]), 5.0)
    assert not seen_near_grazing(np.array([0.0, 0.0, 1.0]) / 5.0, wall)
    # the same floor 1.2 m under the camera: cosines 0.2-0.3, over the grazing bound
    nearer = floor * np.array([1.0, 1.2 / 0.5, 1.0])
    assert np.median(np.abs(nearer[:, 1]) / np.linalg.norm(nearer, axis=1)) > GRAZING_COSINE  # the premise
    assert not seen_near_grazing(np.array([0.0, 1.0, 0.0]) / 1.2, nearer)


def _strip(seed, rows=3, cols=60, noise=0.004, ends=4):
    # a face strip rows x cols on the plane z = 2 + 0.4 x seen along a pinhole camera's rays,
    # range noise ``noise`` along the rays, its last ``ends`` columns on a wall 0.3 m nearer
    # (pixels of the surface beside it): (rays, inverse, weight, rows, cols, truth a, wall pixels)
    rng = np.random.default_rng(seed)
    normal = np.array([-0.4, 0.0, 1.0]) / np.linalg.norm([-0.4, 0.0, 1.0])
    d = 2.0 / np.linalg.norm([-0.4, 0.0, 1.0])
    points = _on_plane(normal, d, rows, cols)
    grid_r, grid_c = np.divmod(np.arange(rows * cols), cols)
    wall = grid_c >= cols - ends
    points[wall] *= ((points[wall, 2] - 0.3) / points[wall, 2])[:, None]
    ranges = np.linalg.norm(points, axis=1)
    points *= ((ranges + rng.normal(0.0, noise, ranges.size)) / ranges)[:, None]
    rays, inverse, weight = ray_terms(points, np.full(len(points), noise))
    return rays, inverse, weight, grid_r, grid_c, normal / d, wall


@pytest.mark.parametrize("seed", range(12))
def test_the_robust_fit_is_numpys_fit_bit_for_bit(seed):
    # robust_ray_plane decides its trial planes and trims in compiled arithmetic and solves its
    # plane from numpy's sums: the same a, kept pixels and mean square as the numpy fit
    from rangeseg_o3d.ray_planes import _robust_ray_plane_numpy, robust_ray_plane

    shapes = [(3, 60, 4), (2, 40, 0), (5, 30, 6), (1, 80, 3)]
    rows, cols, ends = shapes[seed % len(shapes)]
    rays, inverse, weight, r, c, truth, wall = _strip(seed, rows, cols, ends=ends)
    along = c if c.max() - c.min() >= r.max() - r.min() else r
    found = robust_ray_plane(rays, inverse, weight, r, c)
    reference = _robust_ray_plane_numpy(rays, inverse, weight, along)
    assert found is not None and reference is not None
    assert np.array_equal(found[0], reference[0])  # (bits: array_equal on floats)
    assert np.array_equal(found[1], reference[1])
    assert found[2] == reference[2]
    # the values: the face's inverse ranges along its rays within 0.2 % (its tilt across a strip
    # this thin is the noise's), the wall's pixels left out, most face pixels kept
    np.testing.assert_allclose(rays[~wall] @ found[0], rays[~wall] @ truth, rtol=2e-3)
    np.testing.assert_allclose(found[0][[0, 2]], truth[[0, 2]], rtol=0.02)
    assert not found[1][wall].any()
    assert found[1][~wall].mean() > 0.9
    assert 0.3 < found[2] < 2.0


def test_the_robust_fit_leaves_a_decision_at_its_threshold_to_numpy():
    # every chunk the same points: the 37 trial planes tie, so the compiled pick is too near to
    # call (status 2) and numpy's own fit answers
    from rangeseg_o3d.kernels import robust_ray_sets
    from rangeseg_o3d.ray_planes import (ROBUST_CHUNKS, SCREEN_TOLERANCE, TRIM_PASSES, _robust_ray_plane_numpy,
                                         robust_ray_plane)
    from rangeseg_o3d.refinement.context import TRIM_SIGMAS

    rays, inverse, weight, r, c, truth, _ = _strip(3, 1, 8, ends=0)
    rays, inverse, weight = np.tile(rays, (4, 1)), np.tile(inverse, 4), np.tile(weight, 4)
    along = np.repeat(np.arange(8), 4)
    status, _, _ = robust_ray_sets(rays, inverse, weight, along, ROBUST_CHUNKS, TRIM_PASSES, float(TRIM_SIGMAS),
                                   SCREEN_TOLERANCE)
    assert status == 2
    found = robust_ray_plane(rays, inverse, weight, np.zeros(32, np.int64), along)
    reference = _robust_ray_plane_numpy(rays, inverse, weight, along)
    assert np.array_equal(found[0], reference[0]) and np.array_equal(found[1], reference[1])
    np.testing.assert_allclose(rays @ found[0], rays @ truth, rtol=5e-3)  # (8 pixels, 0.2 % noise each)


def test_the_robust_fit_of_too_few_pixels_or_no_plane_is_none():
    from rangeseg_o3d.ray_planes import ROBUST_CHUNKS, robust_ray_plane

    rays, inverse, weight, r, c, _, _ = _strip(0, 1, 3 * ROBUST_CHUNKS - 1, ends=0)
    assert robust_ray_plane(rays, inverse, weight, r, c) is None
    # zero weights: every trial's chi-square is 0 and no system is solvable -> numpy's answer
    rays, inverse, weight, r, c, _, _ = _strip(0, 2, 30, ends=0)
    from rangeseg_o3d.ray_planes import _robust_ray_plane_numpy
    with np.errstate(all="ignore"):
        try:
            reference = _robust_ray_plane_numpy(rays, inverse, np.zeros_like(weight), c)
        except np.linalg.LinAlgError:
            reference = "raises"
        try:
            found = robust_ray_plane(rays, inverse, np.zeros_like(weight), r, c)
        except np.linalg.LinAlgError:
            found = "raises"
    assert type(found) is type(reference)


@pytest.mark.parametrize("seed", range(6))
def test_the_compiled_ray_terms_are_numpys_bit_for_bit(seed):
    # ray_terms of float64 points takes one compiled pass (kernels.ray_terms_of): the same bits
    # as the numpy form, over ranges from millimetres to kilometres, sigmas at and under the
    # 1e-12 floor, a NaN sigma and a point at the origin (its range floored at 1e-12)
    from rangeseg_o3d.ray_planes import _ray_terms_numpy

    rng = np.random.default_rng(seed)
    points = rng.normal(size=(500, 3)) * 10.0 ** rng.uniform(-3, 3, size=(500, 1))
    sigma = 10.0 ** rng.uniform(-14, -1, size=500)
    points[0] = 0.0
    sigma[1] = np.nan
    sigma[2] = 1e-12
    found = ray_terms(points, sigma)
    reference = _ray_terms_numpy(points, sigma)
    for got, want in zip(found, reference):
        assert got.shape == want.shape and got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)  # (NaN where numpy has NaN, every other bit equal)
        assert np.array_equal(got, want, equal_nan=True)
    # the values: unit rays, the inverse range, the weight range**4 / sigma**2 (sigma floored)
    ranges = np.linalg.norm(points[3:], axis=1)
    np.testing.assert_allclose(np.linalg.norm(found[0][3:], axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(found[1][3:], 1.0 / ranges, rtol=1e-12)
    np.testing.assert_allclose(found[2][3:], ranges ** 4 / np.maximum(sigma[3:], 1e-12) ** 2, rtol=1e-9)
    assert found[1][0] == 1e12 and np.isnan(found[2][1])
    # a strided view and a float32 cloud give numpy's answers too (the latter in numpy itself)
    view = np.asfortranarray(points)
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(ray_terms(view, sigma), reference))
    single = points.astype(np.float32)
    assert all(np.array_equal(a, b, equal_nan=True)
               for a, b in zip(ray_terms(single, sigma), _ray_terms_numpy(single, sigma)))
