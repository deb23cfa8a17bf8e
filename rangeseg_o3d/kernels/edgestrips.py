"""Compiled pretest of :func:`rangeseg_o3d.edge_planes.edge_planes_to_curved`: whether a curved
region's model lies near a plane region beside it, read from the grid on the plane's even
sample, without gathering the sample's points in numpy (most pairs a real frame asks are a
wall or a box beside a pipe, far off its model: a gather per plane cost more than the test)."""

from __future__ import annotations

import numpy as np

from .jit import njit  # numba.njit, with this package's cache locator installed

from .modelnoise import _absolute_distance, near_verdict

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("modelnoise.py", "kinds.py")

__all__ = ["strips_near_models"]


@njit(cache=True, nogil=True)
def strips_near_models(labels, xyz, sigma, strip, boxes, steps, kinds, params, k_sigma, relative, absolute):
    """Per pair ``j``: the pixels of label ``strip[j]`` on the grid ``boxes[j]`` (rows
    ``boxes[j, 0]:boxes[j, 1]``, columns ``boxes[j, 2]:boxes[j, 3]``) every ``steps[j]`` rows
    and columns, with finite points (``xyz``, ``(H, W, 3)``) and noise (``sigma``,
    ``(H, W)``), against the model ``kinds[j]``, ``params[j]`` (:mod:`.kinds`): 1 when the
    median of their distances to it is within ``k_sigma`` times the median of their noise,
    0 when over, -1 where the two lie within ``relative`` of that bound plus ``absolute``
    times the magnitude of the terms, or the sample is empty (there another rounding could
    answer otherwise: :func:`.modelnoise.pieces_near_models`'s verdicts on the same points)."""
    m = strip.shape[0]
    out = np.empty(m, np.int8)
    for j in range(m):
        r0, r1, c0, c1, step = boxes[j, 0], boxes[j, 1], boxes[j, 2], boxes[j, 3], steps[j]
        size = ((r1 - r0 + step - 1) // step) * ((c1 - c0 + step - 1) // step)
        distances, noise = np.empty(max(size, 0)), np.empty(max(size, 0))
        terms = 0.0
        for p in range(params.shape[1]):
            terms += abs(params[j, p])
        largest = 0.0
        n = 0
        for r in range(r0, r1, step):
            for c in range(c0, c1, step):
                if labels[r, c] != strip[j]:
                    continue
                x, y, z, s = xyz[r, c, 0], xyz[r, c, 1], xyz[r, c, 2], sigma[r, c]
                if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z) and np.isfinite(s)):
                    continue
                distances[n] = _absolute_distance(kinds[j], params[j], x, y, z)
                noise[n] = s
                largest = max(largest, abs(x) + abs(y) + abs(z))
                n += 1
        if n == 0:
            out[j] = -1
            continue
        out[j] = near_verdict(distances[:n], noise[:n], k_sigma, relative, absolute * (largest + terms))
    return out
