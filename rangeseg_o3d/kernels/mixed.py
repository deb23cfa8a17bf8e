"""Compiled test of a laser's mixed returns, per pixel and counted per region
(:mod:`rangeseg_o3d.refinement.mixed_returns`).

A return is mixed when, along its column or its row, its range lies between its two
neighbours' by more than ``step_sigmas`` sqrt 2 times its range noise on each side and neither
neighbour's own next step reaches ``continued`` of the step to it (a neighbour off the grid,
or with no return beyond it, tells nothing: no). One test (:func:`_is_mixed`) serves the count
over the grid, which visits every pixel of the regions looked at in one pass, and the mask of
the pixels of the regions released.
"""

from __future__ import annotations

import numpy as np

from .jit import njit  # numba.njit, with this package's cache locator installed

__all__ = ["mixed_at", "mixed_counts"]


@njit(cache=True, nogil=True, inline="always")
def _range_at(ranges, r, c, h, w, wrap_columns):
    # the range at (r, c), NaN off the grid (columns wrapping on a 360-degree grid)
    if r < 0 or r >= h:
        return np.nan
    if wrap_columns:
        c = c % w
    elif c < 0 or c >= w:
        return np.nan
    return ranges[r, c]


@njit(cache=True, nogil=True, inline="always")
def _mixed_along(ranges, r, c, dr, dc, h, w, wrap_columns, floor, continued):
    # whether (r, c)'s range lies between its neighbours' along (dr, dc) beyond ``floor`` on
    # each side, neither neighbour stepping on (a comparison with NaN is False throughout)
    own = ranges[r, c]
    before = _range_at(ranges, r - dr, c - dc, h, w, wrap_columns)
    after = _range_at(ranges, r + dr, c + dc, h, w, wrap_columns)
    into, out = own - before, after - own
    if not (into * out > 0.0 and abs(into) > floor and abs(out) > floor):
        return False
    further_before = _range_at(ranges, r - 2 * dr, c - 2 * dc, h, w, wrap_columns)
    further_after = _range_at(ranges, r + 2 * dr, c + 2 * dc, h, w, wrap_columns)
    return abs(before - further_before) < continued * abs(into) and abs(further_after - after) < continued * abs(out)


@njit(cache=True, nogil=True, inline="always")
def _is_mixed(ranges, sigma, r, c, h, w, wrap_columns, scale, continued):
    # the module's test of the return at (r, c), its floor ``scale`` times its noise
    floor = scale * sigma[r, c]
    return (_mixed_along(ranges, r, c, 1, 0, h, w, wrap_columns, floor, continued)
            or _mixed_along(ranges, r, c, 0, 1, h, w, wrap_columns, floor, continued))


@njit(cache=True, nogil=True)
def mixed_counts(labels, ranges, sigma, looked_at, step_sigmas, continued, wrap_columns):
    """Per label ``k`` (below ``looked_at.shape[0]``, ``looked_at[k]`` True), how many of its
    pixels in the (H, W) ``labels`` are mixed returns (the module's test on the (H, W)
    ``ranges``, NaN: no return, and ``sigma``); 0 for the others. With ``wrap_columns`` the
    first and last columns are neighbours."""
    h, w = labels.shape
    n = looked_at.shape[0]
    counts = np.zeros(n, np.int64)
    scale = step_sigmas * np.sqrt(2.0)
    for r in range(h):
        for c in range(w):
            k = labels[r, c]
            if k > 0 and k < n and looked_at[k] and _is_mixed(ranges, sigma, r, c, h, w, wrap_columns, scale,
                                                               continued):
                counts[k] += 1
    return counts


@njit(cache=True, nogil=True)
def mixed_at(ranges, sigma, idx, step_sigmas, continued, wrap_columns):
    """Whether each of the flat pixels ``idx`` of the (H, W) ``ranges`` is a mixed return (the
    module's test; ``sigma`` the (H, W) range noise)."""
    h, w = ranges.shape
    scale = step_sigmas * np.sqrt(2.0)
    out = np.zeros(idx.shape[0], np.bool_)
    for j in range(idx.shape[0]):
        r, c = idx[j] // w, idx[j] % w
        out[j] = _is_mixed(ranges, sigma, r, c, h, w, wrap_columns, scale, continued)
    return out
