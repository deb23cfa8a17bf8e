"""kernels.free_pieces: the 4-connected pieces of free pixels a stereo face may grow from, as
scipy.ndimage.label numbers them and in the raster order of their pixels."""

import numpy as np
import pytest
from scipy import ndimage

from rangeseg_o3d.kernels import free_pieces


def _labelled(labels, valid, min_pixels):
    # the same pieces from scipy: numbered by ndimage.label, each piece's box sliced
    pieces, _ = ndimage.label((labels == 0) & valid)
    out = []
    for p, (rs, cs) in enumerate(ndimage.find_objects(pieces), start=1):
        rows, cols = np.nonzero(pieces[rs, cs] == p)
        if rows.size >= min_pixels:
            out.append((rows + rs.start) * labels.shape[1] + cols + cs.start)
    return out


@pytest.mark.parametrize("seed", range(6))
def test_pieces_are_scipys_in_its_order(seed):
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(5, 90)), int(rng.integers(5, 120))
    labels = np.where(rng.random((h, w)) < rng.uniform(0.3, 0.7), rng.integers(1, 5, (h, w)), 0).astype(np.int32)
    valid = rng.random((h, w)) > 0.1
    min_pixels = int(rng.integers(1, 12))
    pixels, bounds = free_pieces(labels, valid, min_pixels)
    mine = [pixels[b0:b1] for b0, b1 in zip(bounds[:-1], bounds[1:])]
    theirs = _labelled(labels, valid, min_pixels)
    assert len(theirs) > 0 and len(mine) == len(theirs)
    assert all(np.array_equal(a, b) for a, b in zip(mine, theirs))


def test_pieces_join_through_four_neighbours_only_and_keep_their_floor():
    labels = np.ones((4, 6), np.int32)
    labels[0, 0] = labels[1, 1] = 0  # diagonal neighbours: two pieces of one pixel
    labels[2:4, 2:5] = 0  # a piece of six pixels
    valid = np.ones(labels.shape, bool)
    valid[3, 4] = False  # (an invalid pixel is in no piece)
    pixels, bounds = free_pieces(labels, valid, 1)
    assert bounds.tolist() == [0, 1, 2, 7]
    assert pixels.tolist() == [0, 7, 14, 15, 16, 20, 21]
    pixels, bounds = free_pieces(labels, valid, 2)  # the single pixels are under the floor
    assert bounds.tolist() == [0, 5] and pixels.tolist() == [14, 15, 16, 20, 21]
    pixels, bounds = free_pieces(np.ones((3, 3), np.int32), np.ones((3, 3), bool), 1)
    assert bounds.tolist() == [0] and pixels.size == 0
