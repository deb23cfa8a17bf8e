"""The connected pieces a split searches next, in one compiled call.

:func:`rangeseg_o3d.refinement.split.split_regions` (and the facets step's split) searches a
pool, takes the piece found out of it and searches the 4-connected pieces left over the size
floor, largest first. In numpy each round was a set difference, the pieces' numbers, a
counting sort by piece and a list of slices, sorted by size: a handful of small-array calls
per search, dozens of searches a frame. :func:`pool_pieces` does it in one pass.
"""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .grid import piece_ids

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("grid.py", "inline.py", "kinds.py")

__all__ = ["pool_pieces"]


@njit(cache=True, nogil=True)
def pool_pieces(pool, piece, width, min_size):
    """The 4-connected pieces of the flat pixels ``pool`` without those of ``piece`` (both
    increasing, ``piece`` among ``pool``; empty: the whole pool) that hold at least
    ``min_size`` pixels, smallest first (pieces of one size in the raster order of their
    first pixel, as :func:`rangeseg_o3d.kernels.piece_ids` numbers them).

    Returns ``(pixels, bounds)``: piece ``j``'s flat pixels, increasing, are
    ``pixels[bounds[j]:bounds[j + 1]]``. The same pieces, in the same order, as
    ``sorted([idx[ids == p] for p in range(len(sizes)) if sizes[p] >= min_size], key=len)``
    with ``idx = pool[~np.isin(pool, piece)]`` and ``ids, sizes = piece_ids(idx, width)``;
    none when fewer than ``min_size`` pixels are left.
    """
    n = pool.shape[0]
    keep = np.ones(n, np.bool_)
    # (a binary search's insertion points of the increasing ``piece``: one merge pass)
    j = 0
    for q in range(piece.shape[0]):
        value = piece[q]
        while j < n and pool[j] < value:
            j += 1
        if j < n:
            keep[j] = False
    m = 0
    for p in range(n):
        if keep[p]:
            m += 1
    left = np.empty(m, pool.dtype)
    m = 0
    for p in range(n):
        if keep[p]:
            left[m] = pool[p]
            m += 1
    if m < min_size:
        return np.empty(0, pool.dtype), np.zeros(1, np.int64)
    ids, sizes = piece_ids(left, width)
    big = 0
    for s in range(sizes.shape[0]):
        if sizes[s] >= min_size:
            big += 1
    chosen = np.empty(big, np.int64)
    big = 0
    for s in range(sizes.shape[0]):
        if sizes[s] >= min_size:
            chosen[big] = s
            big += 1
    # smallest first, a stable order (Python's sort of the list by length)
    chosen = chosen[np.argsort(sizes[chosen], kind="mergesort")]
    rank = np.full(sizes.shape[0], -1, np.int64)
    bounds = np.zeros(big + 1, np.int64)
    for r in range(big):
        rank[chosen[r]] = r
        bounds[r + 1] = bounds[r] + sizes[chosen[r]]
    pixels = np.empty(bounds[big], pool.dtype)
    at = bounds[:big].copy()
    for p in range(m):
        r = rank[ids[p]]
        if r >= 0:
            pixels[at[r]] = left[p]
            at[r] += 1
    return pixels, bounds
