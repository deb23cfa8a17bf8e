import numpy as np
import pytest

from rangeseg_o3d._numeric import median


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
