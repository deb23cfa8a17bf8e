"""label_counts and relabel: np.bincount and a look-up table over a label image, compiled."""

import numpy as np

from rangeseg_o3d.kernels import label_counts, relabel


def test_label_counts_and_relabel_match_numpy():
    rng = np.random.default_rng(2)
    labels = rng.integers(0, 40, (37, 53)).astype(np.int32)
    labels[labels == 39] = 0  # the largest label drawn need not occur: the counts end at the last one
    np.testing.assert_array_equal(label_counts(labels), np.bincount(labels.ravel()))
    lut = rng.permutation(40).astype(np.int32)
    out = relabel(labels, lut)
    assert out.dtype == np.int32
    np.testing.assert_array_equal(out, lut[labels])


def test_label_counts_of_an_unlabelled_image():
    np.testing.assert_array_equal(label_counts(np.zeros((3, 4), np.int32)), [12])


def test_label_counts_of_runs_match_numpy():
    # labels in runs along the rows, as regions give them (a run is counted at its end),
    # runs crossing the rows' ends and a label coming back after others
    rng = np.random.default_rng(3)
    labels = np.repeat(rng.integers(0, 12, 400), rng.integers(1, 30, 400))[:2400].reshape(40, 60).astype(np.int32)
    np.testing.assert_array_equal(label_counts(labels), np.bincount(labels.ravel()))
    np.testing.assert_array_equal(label_counts(np.full((2, 5), 7, np.int32)), [0] * 7 + [10])


def test_label_sizes_pads_to_the_length_asked():
    from rangeseg_o3d.fitting.region_fitter import label_sizes

    labels = np.array([[0, 3, 3], [1, 1, 0]], np.int32)
    np.testing.assert_array_equal(label_sizes(labels), np.bincount(labels.ravel()))
    np.testing.assert_array_equal(label_sizes(labels, minlength=6), np.bincount(labels.ravel(), minlength=6))
    np.testing.assert_array_equal(label_sizes(labels, minlength=2), [2, 2, 0, 2])  # never cut
    assert label_sizes(np.zeros((0, 4), np.int32), minlength=3).tolist() == [0, 0, 0]
    assert label_sizes(labels).dtype == np.int64
