"""The trimmed proposals' small kernels against numpy: _eigenvectors3 (the plane frame) against
LAPACK's eigh, kth_smallest (the quadric's trimming cut) against np.partition."""

import numpy as np
import pytest

from rangeseg_o3d.kernels.trimmed import _eigenvectors3, kth_smallest


def _scatters(rng):
    # the scatters a proposal meets: general, a plane with noise, an exact plane (a zero
    # eigenvalue), a line (two equal small ones), two equal large ones (a disc), points at one spot
    yield "general", (lambda m: m @ m.T)(rng.normal(size=(3, 3)))
    for name, spread in (("noisy plane", [1.0, 0.5, 1e-4]), ("exact plane", [1.0, 0.5, 0.0]),
                         ("line", [3.0, 1e-3, 1e-3]), ("disc", [1.0, 1.0, 1e-2])):
        rotation = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        pts = rng.normal(size=(200, 3)) * spread @ rotation.T
        yield name, pts.T @ pts
    yield "one spot", np.zeros((3, 3))


@pytest.mark.parametrize("seed", range(20))
def test_eigenvectors3_diagonalise_in_ascending_order(seed):
    rng = np.random.default_rng(seed)
    for name, scatter in _scatters(rng):
        vecs = _eigenvectors3(scatter.copy())
        values = np.linalg.eigvalsh(scatter)
        size = max(abs(values).max(), 1e-300)
        assert np.allclose(vecs.T @ vecs, np.eye(3), atol=1e-12), name
        rotated = vecs.T @ scatter @ vecs
        assert np.abs(rotated - np.diag(np.diag(rotated))).max() <= 1e-12 * size, name
        # the eigenvalues eigh gives, in its (ascending) order
        assert np.allclose(np.diag(rotated), values, rtol=0, atol=1e-12 * size), name


@pytest.mark.parametrize("seed", range(20))
def test_eigenvectors3_match_eigh_up_to_sign_where_the_eigenvalues_are_apart(seed):
    rng = np.random.default_rng(100 + seed)
    for name, scatter in _scatters(rng):
        values, expected = np.linalg.eigh(scatter)
        vecs = _eigenvectors3(scatter.copy())
        size = max(abs(values).max(), 1e-300)
        for j in range(3):
            gap = min(abs(values[j] - values[k]) for k in range(3) if k != j) / size
            if gap < 1e-6:  # a repeated eigenvalue: any basis of its space is an answer
                continue
            # a vector's error is rounding over the relative gap to its neighbours
            error = min(np.abs(vecs[:, j] - expected[:, j]).max(), np.abs(vecs[:, j] + expected[:, j]).max())
            assert error <= 1e-13 / gap, (name, j, error, gap)


def _distance_like(rng, n, case):
    # distances as the proposals meet them: spread, with ties, all equal, sorted either way
    values = np.abs(rng.normal(size=n))
    if case == "ties":
        values = np.round(values, 1)
    elif case == "equal":
        values[:] = 0.25
    elif case == "ascending":
        values.sort()
    elif case == "descending":
        values = np.sort(values)[::-1].copy()
    return values


@pytest.mark.parametrize("case", ["spread", "ties", "equal", "ascending", "descending"])
def test_kth_smallest_is_the_partitions_value(case):
    rng = np.random.default_rng(7)
    for _ in range(300):
        n = int(rng.integers(1, 700))
        values = _distance_like(rng, n, case)
        before = values.copy()
        for k in {0, n - 1, int(rng.integers(0, n)), int(0.6 * n)}:
            assert kth_smallest(values, k, np.empty(n)) == np.partition(values, k)[k]
        assert np.array_equal(values, before)  # the work space is sorted, not the values
