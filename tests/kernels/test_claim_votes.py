"""kernels.rows_with_any and kernels.piece_votes: the claim's numpy reductions, compiled."""

import numpy as np

from rangeseg_o3d.kernels import piece_votes, rows_with_any


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
