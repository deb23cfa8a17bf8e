"""The compiled tests of a face fitted along the rays (rangeseg_o3d.kernels.tilt_noise)
against the numpy forms they replaced in rangeseg_o3d.off_model: the same values within
their rounding (sums added pixel after pixel, a closed-form 3x3 inverse and 2x2 eigenvalue,
against BLAS/LAPACK)."""

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
