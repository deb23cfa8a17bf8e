"""kernels.plane_noise_sums / plane_noise_near and the Context tests built on them
(plane_along_rays, within_distance_noise): numpy's answers, or numpy asked where rounding
could decide."""

import numpy as np
import pytest

from rangeseg_o3d.fitting.primitives import Plane
from rangeseg_o3d.fitting.robust import beyond_noise, distance_noise
from rangeseg_o3d.kernels import plane_noise_near, plane_noise_sums
from rangeseg_o3d.refinement.context import TRIM_SIGMAS, Context


class _Cloud:
    # what Context reads of a cloud: flat-able points and the grid's width
    def __init__(self, xyz):
        self.xyz = xyz.reshape(1, -1, 3)
        self.shape = self.xyz.shape[:2]


def _wall(rng, n=3000, slant=0.0, noise_scale=1.0):
    # points of the plane z = 2 (tilted by ``slant`` radians about x) moved along their rays
    # by range noise growing with range
    u, v = rng.uniform(-0.8, 0.8, (2, n))
    rays = np.stack([u, v, np.ones(n)], axis=1)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    normal = np.array([0.0, np.sin(slant), np.cos(slant)])
    ranges = 2.0 / (rays @ normal)
    sigma = 0.002 * (1.0 + ranges ** 2)
    ranges = ranges + noise_scale * rng.normal(0.0, 1.0, n) * sigma
    return rays * ranges[:, None], sigma, Plane(normal=normal, d=2.0, rms=0.0, inliers=n)


def _numpy_beyond(plane, points, sigma):
    noise = distance_noise(plane, points, sigma)
    rms = float(np.sqrt(np.mean(plane.distances(points) ** 2)))
    return bool(beyond_noise(rms, float(np.sqrt(np.mean(noise * noise))), points.shape[0]))


@pytest.mark.parametrize("noise_scale, expected", [(1.0, False), (3.0, True)])
def test_plane_along_rays_answers_as_numpy(noise_scale, expected):
    rng = np.random.default_rng(5)
    points, sigma, plane = _wall(rng, slant=0.4, noise_scale=noise_scale)
    ctx = Context(_Cloud(points), None, sigma, 10)
    idx = np.arange(points.shape[0])
    assert _numpy_beyond(plane, points, sigma) is expected
    assert ctx._plane_beyond_noise(plane, idx) is expected  # decided by the compiled pass
    assert bool(ctx.plane_along_rays(plane, idx)) is expected


def test_plane_noise_sums_are_numpys_sums():
    rng = np.random.default_rng(7)
    points, sigma, plane = _wall(rng, slant=0.9)
    idx = np.arange(0, points.shape[0], 3)
    squares, noise_squares, scale, sigma_max = plane_noise_sums(points, sigma, idx, plane.normal, plane.d)
    noise = distance_noise(plane, points[idx], sigma[idx])
    np.testing.assert_allclose(squares, np.sum(plane.distances(points[idx]) ** 2), rtol=1e-12)
    np.testing.assert_allclose(noise_squares, np.sum(noise * noise), rtol=1e-12)
    assert sigma_max == sigma[idx].max() and scale >= 2.0


def test_a_bound_met_to_the_rounding_is_left_to_numpy():
    # the pixels' rms set on the bound itself: the compiled pass does not answer
    rng = np.random.default_rng(9)
    points, sigma, plane = _wall(rng, slant=0.3)
    ctx = Context(_Cloud(points), None, sigma, 10)
    idx = np.arange(points.shape[0])
    from rangeseg_o3d.kernels.linalg import CHI_SQUARE_SIGMAS, noise_rms_bound

    n, moved = idx.size, points
    for _ in range(4):  # each point moved along the normal so that the rms is the bound (the noise moves a little)
        squares, noise_squares, _, _ = plane_noise_sums(moved, sigma, idx, plane.normal, plane.d)
        bound = noise_rms_bound.py_func(np.sqrt(noise_squares / n), float(n), CHI_SQUARE_SIGMAS)
        distances = plane.distances(moved)
        moved = moved + (distances * (bound / np.sqrt(squares / n)) - distances)[:, None] * plane.normal
    ctx = Context(_Cloud(moved), None, sigma, 10)
    assert ctx._plane_beyond_noise(plane, idx) is None
    assert bool(ctx.plane_along_rays(plane, idx)) is _numpy_beyond(plane, moved, sigma)


def test_near_plane_matches_numpy_and_defers_on_a_tie():
    rng = np.random.default_rng(11)
    points, sigma, plane = _wall(rng, slant=0.9, noise_scale=2.5)
    idx = np.arange(points.shape[0])
    want = np.abs(plane.distances(points)) <= TRIM_SIGMAS * distance_noise(plane, points, sigma)
    assert 0 < want.sum() < want.size  # the test decides both ways
    ctx = Context(_Cloud(points), None, sigma, 10)
    np.testing.assert_array_equal(ctx._near_plane(idx, plane), want)
    # one point put on its own bound: the compiled pass leaves the whole answer to numpy
    near, unsure = plane_noise_near(points, sigma, idx, plane.normal, plane.d, TRIM_SIGMAS, 1e-9,
                                    64 * np.finfo(float).eps)
    assert not unsure
    tied = points.copy()
    for _ in range(4):  # (the point's noise moves with it a little)
        noise0 = distance_noise(plane, tied[:1], sigma[:1])[0]
        tied[0] += (TRIM_SIGMAS * noise0 - plane.distances(tied[:1])[0]) * plane.normal
    _, unsure = plane_noise_near(tied, sigma, idx, plane.normal, plane.d, TRIM_SIGMAS, 1e-9,
                                 64 * np.finfo(float).eps)
    assert unsure
    assert Context(_Cloud(tied), None, sigma, 10)._near_plane(idx, plane) is None


