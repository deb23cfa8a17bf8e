import numpy as np
import pytest

from rangeseg_o3d.segmentation.residual import (
    neighbourhood_moments,
    noise_sigma,
    residual_image,
    smallest_eigenpairs,
)


def _pack(m):
    return np.stack([m[..., 0, 0], m[..., 1, 1], m[..., 2, 2], m[..., 0, 1], m[..., 0, 2], m[..., 1, 2]])


def test_closed_form_eigenpairs_match_eigh():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(2000, 3, 3))
    sym = a @ np.swapaxes(a, 1, 2)
    value, vector = smallest_eigenpairs(_pack(sym))
    w, v = np.linalg.eigh(sym)
    assert np.allclose(value, w[:, 0], atol=1e-6 * w[:, 2].max())
    assert np.allclose(np.abs(np.einsum("in,ni->n", vector, v[:, :, 0])), 1.0, atol=1e-6)


def test_closed_form_handles_degenerate_matrices():
    zero = np.zeros((6, 1))
    value, vector = smallest_eigenpairs(zero)
    assert value[0] == 0.0 and np.isnan(vector).all()
    # Rank-2 scatter of a perfect plane z = 0: eigenvalue 0, normal +-z.
    plane = np.array([[2.0], [1.0], [0.0], [0.3], [0.0], [0.0]])
    value, vector = smallest_eigenpairs(plane)
    assert value[0] == pytest.approx(0.0, abs=1e-12)
    assert abs(vector[2, 0]) == pytest.approx(1.0)


def test_eigenvalues_of_repeated_and_clustered_roots():
    # Newton from below converges slowly on double roots: those go on past the batch loop.
    rng = np.random.default_rng(4)
    rotations = np.linalg.qr(rng.normal(size=(300, 3, 3)))[0]
    spectra = np.array([[1.0, 1.0, 5.0], [2.0, 2.0, 2.0], [0.0, 0.0, 3.0],
                        [1.0, 1.0 + 1e-9, 1.0 + 2e-9], [1e-12, 1.0, 1.0]])
    spectra = spectra[rng.integers(0, len(spectra), 300)]
    sym = np.einsum("nij,nj,nkj->nik", rotations, spectra, rotations)
    value = smallest_eigenpairs(_pack(sym), with_vectors=False)
    assert np.allclose(value, spectra[:, 0], atol=1e-9 * spectra[:, 2].max())


def test_residual_keeps_its_precision_far_from_the_origin():
    rng = np.random.default_rng(5)
    x, y = _grid(spacing=0.07)
    z = 4.0 + 0.1 * x + rng.normal(0, 0.005, x.shape)
    near, _ = residual_image(np.dstack([x, y, z]), ranges=np.full(x.shape, 4.0), sigma0=0.005)
    far, _ = residual_image(np.dstack([x + 1000.0, y - 2000.0, z + 500.0]),
                            ranges=np.full(x.shape, 4.0), sigma0=0.005)
    assert np.allclose(far, near, rtol=1e-5)


def _grid(h=20, w=30, spacing=0.05):
    v, u = np.mgrid[0:h, 0:w].astype(float)
    return u * spacing, v * spacing


def test_moments_match_brute_force_with_invalid_points():
    rng = np.random.default_rng(2)
    xyz = rng.normal(size=(6, 7, 3)) + 5.0
    xyz[2, 3] = np.nan
    xyz[0, 0] = np.nan
    count, centroid, scatter = neighbourhood_moments(xyz)
    for i, j in [(1, 1), (2, 3), (0, 0), (5, 6), (3, 4)]:
        win = xyz[max(i - 1, 0):i + 2, max(j - 1, 0):j + 2].reshape(-1, 3)
        win = win[~np.isnan(win[:, 0])]
        assert count[i, j] == len(win)
        c = win - win.mean(axis=0)
        a = c.T @ c
        assert np.allclose(centroid[:, i, j], win.mean(axis=0))
        assert np.allclose(scatter[:, i, j], [a[0, 0], a[1, 1], a[2, 2], a[0, 1], a[0, 2], a[1, 2]], atol=1e-9)


def test_plane_residual_is_noise_level_at_every_range():
    rng = np.random.default_rng(3)
    sigma = 0.005
    for distance in (1.0, 7.0):
        x, y = _grid(spacing=0.0175 * distance)  # 1 deg steps at that range
        z = np.full_like(x, distance) + rng.normal(0, sigma, x.shape)
        xyz = np.dstack([x, y, z])
        res, _ = residual_image(xyz, ranges=np.full(x.shape, distance), sigma0=sigma)
        inner = res[1:-1, 1:-1]
        # chi-square / dof with 6 dof: mean 1, 99.9th percentile about 3.7.
        assert 0.7 < inner.mean() < 1.3
        assert np.percentile(inner, 99) < 4.0


