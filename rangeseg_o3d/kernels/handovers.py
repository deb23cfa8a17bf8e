"""Compiled pretests of the dissolve step's hand-overs (:mod:`rangeseg_o3d.refinement.dissolve`):
which regions their larger neighbours may take, read from the grid in one pass over every
candidate at once.

:func:`fragments_may_pass` for :func:`~rangeseg_o3d.refinement.dissolve.dissolve_fragments`:
the numpy form gathers each candidate's pixels (or its sample) and stacks its hosts'
distances, six calls and ~0.1 ms a region; on a laser scan nearly every candidate (a wall
beside a larger wall, a box face beside the floor) is refused by its sample.
:func:`ripples_may_pass` for :func:`~rangeseg_o3d.refinement.dissolve.absorb_ripples`: on a
laser scan no larger plane holds half of a column's or a ball's pixels. Each refuses only
where numpy's tests certainly refuse: a pixel counts as explained when its distance is
within the bound widened by ``slack`` of itself and of the magnitude of the distance's
terms, far above the rounding of any way of computing it, so the counts are at least
numpy's.
"""

from __future__ import annotations

import numpy as np

from .jit import njit  # numba.njit, with this package's cache locator installed

from .kinds import NONE
from .modelnoise import _absolute_distance

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("modelnoise.py", "kinds.py")

__all__ = ["fragments_may_pass", "ripples_may_pass"]


@njit(cache=True, nogil=True)
def fragments_may_pass(labels, xyz, sigma, jumps, adjacency, fitted, kinds, params, rms, sizes,
                       k_sigma, share, sample_target, slack):
    """Per label ``k`` below ``n = adjacency.shape[0]``: False where dissolve_fragments' tests
    certainly keep region ``k`` from its hosts, True where they may not.

    A fitted region's hosts are the fitted regions (``fitted``) it touches (``adjacency``,
    (n, n) bool) with more pixels (``sizes``); a label without hosts gets False. ``labels``,
    ``jumps`` (bool) and ``sigma`` are flat over the grid, ``xyz`` its (N, 3) points; the
    models are the table ``kinds``, ``params``, ``rms`` (:mod:`.kinds`, indexed by label).
    A pixel counts as explained when some host is within ``k_sigma * max(sigma, rms[host])``
    of it, that bound widened by ``slack`` of itself and of the magnitude of the terms
    (``|x| + |y| + |z|`` and the host's parameters); a host of kind NONE (a model the table
    cannot hold) explains every pixel. With ``n`` explained pixels, ``freed`` unexplained
    ones off the jumps, and for a region of more than ``sample_target`` pixels ``hits`` of
    the ``m`` pixels at positions ``0, step, 2 step, ...`` (``step = size // sample_target``,
    in raster order) explained, a region is refused where ``hits / m < 0.5 - 1.5 / sqrt(m)``
    by more than ``slack``, ``2 n <= size``, or ``n < share * (n + freed)``: as many or fewer
    explained pixels fail numpy's tests too (``n`` fewer by one or more lowers the left side by
    more than ``share`` times it lowers the right side's count). The sample is read first:
    only the regions it does not refuse are read whole.
    """
    n_labels = adjacency.shape[0]
    host_starts, hosts = _larger_fitted_neighbours(adjacency, fitted, sizes)
    terms = np.zeros(n_labels)
    for k in range(n_labels):
        for p in range(params.shape[1]):
            terms[k] += abs(params[k, p])
    steps = np.zeros(n_labels, np.int64)
    for k in range(n_labels):
        if sizes[k] > sample_target and host_starts[k + 1] > host_starts[k]:
            steps[k] = sizes[k] // sample_target
    # the samples: every step-th pixel of each large region, in raster order
    hopeful = host_starts[1:] > host_starts[:-1]
    until = np.zeros(n_labels, np.int64)  # pixels of the region to pass before its next sample
    hits = np.zeros(n_labels, np.int64)
    samples = np.zeros(n_labels, np.int64)
    if np.any(steps > 0):
        for i in range(labels.shape[0]):
            k = labels[i]
            if k <= 0 or k >= n_labels or steps[k] == 0:
                continue
            if until[k] > 0:  # (a count down: a division per pixel cost more than the rest)
                until[k] -= 1
                continue
            until[k] = steps[k] - 1
            samples[k] += 1
            if _some_host_near(i, xyz, sigma, hosts, host_starts[k], host_starts[k + 1], kinds, params, rms,
                               terms, k_sigma, slack):
                hits[k] += 1
        for k in range(n_labels):
            if samples[k] > 0 and hits[k] / samples[k] < 0.5 - 1.5 / np.sqrt(samples[k]) - slack:
                hopeful[k] = False
    # the whole regions the samples left
    explained = np.zeros(n_labels, np.int64)
    freed = np.zeros(n_labels, np.int64)
    if not np.any(hopeful):
        return hopeful
    for i in range(labels.shape[0]):
        k = labels[i]
        if k <= 0 or k >= n_labels or not hopeful[k]:
            continue
        if _some_host_near(i, xyz, sigma, hosts, host_starts[k], host_starts[k + 1], kinds, params, rms,
                           terms, k_sigma, slack):
            explained[k] += 1
        elif not jumps[i]:
            freed[k] += 1
    for k in range(n_labels):
        n = explained[k]
        if hopeful[k] and (2 * n <= sizes[k] or n < share * (n + freed[k])):
            hopeful[k] = False
    return hopeful