def _numpy_pretest(model, points, sigma, k_sigma):
    # merge_into_curved's pretest as numpy words it: 1 near, 0 far
    from rangeseg_o3d._numeric import median

    return int(not median(np.abs(model.distances(points))) > k_sigma * median(sigma))


def test_pieces_near_models_answers_as_numpy_for_each_kind():
    from rangeseg_o3d.fitting.primitives import Cylinder, Sphere
    from rangeseg_o3d.fitting.region_fitter import model_row
    from rangeseg_o3d.kernels import pieces_near_models

    rng = np.random.default_rng(13)
    models = [Plane(normal=np.array([0.0, 0.6, 0.8]), d=2.0, rms=0.0, inliers=0),
              Cylinder(axis=np.array([0.0, 1.0, 0.0]), point=np.array([0.2, 0.0, 2.5]), radius=0.3, rms=0.0, inliers=0),
              Sphere(center=np.array([-0.3, 0.1, 3.0]), radius=0.4, rms=0.0, inliers=0)]
    points = rng.uniform(-1.0, 1.0, (4000, 3)) * [1.0, 1.0, 0.5] + [0.0, 0.0, 2.5]
    sigma = rng.uniform(0.002, 0.01, 4000)
    # pieces of 1 to 401 pixels (odd and even counts), each against each kind, at 3 and 300 sigmas
    sizes = [1, 2, 7, 40, 401, 400]
    starts = np.concatenate([[0], np.cumsum(sizes * 3)])
    pixels = rng.permutation(4000)[:starts[-1]].astype(np.int64)
    rows = [model_row(m) for m in models for _ in sizes]
    kinds, params = np.array([k for k, _ in rows], np.int8), np.array([p for _, p in rows])
    answers = set()
    for k_sigma in (3.0, 300.0):
        got = pieces_near_models(points, sigma, pixels, starts, kinds, params, k_sigma, 1e-9, 64 * np.finfo(float).eps)
        want = [_numpy_pretest(models[j // len(sizes)], points[pixels[a:b]], sigma[pixels[a:b]], k_sigma)
                for j, (a, b) in enumerate(zip(starts[:-1], starts[1:]))]
        assert got.tolist() == want
        answers.update(want)
    assert answers == {0, 1}  # (both answers given)


def test_pieces_near_models_leaves_a_tie_and_an_empty_piece_to_numpy():
    from rangeseg_o3d.fitting.region_fitter import model_row
    from rangeseg_o3d.kernels import pieces_near_models

    plane = Plane(normal=np.array([0.0, 0.0, 1.0]), d=2.0, rms=0.0, inliers=0)
    sigma = np.full(3, 0.01)
    points = np.array([[0.0, 0.0, 2.0 + 0.01], [0.1, 0.0, 2.0 - 0.03], [0.2, 0.0, 2.0 + 0.05]])  # median 0.03 = 3 sigma
    kind, row = model_row(plane)
    starts = np.array([0, 3, 3], np.int64)
    got = pieces_near_models(points, sigma, np.arange(3, dtype=np.int64), starts, np.array([kind, kind], np.int8),
                             np.array([row, row]), 3.0, 1e-9, 64 * np.finfo(float).eps)
    assert got.tolist() == [-1, -1]


@pytest.mark.parametrize("slant", [0.0, 0.9, 1.4])
def test_plane_distances_noise_are_numpys_values(slant):
    # faces_of_plane's distances and noise from one pass: numpy's Plane.distances and
    # distance_noise within a few units of the last place of the terms, pixel by pixel
    from rangeseg_o3d.kernels import plane_distances_noise

    rng = np.random.default_rng(11)
    points, sigma, plane = _wall(rng, slant=slant, noise_scale=2.0)
    idx = np.sort(rng.choice(points.shape[0], 1000, replace=False))
    distances, noise = plane_distances_noise(points, sigma, idx, plane.normal, plane.d)
    assert distances.shape == noise.shape == (1000,)
    terms = np.abs(points[idx]) @ np.abs(plane.normal) + abs(plane.d)
    assert np.all(np.abs(distances - plane.distances(points[idx])) <= 4e-16 * terms)
    want = distance_noise(plane, points[idx], sigma[idx])
    assert np.all(np.abs(noise - want) <= 4e-16 * sigma[idx])
    assert np.all(noise >= 0.0) and np.any(noise > 0.5 * sigma[idx])
    # and the sums of plane_noise_sums are theirs
    squares, noise_squares, _, _ = plane_noise_sums(points, sigma, idx, plane.normal, plane.d)
    np.testing.assert_allclose([squares, noise_squares], [np.sum(distances ** 2), np.sum(noise ** 2)], rtol=1e-12)
