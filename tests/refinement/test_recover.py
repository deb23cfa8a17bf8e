"""The recover step: compact leftover blobs are candidates, thin crease bands are not."""

import numpy as np

from rangeseg_o3d.refinement.recover import leftover_candidates


def test_leftover_candidates_cut_thin_bands_and_keep_blobs():
    labels = np.ones((20, 30), np.int32)
    labels[:, 14:16] = 0          # a 2-pixel band between two regions
    labels[5:12, 3:10] = 0        # a 7x7 blob
    valid = np.ones_like(labels, bool)
    cand = leftover_candidates(labels, valid, np.zeros_like(valid), min_size=20, first_label=5)
    assert set(np.unique(cand)) == {0, 5}
    assert (cand[5:12, 3:10] == 5).all()
    assert (cand[:, 14:16] == 0).all()


def test_leftover_candidates_keep_strips_along_the_grid_border():
    # A ceiling seen only by the first two scan rows: the border is no edge, so the
    # erosion that cuts crease bands must not eat the strip; the same strip inside the
    # grid is a crease band and is cut.
    labels = np.ones((20, 60), np.int32)
    labels[0:2, 10:50] = 0
    labels[9:11, 10:50] = 0
    valid = np.ones_like(labels, bool)
    cand = leftover_candidates(labels, valid, np.zeros_like(valid), min_size=20, first_label=3)
    assert (cand[0:2, 11:49] == 3).all()
    assert not cand[9:11].any()
