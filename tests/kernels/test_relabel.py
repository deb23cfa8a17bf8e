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
