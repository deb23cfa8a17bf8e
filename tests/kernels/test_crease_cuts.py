"""``crease_cut_squares`` (crease_line's search in one compiled call) against the form it replaced (kept
here): numpy's stable argsort per direction, the (N, 13) moment columns summed by ``reduceat`` and
``cumsum``, and ``ray_fits``' LAPACK solves. The orders are the same positions; the chi-squares differ only in
rounding (a running sum and an in-place elimination): within 1e-8 relative, and the best cut is the same or ties with it."""

import numpy as np
import pytest

from rangeseg_o3d.kernels.rays import crease_cut_squares, grid_line_order
from rangeseg_o3d.ray_planes import moment_columns, ray_fits, ray_terms, split_columns

ANGLES = np.arange(32) * (np.pi / 32)
COSINES = np.array([np.cos(a) for a in ANGLES])
SINES = np.array([np.sin(a) for a in ANGLES])


def _old_search(rows, cols, rays, inverse, weight, sizes):
    # crease_line's search before the kernel
    orders = np.stack([np.argsort(cols * np.cos(a) + rows * np.sin(a), kind="stable") for a in ANGLES])
    columns = moment_columns(rays, inverse, weight)
    starts = np.concatenate([[0], sizes])
    prefix = np.stack([np.cumsum(np.add.reduceat(columns[order], starts, axis=0), axis=0) for order in orders])
    lefts = prefix[:, :-1]
    rights = prefix[:, -1:] - lefts
    left, _ = ray_fits(split_columns(lefts.reshape(-1, 13)))
    right, _ = ray_fits(split_columns(rights.reshape(-1, 13)))
    return (left + right).reshape(len(ANGLES), -1), orders


def _region(rng, kind, m):
    # flat pixels (increasing) of a 400 x 600 grid: scattered, a filled rectangle, or a disc
    if kind == "scattered":
        flat = np.sort(rng.choice(400 * 600, m, replace=False))
    elif kind == "rectangle":
        h = max(int(np.sqrt(m / 3)), 1)
        rows, cols = np.mgrid[100:100 + h, 50:50 + -(-m // h)]
        flat = np.sort((rows * 600 + cols).ravel()[:m])
    else:
        rows, cols = np.mgrid[0:400, 0:600]
        r = np.sqrt(m / np.pi)
        flat = np.flatnonzero((rows - 200) ** 2 + (cols - 300) ** 2 <= r * r)
    return np.divmod(flat, 600)


def _two_faces(rng, rows, cols):
    # points of two planes meeting along a slanted line, with range noise
    x, y = (cols - 300) * 0.004, (rows - 200) * 0.004
    z = 3.0 + np.where(x + 0.3 * y > 0.1, 0.8 * (x + 0.3 * y - 0.1), 0.0) + 0.2 * y
    points = np.stack([x, y, z], axis=1) * (1.0 + rng.normal(0.0, 0.002, x.size))[:, None]
    return ray_terms(points, np.full(x.size, 0.01))


@pytest.mark.parametrize("kind", ["scattered", "rectangle", "disc"])
@pytest.mark.parametrize("m", [1, 2, 40, 1000, 16384])
def test_grid_line_order_is_numpys_stable_argsort(kind, m):
    rows, cols = _region(np.random.default_rng(m), kind, m)
    order = np.empty(rows.size, np.int64)
    for cosine, sine in zip(COSINES, SINES):
        keys = cols * cosine + rows * sine
        grid_line_order(keys, order)
        assert np.array_equal(order, np.argsort(keys, kind="stable"))


def test_grid_line_order_keeps_position_order_among_equal_keys():
    # few distinct keys in large shuffled buckets (merge sort path) and small ones (insertion path)
    rng = np.random.default_rng(3)
    for distinct, n in [(3, 5000), (700, 5000), (5000, 5000)]:
        keys = rng.integers(0, distinct, n).astype(np.float64) * 0.37
        order = np.empty(n, np.int64)
        grid_line_order(keys, order)
        assert np.array_equal(order, np.argsort(keys, kind="stable"))
    order = np.empty(0, np.int64)
    grid_line_order(np.empty(0), order)  # nothing to order


@pytest.mark.parametrize("kind", ["scattered", "rectangle", "disc"])
@pytest.mark.parametrize("m", [40, 300, 4000, 16384])
def test_crease_cut_squares_agree_with_the_numpy_search(kind, m):
    rng = np.random.default_rng(m + len(kind))
    rows, cols = _region(rng, kind, m)
    m = rows.size
    rays, inverse, weight = _two_faces(rng, rows, cols)
    sizes = np.unique(np.linspace(max(m // 10, 1), m - max(m // 10, 1), 129).astype(np.int64))
    total, orders = crease_cut_squares(rows, cols, rays, inverse, weight, sizes, COSINES, SINES)
    want, want_orders = _old_search(rows, cols, rays, inverse, weight, sizes)
    assert total.shape == (32, sizes.size)
    assert np.array_equal(orders, want_orders)
    assert np.allclose(total, want, rtol=1e-8, atol=0.0)
    # the best cut is the old best, or one whose old chi-square ties with it (on a few scattered
    # pixels, lines of two directions can cut the same two sets)
    assert want.ravel()[np.argmin(total)] <= want.min() * (1.0 + 1e-8)


def test_crease_cut_squares_are_inf_where_a_side_has_no_plane():
    # zero weights: every sum 0, no ridge, a singular system (numpy's solve would raise)
    rows, cols = _region(np.random.default_rng(1), "rectangle", 300)
    rays, inverse, weight = _two_faces(np.random.default_rng(1), rows, cols)
    sizes = np.array([30, 150, 270])
    total, _ = crease_cut_squares(rows, cols, rays, inverse, np.zeros_like(weight), sizes, COSINES, SINES)
    assert np.all(np.isinf(total))
    total, _ = crease_cut_squares(rows, cols, rays, inverse, weight, sizes, COSINES, SINES)
    assert np.all(np.isfinite(total)) and np.all(total >= 0.0)
