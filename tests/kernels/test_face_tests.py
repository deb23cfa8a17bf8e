"""The compiled tests of a face fitted along the rays (rangeseg_o3d.kernels.tilt_noise,
plane_scores) against the numpy forms they replaced in rangeseg_o3d.off_model: the same
values within their rounding (sums added pixel after pixel, a closed-form 3x3 inverse and
2x2 eigenvalue, against BLAS/LAPACK and numpy's pairwise sums)."""

import numpy as np
import pytest

from rangeseg_o3d.fitting.primitives import Plane
from rangeseg_o3d.ray_planes import ray_terms

KINECT = 1.425e-3  # range noise sigma = KINECT z^2 (metres)


def _face(seed, n=300, spread=0.2, distance=3.0, turn_deg=40.0, noise=True):
    # n pixels of a plane turned by turn_deg about the y axis at `distance`, rays within
    # `spread` (tangent) of the optical axis; range noise along the rays
    rng = np.random.default_rng(seed)
    theta = np.radians(turn_deg)
    normal = np.array([np.sin(theta), 0.0, np.cos(theta)])
    uv = rng.uniform(-spread, spread, (n, 2))
    rays = np.column_stack([uv, np.ones(n)])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    ranges = distance / (rays @ normal)
    sigma = KINECT * ranges ** 2
    if noise:
        ranges = ranges + rng.normal(0.0, 1.0, n) * sigma
    return rays * ranges[:, None], sigma, Plane(normal, distance, rms=0.0, inliers=n)


@pytest.mark.parametrize("seed", range(6))
def test_tilt_bound_compiled_agrees_with_numpy_and_shrinks_with_the_count(seed):
    from rangeseg_o3d.off_model import _tilt_bound, _tilt_bound_numpy

    rng = np.random.default_rng(100 + seed)
    points, sigma, plane = _face(seed, n=int(rng.integers(40, 400)), spread=float(rng.uniform(0.02, 0.4)),
                                 turn_deg=float(rng.uniform(0.0, 80.0)))
    rays, _, weight = ray_terms(points, sigma)
    a = plane.normal / plane.d * (1.0 + rng.normal(0.0, 1e-3, 3))
    keep = rng.random(weight.size) < 0.85
    for max_angle in (0.0, 3.0):
        normal, bound = _tilt_bound(a, rays, weight, max_angle, keep)
        normal0, bound0 = _tilt_bound_numpy(a, rays[keep], weight[keep], max_angle)
        assert np.array_equal(normal, normal0)
        assert bound == pytest.approx(bound0, rel=1e-9)
    # values: the normal is a's direction; the bound is at least the angle; four times the
    # pixels (each ray repeated) halve the tilt noise
    assert np.allclose(normal, a / np.linalg.norm(a), rtol=0, atol=1e-15)
    assert bound >= np.radians(3.0)
    _, noise1 = _tilt_bound(a, rays, weight, 0.0, keep)
    _, noise4 = _tilt_bound(a, np.tile(rays, (4, 1)), np.tile(weight, 4), 0.0, np.tile(keep, 4))
    assert noise4 == pytest.approx(0.5 * noise1, rel=1e-9)
    # no mask: every row
    assert _tilt_bound(a, rays, weight, 0.0)[1] == pytest.approx(_tilt_bound_numpy(a, rays, weight, 0.0)[1], rel=1e-9)


def test_tilt_bound_none_for_no_plane_or_singular_sums_and_numpy_for_other_dtypes():
    from rangeseg_o3d.off_model import _tilt_bound, _tilt_bound_numpy

    points, sigma, plane = _face(0)
    rays, _, weight = ray_terms(points, sigma)
    a = plane.normal / plane.d
    assert _tilt_bound(np.zeros(3), rays, weight, 3.0) is None
    assert _tilt_bound(np.array([np.nan, 0.0, 1.0]), rays, weight, 3.0) is None
    # every ray the optical axis: the sums span one direction, no tilt is determined
    axis = np.tile([0.0, 0.0, 1.0], (50, 1))
    assert _tilt_bound(a, axis, np.ones(50), 3.0) is None
    assert _tilt_bound_numpy(a, axis, np.ones(50), 3.0) is None
    # float32 rays: numpy's form
    got = _tilt_bound(a, rays.astype(np.float32), weight.astype(np.float32), 0.0)
    want = _tilt_bound_numpy(a, rays.astype(np.float32), weight.astype(np.float32), 0.0)
    assert np.array_equal(got[0], want[0]) and got[1] == want[1]
    with pytest.raises(ValueError, match="keep"):
        _tilt_bound(a, rays, weight, 3.0, np.ones(3, bool))