def test_crease_and_jump_have_high_residual():
    x, y = _grid(h=10, w=20, spacing=0.02)
    z = np.where(x < 0.2, 1.0, 1.0 + (x - 0.2))  # 45 degree crease at x = 0.2
    res, normals = residual_image(np.dstack([x, y, z]), ranges=z, sigma0=0.001)
    crease_cols = res[5, 9:12]
    assert crease_cols.max() > 20
    assert res[5, 3] < 1e-3 and res[5, 16] < 1e-3
    assert abs(normals[5, 3, 2]) == pytest.approx(1.0)
    z = np.where(x < 0.2, 1.0, 1.5)
    res, _ = residual_image(np.dstack([x, y, z]), ranges=z, sigma0=0.001)
    assert res[5, 9:11].min() > 50


def test_invalid_and_sparse_windows_are_infinite():
    x, y = _grid(h=5, w=5)
    xyz = np.dstack([x, y, np.ones_like(x)])
    xyz[2, 2] = np.nan
    xyz[0, :] = np.nan
    res, _ = residual_image(xyz, min_valid=6)
    assert np.isinf(res[2, 2])
    assert np.isinf(res[0]).all()
    assert np.isinf(res[1, 0])  # corner-ish window with 4 valid points
    assert np.isfinite(res[3, 2])


def test_all_nan_gives_all_infinite():
    res, _ = residual_image(np.full((4, 4, 3), np.nan))
    assert np.isinf(res).all()


@pytest.mark.parametrize("shape", [(10, 3), (4, 4, 2), (2, 2, 3, 1)])
def test_bad_shapes_raise(shape):
    with pytest.raises(ValueError, match=r"shape \(H, W, 3\)"):
        residual_image(np.zeros(shape))


def test_bad_window_and_min_valid_raise():
    with pytest.raises(ValueError, match="window"):
        residual_image(np.zeros((4, 4, 3)), window=4)
    with pytest.raises(ValueError, match="min_valid"):
        residual_image(np.zeros((4, 4, 3)), min_valid=10)


def test_noise_sigma_model():
    assert noise_sigma(np.array([2.0]), sigma0=0.001, sigma_quadratic=0.001425)[0] == pytest.approx(0.0067)


def test_block_means_average_tiles_and_respect_invalid_pixels():
    from rangeseg_o3d.segmentation.residual import block_means

    xyz = np.arange(4 * 6 * 3, dtype=float).reshape(4, 6, 3)
    xyz[0, 0] = np.nan
    means, counts = block_means(xyz, 2)
    assert means.shape == (2, 3, 3) and counts.tolist() == [[3, 4, 4], [4, 4, 4]]
    np.testing.assert_allclose(means[0, 0], np.nanmean(xyz[:2, :2].reshape(-1, 3), axis=0))
    np.testing.assert_allclose(means[1, 2], xyz[2:4, 4:6].reshape(-1, 3).mean(axis=0))
    # A tile with less than half its pixels valid is no point; a ragged edge is padded.
    xyz[:2, 2:4] = np.nan
    xyz[0, 4] = xyz[1, 4] = xyz[0, 5] = np.nan
    means, counts = block_means(xyz[:, :5], 2)
    assert means.shape == (2, 3, 3)
    assert np.isnan(means[0, 1]).all() and np.isnan(means[0, 2]).all()
    with pytest.raises(ValueError, match="block"):
        block_means(xyz, 0)


def test_tile_means_lower_the_random_noise_term_only():
    rng = np.random.default_rng(5)
    v, u = np.mgrid[0:60, 0:80].astype(float)
    z = np.full(u.shape, 3.0) + rng.normal(0, 0.01, u.shape)
    xyz = np.dstack([u * 0.005, v * 0.005, z])
    from rangeseg_o3d.segmentation.residual import block_means

    means, counts = block_means(xyz, 4)
    scale = 1.0 / np.sqrt(counts)
    # Random part of sigma is 0.01 m: tile means of 16 have 0.0025 m.
    res, _ = residual_image(means, sigma0=0.0, sigma_quadratic=0.01 / 9.0, noise_scale=scale,
                            ranges=np.full(counts.shape, 3.0))
    inner = res[1:-1, 1:-1]
    assert 0.6 < np.median(inner) < 1.4