@njit(cache=True, nogil=True)
def _larger_fitted_neighbours(adjacency, fitted, sizes):
    # (starts, hosts): the fitted labels h > 0 touching each fitted label k > 0 with more
    # pixels, increasing, as hosts[starts[k]:starts[k + 1]]
    n = adjacency.shape[0]
    starts = np.zeros(n + 1, np.int64)
    for k in range(n):
        count = 0
        if k > 0 and fitted[k]:
            for h in range(1, n):
                if adjacency[k, h] and fitted[h] and sizes[h] > sizes[k]:
                    count += 1
        starts[k + 1] = starts[k] + count
    hosts = np.empty(starts[n], np.int64)
    for k in range(1, n):
        if starts[k + 1] == starts[k]:
            continue
        j = starts[k]
        for h in range(1, n):
            if adjacency[k, h] and fitted[h] and sizes[h] > sizes[k]:
                hosts[j] = h
                j += 1
    return starts, hosts


@njit(cache=True, nogil=True, inline="always")
def _some_host_near(i, xyz, sigma, hosts, start, stop, kinds, params, rms, terms, k_sigma, slack):
    # whether one of the hosts[start:stop] (labels) is within k_sigma max(sigma, rms) of the point i,
    # widened by slack of itself and of the terms (fragments_may_pass); NONE: always
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    point_terms = abs(x) + abs(y) + abs(z)
    for j in range(start, stop):  # (indices, not a slice: a slice per pixel costs its reference counts)
        h = hosts[j]
        if kinds[h] == NONE:
            return True
        reach = k_sigma * max(sigma[i], rms[h]) * (1.0 + slack) + slack * (point_terms + terms[h])
        if _absolute_distance(kinds[h], params[h], x, y, z) <= reach:
            return True
    return False


@njit(cache=True, nogil=True)
def ripples_may_pass(labels, xyz, sigma, candidates, normals, offsets, scatter, plane_sizes, limit, slack):
    """Per label ``k``: False where no plane ``j`` (rows of ``normals``, ``offsets``,
    ``scatter``) of more pixels than region ``k`` (``plane_sizes[j]``, against the region's
    pixel count here) holds ``ceil(n / 2)`` of the region's n pixels within ``limit *
    max(sigma, scatter[j])``, that bound widened by ``slack`` of itself and of the terms of
    the distance (``|x nx| + |y ny| + |z nz| + |d|``, as :func:`.labelwise.planes_may_hold_half`);
    True where one may, and for every label without ``candidates[k]`` False.

    ``labels`` and ``sigma`` are flat over the grid, ``xyz`` its (N, 3) points. A region
    whose median noise-scaled distance to a plane is within ``limit`` has that half within
    it (at any spread up to ``max(sigma, scatter)``): where this answers False for every
    label, no curved patch has a host.
    """
    n, p = candidates.shape[0], normals.shape[0]
    counts = np.zeros(n, np.int64)
    for i in range(labels.shape[0]):
        k = labels[i]
        if 0 < k < n and candidates[k]:
            counts[k] += 1
    hits = np.zeros((n, p), np.int64)
    for i in range(labels.shape[0]):
        k = labels[i]
        if k <= 0 or k >= n or not candidates[k]:
            continue
        for j in range(p):
            if plane_sizes[j] <= counts[k]:
                continue
            tx, ty, tz = xyz[i, 0] * normals[j, 0], xyz[i, 1] * normals[j, 1], xyz[i, 2] * normals[j, 2]
            along = tx + ty + tz
            terms = abs(tx) + abs(ty) + abs(tz) + abs(offsets[j])
            reach = limit * max(sigma[i], scatter[j]) * (1.0 + slack) + slack * terms
            if abs(along - offsets[j]) <= reach:
                hits[k, j] += 1
    out = np.zeros(n, np.bool_)
    for k in range(n):
        if not candidates[k]:
            continue
        for j in range(p):
            if plane_sizes[j] > counts[k] and hits[k, j] >= (counts[k] + 1) // 2:
                out[k] = True
                break
    return out