def _numpy_scores(rays, inverse, weight, keep, planes, own):
    # planes_keeping's arithmetic per plane (numpy), on the kept rows
    from rangeseg_o3d.refinement.context import TRIM_SIGMAS

    rays, inverse, weight = rays[keep], inverse[keep], weight[keep]
    mine = weight * (inverse - rays @ (own.normal / own.d)) ** 2
    out = []
    for plane in planes:
        squares = weight * (inverse - rays @ (plane.normal / plane.d)) ** 2
        kept = squares <= TRIM_SIGMAS * TRIM_SIGMAS
        out.append((int(np.count_nonzero(kept)), float(np.mean(squares[kept])) if kept.any() else np.nan,
                    float(np.mean(mine[kept])) if kept.any() else np.nan))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_plane_scores_agree_with_numpy_on_every_plane(seed):
    from rangeseg_o3d.off_model import _plane_scores

    rng = np.random.default_rng(200 + seed)
    points, sigma, plane = _face(seed, n=int(rng.integers(60, 2000)))
    rays, inverse, weight = ray_terms(points, sigma)
    shifted = Plane(plane.normal, plane.d + 1.5 * KINECT * plane.d ** 2, rms=0.0, inliers=0)
    turned = Plane(np.array([0.0, 0.0, 1.0]), plane.d, rms=0.0, inliers=0)
    far = Plane(plane.normal, plane.d * 1.5, rms=0.0, inliers=0)
    planes = [plane, shifted, turned, far]
    keep = rng.random(weight.size) < 0.9
    counts, means, owns = _plane_scores(rays, inverse, weight, keep, planes, plane)
    assert counts.size == means.size == owns.size == 5  # the planes, then the own plane
    want = _numpy_scores(rays, inverse, weight, keep, planes + [plane], plane)
    for k, (n, mean, own) in enumerate(want):
        assert counts[k] == n
        if n:
            assert means[k] == pytest.approx(mean, rel=1e-12)
            assert owns[k] == pytest.approx(own, rel=1e-12)
        else:
            assert np.isnan(means[k]) and np.isnan(owns[k])
    # values: the true plane keeps nearly every pixel at a mean square near 1 (noise units);
    # the shifted one fewer at a larger mean square; the far one none
    size = int(keep.sum())
    assert counts[0] > 0.98 * size and 0.75 < means[0] < 1.25
    assert counts[1] < counts[0] and means[1] > means[0]
    assert counts[3] == 0 and np.isnan(means[3])
    assert means[4] == means[0] and owns[0] == means[0]


def test_plane_scores_no_own_plane_and_no_planes():
    from rangeseg_o3d.off_model import _plane_scores

    points, sigma, plane = _face(1)
    rays, inverse, weight = ray_terms(points, sigma)
    counts, means, owns = _plane_scores(rays, inverse, weight, None, [plane], None)
    assert counts.size == 1 and counts[0] > 0.98 * weight.size and np.isnan(owns[0])
    counts, means, owns = _plane_scores(rays, inverse, weight, None, [], None)
    assert counts.size == means.size == owns.size == 0


def test_pixel_plane_scores_are_plane_scores_of_the_pixels_ray_terms():
    # the same bits: the terms are ray_terms' (kernels.growth._ray_term), the sums the same
    from rangeseg_o3d.kernels import pixel_plane_scores, plane_scores

    points, sigma, plane = _face(3, n=800)
    rng = np.random.default_rng(3)
    xyz = np.vstack([points, rng.normal(size=(200, 3))])
    noise = np.concatenate([sigma, np.full(200, 0.01)])
    idx = np.sort(rng.choice(800, 500, replace=False)).astype(np.int64)
    table = np.array([plane.normal / plane.d, plane.normal / (1.01 * plane.d)])
    own = plane.normal / plane.d
    rays, inverse, weight = ray_terms(xyz[idx], noise[idx])
    got = pixel_plane_scores(xyz, noise, idx, table, own, 3.0)
    want = plane_scores(rays, inverse, weight, np.ones(idx.size, bool), table, own, 3.0)
    for g, w in zip(got, want):
        assert np.array_equal(g, w)
    assert got[0][0] > 0.98 * idx.size and got[0][1] < got[0][0]
