"""Every curved region less the returns along one of its sides, in one pass: the planes of
those rests, for polish's test of a bend that rests on one or two sides' grid lines
(:func:`rangeseg_o3d.refinement.polish.bent_at_border_lines`).

In numpy the same sums cost some 25 small-array calls per region (a quarter of a millisecond
each on the LMS200 suite's scans); here one pass over the label image serves every region.
"""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .window import smallest_eigenvalues

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("inline.py", "kinds.py", "window.py")

__all__ = ["side_rest_planes"]


@njit(cache=True, nogil=True)
def side_rest_planes(xyz, labels, width, wanted, wrap_columns):
    """For each label ``k`` with ``wanted[k]`` (``wanted`` (n,) bool; ``labels`` (H*W,) int, the
    grid ``width`` columns wide; ``xyz`` (H*W, 3), non-finite points skipped): the count and the
    least-squares plane rms of its pixels less those of each side, a side being its pixels whose
    neighbour above, below, left or right is not of ``k`` (off the grid counts as not; across the
    seam when ``wrap_columns``). Returns ``(counts (n, 4), rms (n, 4))``, the sides in that order;
    rms NaN under 3 points, and both 0 for labels not wanted. The sums are about each label's
    first point (no cancellation at long range)."""
    n = wanted.size
    size = labels.size
    height = size // width
    ref = np.zeros((n, 3))
    seen = np.zeros(n, np.bool_)
    region = np.zeros((n, 10))
    sides = np.zeros((n, 4, 10))
    flags = np.zeros(4, np.bool_)
    for i in range(size):
        k = labels[i]
        if k <= 0 or k >= n or not wanted[k]:
            continue
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        if not seen[k]:
            seen[k] = True
            ref[k, 0], ref[k, 1], ref[k, 2] = x, y, z
        dx, dy, dz = x - ref[k, 0], y - ref[k, 1], z - ref[k, 2]
        r = i // width
        c = i - r * width
        flags[0] = r == 0 or labels[i - width] != k
        flags[1] = r == height - 1 or labels[i + width] != k
        if wrap_columns:
            flags[2] = labels[r * width + (c - 1) % width] != k
            flags[3] = labels[r * width + (c + 1) % width] != k
        else:
            flags[2] = c == 0 or labels[i - 1] != k
            flags[3] = c == width - 1 or labels[i + 1] != k
        terms = (1.0, dx, dy, dz, dx * dx, dx * dy, dx * dz, dy * dy, dy * dz, dz * dz)
        for j in range(10):
            region[k, j] += terms[j]
        for s in range(4):
            if flags[s]:
                for j in range(10):
                    sides[k, s, j] += terms[j]
    counts = np.zeros((n, 4))
    packed = np.zeros((6, n * 4))
    for k in range(n):
        if not wanted[k]:
            continue
        for s in range(4):
            m = region[k, 0] - sides[k, s, 0]
            counts[k, s] = m
            col = k * 4 + s
            if m < 3.0:
                packed[0, col] = np.nan
                continue
            mx = (region[k, 1] - sides[k, s, 1]) / m
            my = (region[k, 2] - sides[k, s, 2]) / m
            mz = (region[k, 3] - sides[k, s, 3]) / m
            packed[0, col] = (region[k, 4] - sides[k, s, 4]) / m - mx * mx
            packed[1, col] = (region[k, 7] - sides[k, s, 7]) / m - my * my
            packed[2, col] = (region[k, 9] - sides[k, s, 9]) / m - mz * mz
            packed[3, col] = (region[k, 5] - sides[k, s, 5]) / m - mx * my
            packed[4, col] = (region[k, 6] - sides[k, s, 6]) / m - mx * mz
            packed[5, col] = (region[k, 8] - sides[k, s, 8]) / m - my * mz
    values = smallest_eigenvalues(packed)
    rms = np.zeros((n, 4))
    for k in range(n):
        if wanted[k]:
            for s in range(4):
                rms[k, s] = np.sqrt(values[k * 4 + s]) if counts[k, s] >= 3.0 else np.nan
    return counts, rms
