"""kernels.within_plane_noise: the claim test of refinement.recover, compiled."""

import numpy as np

from rangeseg_o3d.kernels import within_plane_noise


def _numpy_form(points, sigma, normals, offsets, rms, k_sigma):
    along = sum(points[:, axis, None] * normals[None, :, axis] for axis in range(3))
    cosines = np.abs(along) / np.maximum(np.linalg.norm(points, axis=1), 1e-12)[:, None]
    noise = np.maximum(sigma[:, None] * cosines, rms)
    return np.abs(along - offsets) <= k_sigma * noise


def _scene(rng, n=4000):
    # points scattered about three planes at 1-4 m, 5 mm range noise growing with range
    normals = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -1.0, 0.0]])
    offsets = np.array([3.0, 2.0, -0.5])
    owner = rng.integers(0, 3, n)
    u, v = rng.uniform(-1.0, 1.0, (2, n))
    seeds = np.stack([u, v, np.ones(n)], axis=1)
    along = seeds @ normals.T
    depth = offsets[owner] / along[np.arange(n), owner]
    points = seeds * depth[:, None]
    sigma = 0.005 * (1.0 + 0.1 * np.linalg.norm(points, axis=1) ** 2)
    points += rng.normal(0.0, 1.0, (n, 1)) * sigma[:, None] * points / np.linalg.norm(points, axis=1, keepdims=True)
    return points, sigma, normals, offsets, owner


def test_agrees_with_the_numpy_form_bit_for_bit():
    rng = np.random.default_rng(3)
    points, sigma, normals, offsets, _ = _scene(rng)
    rms = np.array([0.001, 0.02, 0.0])
    got = within_plane_noise(points, sigma, normals, offsets, rms, 3.0)
    want = _numpy_form(points, sigma, normals, offsets, rms, 3.0)
    assert got.shape == (points.shape[0], 3) and got.dtype == np.bool_
    np.testing.assert_array_equal(got, want)
    assert 0 < got.sum() < got.size  # the test decides both ways on this scene


def test_each_point_is_on_its_own_plane_and_noise_scales_the_answer():
    rng = np.random.default_rng(5)
    points, sigma, normals, offsets, owner = _scene(rng)
    rms = np.zeros(3)
    within = within_plane_noise(points, sigma, normals, offsets, rms, 5.0)
    # Gaussian range noise: beyond 5 sigmas along the ray is rarer than 1 in a million
    assert within[np.arange(points.shape[0]), owner].all()
    # a plane's own rms widens the band: at the farthest point's distance every point is in
    farthest = np.abs(points @ normals.T - offsets).max(axis=0) * (1.0 + 1e-9)
    assert within_plane_noise(points, sigma, normals, offsets, farthest, 1.0).all()
    assert not within_plane_noise(points, sigma, normals, offsets, 0.5 * farthest, 1.0).all()
    # and no noise at all takes nothing off a plane
    assert not within_plane_noise(points + 0.5 * normals[owner], np.zeros(len(points)), normals, offsets,
                                  rms, 5.0)[np.arange(points.shape[0]), owner].any()


def test_a_point_at_the_origin_and_no_planes():
    at_origin = within_plane_noise(np.zeros((1, 3)), np.ones(1), np.array([[0.0, 0.0, 1.0]]),
                                   np.array([1.0]), np.zeros(1), 3.0)
    assert at_origin.tolist() == [[False]]  # no cosine, no noise: 1 m off is off
    empty = within_plane_noise(np.ones((4, 3)), np.ones(4), np.zeros((0, 3)), np.zeros(0), np.zeros(0), 3.0)
    assert empty.shape == (4, 0)
