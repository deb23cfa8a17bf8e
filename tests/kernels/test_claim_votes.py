"""kernels.rows_with_any, piece_votes, voted_columns and claim_parts: the claim's numpy reductions, compiled."""

import numpy as np

from rangeseg_o3d.kernels import claim_parts, piece_ids, piece_votes, rows_with_any, voted_columns
from rangeseg_o3d.kernels.linalg import CHI_SQUARE_SIGMAS, noise_rms_bound


def _within(seed: int, n: int = 400, p: int = 7) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.random((n, p)) < rng.uniform(0.02, 0.3)


def test_rows_with_any_is_numpys_for_sparse_and_dense_rows():
    for seed in range(5):
        within = _within(seed)
        np.testing.assert_array_equal(rows_with_any(within), np.flatnonzero(within.any(axis=1)))


def test_rows_with_any_of_nothing_and_of_no_columns():
    assert rows_with_any(np.zeros((5, 3), bool)).size == 0
    assert rows_with_any(np.zeros((5, 0), bool)).size == 0
    np.testing.assert_array_equal(rows_with_any(np.ones((4, 1), bool)), np.arange(4))


def test_piece_votes_is_the_bincount_of_hits():
    for seed in range(5):
        within = _within(seed)
        ids = np.random.default_rng(seed + 100).integers(0, 9, within.shape[0])
        at, plane = np.nonzero(within)
        expected = np.bincount(ids[at] * within.shape[1] + plane,
                               minlength=9 * within.shape[1]).reshape(9, within.shape[1])
        got = piece_votes(ids, within, 9)
        np.testing.assert_array_equal(got, expected)
        assert got.sum() == within.sum()


def test_voted_columns_are_each_pieces_argmax_vote():
    for seed in range(5):
        within = _within(seed)
        ids = np.random.default_rng(seed + 100).integers(0, 9, within.shape[0])
        best = np.argmax(piece_votes(ids, within, 9), axis=1)[ids]
        member, column = voted_columns(ids, within, 9)
        np.testing.assert_array_equal(column, best)
        np.testing.assert_array_equal(member, within[np.arange(ids.size), best])
    # equal votes: the first column, as np.argmax
    member, column = voted_columns(np.zeros(2, np.int64), np.array([[False, True, True], [True, True, False]]), 1)
    assert column.tolist() == [1, 1] and member.tolist() == [True, True]


def _claim_reference(labels, xyz, sigma, pixels, columns, parts, sizes, normals, offsets, rms, plane_labels,
                     min_size, apart):
    # the numpy form of one claim round after the vote (recover._claim_once before claim_parts)
    points = xyz[pixels]
    n = normals[columns]
    along = points[:, 0] * n[:, 0] + points[:, 1] * n[:, 1] + points[:, 2] * n[:, 2]
    norms = np.sqrt(points[:, 0] * points[:, 0] + points[:, 1] * points[:, 1] + points[:, 2] * points[:, 2])
    noise = np.maximum(sigma[pixels] * (np.abs(along) / np.maximum(norms, 1e-12)), rms[columns])
    distances = along - offsets[columns]
    counts = np.maximum(sizes, 1)
    mean_squares = np.bincount(parts, weights=distances ** 2, minlength=sizes.size) / counts
    noise_squares = np.bincount(parts, weights=noise ** 2, minlength=sizes.size) / counts
    column = np.full(int(labels.max()) + 1, -1)
    column[plane_labels] = np.arange(len(plane_labels))
    rows, cols = np.divmod(pixels, labels.shape[1])
    hit = np.zeros(pixels.size, bool)
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        r, c = rows + dr, cols + dc
        inside = np.flatnonzero((r >= 0) & (r < labels.shape[0]) & (c >= 0) & (c < labels.shape[1]))
        hit[inside] |= column[labels[r[inside], c[inside]]] == columns[inside]
    touches = np.bincount(parts, weights=hit, minlength=sizes.size) > 0
    bound = noise_rms_bound.py_func(np.sqrt(noise_squares), counts.astype(float), CHI_SQUARE_SIGMAS)
    kept = (((sizes >= min_size) & apart) | touches) & (np.sqrt(mean_squares) <= bound)
    out = labels.copy()
    out.ravel()[pixels[kept[parts]]] = plane_labels[columns[kept[parts]]]
    return out


def test_claim_parts_claims_as_the_numpy_round_does():
    h, w = 40, 50
    rng = np.random.default_rng(3)
    xyz = np.stack(np.meshgrid(np.linspace(-1, 1, w), np.linspace(-0.8, 0.8, h)), -1).reshape(-1, 2)
    xyz = np.column_stack([xyz, np.full(len(xyz), 2.0)])
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.6, 0.8], [0.6, 0.0, 0.8]])
    offsets = np.array([2.0, 1.7, 1.9])
    plane_labels = np.array([3, 5, 8])
    claimed_some = refused_some = 0
    for seed in range(6):
        rng = np.random.default_rng(seed)
        points = xyz + rng.normal(0, 0.004, xyz.shape) * [0, 0, 1]
        sigma = np.full(h * w, 0.003 * rng.uniform(0.5, 2.0))
        rms = rng.uniform(0.0, 0.004, 3)
        labels = np.where(rng.random((h, w)) < 0.25, rng.choice([0, 3, 5, 8, 9], (h, w)), 0).astype(np.int32)
        pixels = np.flatnonzero((labels.ravel() == 0) & (rng.random(h * w) < 0.7))
        columns = rng.integers(0, 3, pixels.size)
        parts, sizes = piece_ids(pixels, w)
        for min_size, apart in ((10, True), (10, False), (200, True)):
            expected = _claim_reference(labels, points, sigma, pixels, columns, parts, sizes, normals, offsets, rms,
                                        plane_labels, min_size, apart)
            got = labels.copy()
            column_of = np.full(plane_labels.max() + 1, -1, np.int64)
            column_of[plane_labels] = np.arange(3)
            any_claimed = claim_parts(got.reshape(-1), w, points, sigma, pixels, columns, parts, sizes, normals,
                                      offsets, rms, plane_labels, column_of, min_size, apart, CHI_SQUARE_SIGMAS)
            np.testing.assert_array_equal(got, expected)
            assert any_claimed == bool((expected != labels).any())
            claimed_some += any_claimed
            refused_some += int((expected.ravel()[pixels] == 0).any())
    assert claimed_some and refused_some  # both outcomes were exercised
