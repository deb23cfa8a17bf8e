import numpy as np
import pytest

from rangeseg_o3d._numeric import median, rows_at, unique_ints


def test_median_equals_numpys_bit_for_bit():
    rng = np.random.default_rng(3)
    for i in range(2000):
        n = int(rng.integers(1, 80))
        values = rng.standard_normal(n) * 10.0 ** int(rng.integers(-6, 6))
        if i % 3 == 0:
            values = np.round(values, 1)  # ties
        if i % 7 == 0:
            values[rng.integers(0, n)] = np.inf
        got, want = median(values), float(np.median(values))
        assert got == want or (np.isnan(got) and np.isnan(want))


def test_median_is_nan_with_a_nan_as_numpys():
    assert np.isnan(median(np.array([1.0, np.nan, 2.0])))
    assert np.isnan(median(np.array([np.nan])))


def test_median_refuses_an_empty_or_2d_array():
    with pytest.raises(ValueError, match="non-empty 1-D"):
        median(np.zeros(0))
    with pytest.raises(ValueError, match="non-empty 1-D"):
        median(np.zeros((2, 2)))


def test_rows_at_equals_fancy_indexing():
    # integer indices (any width, repeated, unsorted, negative, none) go through take; a
    # boolean mask, a list or a 2-D index array are indexed as numpy indexes them
    rng = np.random.default_rng(5)
    points = rng.standard_normal((50, 3))
    points.flags.writeable = False  # as a cloud's points are
    for idx in (np.array([3, 1, 3, 49], np.int64), np.array([0, 7], np.int32), np.array([-1, -50]),
                np.zeros(0, np.int64), rng.random(50) < 0.3, [4, 2], np.array([[1, 2], [3, 4]])):
        got, want = rows_at(points, idx), points[idx]
        assert got.dtype == want.dtype and got.shape == want.shape and got.tobytes() == want.tobytes()
        assert got.flags.c_contiguous and got.flags.writeable
    with pytest.raises(IndexError):
        rows_at(points, np.array([50]))


def test_unique_ints_equals_numpys_unique():
    # repeated, unsorted, negative, of every integer width, bool, one value, none
    rng = np.random.default_rng(7)
    for dtype in (np.int64, np.int32, np.int16, np.uint8, np.uint32, np.bool_):
        for n in (0, 1, 2, 17, 4000):
            values = rng.integers(-50 if np.dtype(dtype).kind == "i" else 0, 200, n).astype(dtype)
            got, want = unique_ints(values), np.unique(values)
            assert got.dtype == want.dtype and got.tobytes() == want.tobytes()
    empty = np.concatenate([np.zeros(0), np.zeros(0, np.int64)])  # (a float dtype, as numpy promotes it)
    assert unique_ints(empty).dtype == np.unique(empty).dtype and unique_ints(empty).size == 0


def test_unique_ints_refuses_floats_and_2d_arrays():
    with pytest.raises(ValueError, match="1-D integer array"):
        unique_ints(np.array([1.0, 2.0]))
    with pytest.raises(ValueError, match="1-D integer array"):
        unique_ints(np.zeros((2, 2), np.int64))
