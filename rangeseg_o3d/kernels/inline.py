"""Inline helpers shared by the kernels: model distances and 4-neighbours on a flat grid."""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .kinds import CYLINDER, PLANE, SPHERE

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("kinds.py",)


@njit(cache=True, nogil=True, inline="always")
def _distance(kind, prm, x, y, z):
    # Absolute orthogonal distance of (x, y, z) from the model (a row of a model table, see
    # kinds.py); inf for "no model".
    if kind == PLANE:
        return abs(prm[0] * x + prm[1] * y + prm[2] * z - prm[3])
    if kind == SPHERE:
        dx, dy, dz = x - prm[0], y - prm[1], z - prm[2]
        return abs(np.sqrt(dx * dx + dy * dy + dz * dz) - prm[3])
    if kind == CYLINDER:
        rx, ry, rz = x - prm[3], y - prm[4], z - prm[5]
        along = rx * prm[0] + ry * prm[1] + rz * prm[2]
        radial2 = rx * rx + ry * ry + rz * rz - along * along
        return abs(np.sqrt(max(radial2, 0.0)) - prm[6])
    return np.inf

@njit(cache=True, nogil=True, inline="always")
def _neighbour(i, step, h, w):
    # Flat index of the 4-neighbour ``step`` (up, down, left, right) of pixel i; -1 off the grid.
    r, c = i // w, i % w
    if step == 0:
        return i - w if r > 0 else -1
    if step == 1:
        return i + w if r < h - 1 else -1
    if step == 2:
        return i - 1 if c > 0 else -1
    return i + 1 if c < w - 1 else -1


@njit(cache=True, nogil=True, inline="always")
def _nearest_neighbour_model(i, flat, h, w, xyz, kinds, params, rms, sigma, ranges, k_sigma, jump_ratio,
                             jump_min):
    # Growth's test for free pixel i: among its 4-neighbours' regions with a model and no
    # range jump to them (step <= max(jump_min, jump_ratio * r)), the one whose model is
    # nearest in units of max(sigma, rms), within k_sigma (the first of equals); returns
    # (label, distance), label 0 when none.
    n = kinds.shape[0]
    best, best_score, best_dist = 0, k_sigma, 0.0
    for step in range(4):
        j = _neighbour(i, step, h, w)
        if j < 0:
            continue
        k = flat[j]
        if k <= 0 or k >= n or kinds[k] == 0:
            continue
        ri, rj = ranges[i], ranges[j]
        if not (abs(ri - rj) <= max(jump_min, jump_ratio * min(ri, rj))):
            continue
        dist = _distance(kinds[k], params[k], xyz[i, 0], xyz[i, 1], xyz[i, 2])
        score = dist / max(sigma[i], rms[k])
        if score <= best_score and (best == 0 or score < best_score):
            best, best_score, best_dist = k, score, dist
    return best, best_dist