def test_residual_without_normals_equals_the_step_by_step_residual_bit_for_bit():
    # with_normals=False runs one fused kernel (kernels.window_residuals); the residual must
    # be the very values of the moments -> eigenvalue -> noise steps the normals path takes,
    # also with invalid points, sparse windows, a zero noise, NaN ranges and per-pixel scales
    rng = np.random.default_rng(21)
    for trial in range(40):
        h, w = rng.integers(1, 25, size=2)
        xyz = rng.normal(0.0, 0.05, (h, w, 3)) + (0.0, 0.0, rng.uniform(0.5, 40.0))
        if trial % 4 == 0:  # exact planes: repeated roots, the closed form's case
            xyz[..., 2] = 2.0
        xyz[rng.random((h, w)) < 0.2] = np.nan
        ranges = np.linalg.norm(xyz, axis=2)
        ranges[rng.random((h, w)) < 0.05] = np.nan
        scale = rng.uniform(0.2, 1.0, (h, w)) if trial % 2 else 1.0
        kwargs = dict(window=int(rng.choice([3, 5])), min_valid=4, ranges=ranges,
                      sigma0=0.0 if trial % 5 == 0 else 0.003, sigma_quadratic=0.002, noise_scale=scale)
        fused, normals = residual_image(xyz, with_normals=False, **kwargs)
        stepwise, _ = residual_image(xyz, with_normals=True, **kwargs)
        assert normals is None
        assert np.array_equal(fused, stepwise)
        assert np.isinf(fused[np.isnan(xyz[..., 2])]).all()


def test_full_3x3_windows_summed_row_by_row_equal_the_window_moments_bit_for_bit():
    # window_residuals sums the 3x3 windows whose nine points are valid a row at a time
    # (kernels.window._scatter3): the very counts and scatters of window_moments, at the
    # border, beside invalid points, in a window with none and on grids 1 and 2 pixels wide
    from rangeseg_o3d.kernels.window import _scatter3, window_moments

    rng = np.random.default_rng(3)
    shapes = [(1, 1), (1, 7), (7, 1), (2, 2), (3, 3), (2, 9), (9, 2)] + [tuple(rng.integers(3, 30, 2)) for _ in range(20)]
    for trial, (h, w) in enumerate(shapes):
        xyz = rng.normal(0.0, 10.0 ** rng.uniform(-3, 1), (h, w, 3)) + (0.0, 0.0, rng.uniform(0.5, 80.0))
        xyz[rng.random((h, w)) < (0.0 if trial % 3 == 0 else 0.25)] = np.nan
        if h >= 5 and w >= 5 and trial % 2:
            xyz[1:4, 1:4] = np.nan  # a window without a valid point
        xyz = np.ascontiguousarray(xyz)
        xyz.flags.writeable = False  # as the residual passes a cloud's points
        count, scatter = _scatter3(xyz)
        expected_count, _, expected_scatter = window_moments(xyz, 3)
        assert count.tobytes() == expected_count.tobytes()
        assert scatter.tobytes() == expected_scatter.tobytes()


@pytest.mark.parametrize("window", [3, 5, 9])
def test_window_normals_at_chosen_pixels_equal_the_whole_grids_bit_for_bit(window):
    # the crease test asks for the normals of its blind pixels only: the same values as the
    # whole grid's at those pixels (windows clipped at the border, invalid points, a window
    # with no valid point), NaN at the others
    from rangeseg_o3d.kernels import window_normals
    from rangeseg_o3d.segmentation.residual import _check_grid

    rng = np.random.default_rng(window)
    rows, cols = np.mgrid[0:23, 0:31]
    xyz = np.stack([cols * 0.01, rows * 0.01, 2.0 + 0.01 * np.sin(cols / 4.0) + 0.001 * rng.normal(size=rows.shape)],
                   axis=-1)
    xyz[rng.random(rows.shape) < 0.15] = np.nan
    xyz[10:10 + window, 20:20 + window] = np.nan  # a window without a valid point
    _, whole = residual_image(xyz, window=window, min_valid=4, with_normals=True)
    wanted = rng.random(rows.shape) < 0.4
    wanted[10 + window // 2, 20 + window // 2] = True
    wanted[0, :] = wanted[:, -1] = True  # border windows
    normals = window_normals(_check_grid(xyz, window), window, wanted)
    assert np.array_equal(normals[wanted], whole[wanted], equal_nan=True)
    assert np.isnan(normals[~wanted]).all()
    assert np.isnan(normals[10 + window // 2, 20 + window // 2]).all()
    assert np.isfinite(normals[wanted & np.isfinite(whole[..., 0])]).all()
    # unit normals of the surface z = 2 + 0.01 sin(x / 0.04) (slope at most 0.25): near z
    finite = wanted & np.isfinite(normals[..., 0])
    assert np.allclose(np.linalg.norm(normals[finite], axis=1), 1.0, atol=1e-12)
    assert np.median(np.abs(normals[finite][:, 2])) > 0.9
    nothing = window_normals(_check_grid(xyz, window), window, np.zeros(rows.shape, bool))
    assert nothing.shape == xyz.shape and np.isnan(nothing).all()
