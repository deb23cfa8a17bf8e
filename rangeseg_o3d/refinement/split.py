"""Step 1, ``split``: a region no model explains is split into all the surfaces it holds.

The paper's "local checks that remove under-segmentation" (Sec. 6): least trimmed squares
(:func:`rangeseg_o3d.fitting.robust.trimmed_fit`), one surface after the other, each cut
to its largest connected piece; only what no surface takes is freed.
"""

from __future__ import annotations

import numpy as np

from ..fitting.region_fitter import region_indices
from .context import Context, without

__all__ = ["split_regions"]

# searches per split region (found surfaces and failed pieces alike): bounds the split's time
_MAX_SPLIT_ATTEMPTS = 24


def split_regions(ctx: Context, labels: np.ndarray, fits: dict, failed: list[int], *,
                  pixels: dict | None = None, own: bool = False):
    """Split every region of ``failed`` into all the surfaces it holds; returns new ``(labels, fits)``.

    Sequential robust extraction with connectivity kept: the dominant surface of a
    connected pool of the region's pixels, cut to its largest 4-connected piece, becomes a
    region; the rest of the pool falls apart into its connected pieces, and each is
    searched in turn, until every piece is smaller than the size floor or no model
    explains enough of it. Regions leaking through creases the edge image missed (floor,
    walls and the objects on them in one) come back as one region per surface; what no
    surface takes (the crease bands) is freed for growth. A region of which nothing is
    explained keeps its failure (reported as unfitted). The first surface found keeps the
    region's label, the others take new labels above the largest. ``pixels`` (optional):
    the flat pixels (increasing) of each failed region, when the caller has them (saves a
    pass over the grid). ``own``: ``labels`` is the caller's own C-ordered int32 copy, which
    this split may change in place and return (a frame-sized copy less at full resolution).
    """
    labels, fits = (labels if own else labels.copy()), dict(fits)
    flat = labels.ravel()
    if pixels is None:
        pixels = region_indices(labels)
    regions = {k: pixels[k] for k in sorted(failed) if k in pixels}
    next_label = int(labels.max(initial=0)) + 1
    for k, idx in regions.items():
        label, found = k, False
        pools = ctx.pieces(idx)
        attempts = 0
        while pools and attempts < _MAX_SPLIT_ATTEMPTS:
            attempts += 1
            pool = pools.pop()  # the largest piece (pools are kept sorted by size)
            piece, model = ctx.dominant_piece(pool)
            if piece is None:
                continue
            if not found:
                flat[idx] = 0  # the failed region dissolves into what is found
                found = True
            flat[piece] = label
            fits[label] = model
            label, next_label = next_label, next_label + 1
            pools.extend(ctx.pieces(without(pool, piece)))
            pools.sort(key=len)
    return labels, fits
