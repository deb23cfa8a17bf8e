"""The recovery step's leftover strips, in one compiled call.

:func:`rangeseg_o3d.refinement.recover.claim_thin_strips` offers the planes the leftover
pixels no blob took, in 4-connected strips of at least the size floor. In numpy and OpenCV
that was a mask of three grids, a connected-components pass over the whole grid, a count per
component and a gather: some 0.1 ms of small-array calls on a 70 x 131 LMS200 scan, where
:func:`strip_pool` lists the strips' pixels in one pass over the grid and works on the
listed pixels only. :func:`pieces_apart` lists the free pieces joined where no range jump
parts neighbours, for :func:`rangeseg_o3d.refinement.recover.strips_apart_as_blobs`.
"""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .grid import piece_ids
from .inline import _grid_neighbour, _jump_limit

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("grid.py", "inline.py", "kinds.py")

__all__ = ["strip_pool", "free_near_planes_reach", "pieces_apart"]


@njit(cache=True, nogil=True)
def strip_pool(labels, valid, candidates, min_size):
    """The flat indices (increasing) of the valid pixels with no label and no candidate blob
    (``labels == 0`` and ``candidates == 0``) whose 4-connected piece of such pixels holds at
    least ``min_size`` of them (the grid's columns do not wrap).

    The same pixels as ``np.flatnonzero(kept[strips])`` with ``n, strips =
    cv2.connectedComponents(free, connectivity=4)``, ``kept = np.bincount(strips.ravel()) >=
    min_size`` less the background, and ``free = valid & (labels == 0) & (candidates == 0)``.
    ``labels``, ``valid`` and ``candidates`` are (H, W) arrays of one shape, C-contiguous (the
    pass reads them as flat views).
    """
    h, w = labels.shape
    flat_labels = labels.reshape(h * w)
    flat_valid = valid.reshape(h * w)
    flat_candidates = candidates.reshape(h * w)
    listed = np.empty(h * w, np.int64)
    n = 0
    for i in range(h * w):
        if flat_valid[i] and flat_labels[i] == 0 and flat_candidates[i] == 0:
            listed[n] = i
            n += 1
    if n < min_size or n == 0:
        return np.zeros(0, np.int64)
    listed = listed[:n]
    ids, sizes = piece_ids(listed, w)
    kept = 0
    for p in range(n):
        if sizes[ids[p]] >= min_size:
            listed[kept] = listed[p]
            kept += 1
    return listed[:kept].copy()


@njit(cache=True, nogil=True)
def free_near_planes_reach(labels, valid, xyz, sigma, normals, offsets, rms, k_sigma, count, slack):
    """Whether at least ``count`` valid pixels with no label (``labels == 0``) may lie within
    ``k_sigma * max(sigma, rms[j])`` of some plane ``j`` (rows of ``normals``, ``offsets``,
    ``rms``; ``xyz`` and ``sigma`` flat, one row per pixel): the distance ``|p . n - d|``
    compared with that bound widened by ``slack`` of itself and of the terms of the distance
    (``|x nx| + |y ny| + |z nz| + |d|``), far above the rounding of any way of computing it
    (numpy's matrix product sums the terms in its own order).

    A necessary test for :func:`rangeseg_o3d.refinement.recover.claim_occluded_strips` to
    find ``count`` such pixels: False only where fewer certainly lie within the bound. Stops
    at the ``count``-th pixel.
    """
    h, w = labels.shape
    flat_labels = labels.reshape(h * w)
    flat_valid = valid.reshape(h * w)
    p = normals.shape[0]
    found = 0
    if count <= 0:
        return True
    for i in range(h * w):
        if not flat_valid[i] or flat_labels[i] != 0:
            continue
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        for j in range(p):
            tx, ty, tz = x * normals[j, 0], y * normals[j, 1], z * normals[j, 2]
            bound = k_sigma * max(sigma[i], rms[j])
            terms = abs(tx) + abs(ty) + abs(tz) + abs(offsets[j])
            if abs(tx + ty + tz - offsets[j]) <= bound + slack * (bound + terms):
                found += 1
                break
        if found >= count:
            return True
    return False


@njit(cache=True, nogil=True)
def pieces_apart(labels, valid, taken, ranges, jump_ratio, jump_min, min_size, wrap):
    """The pieces of the free pixels (valid, ``labels == 0``, ``taken == 0``), 4-connected
    where two neighbours' ranges differ by no jump (``<= max(jump_min, jump_ratio * r)``, r
    the nearer), of at least ``min_size`` pixels: ``(pixels, starts, contact, jumped)``, the
    flat pixels of piece ``s`` (increasing) ``pixels[starts[s]:starts[s + 1]]``, and how many
    of its links out of it are no jump to a labelled pixel and a jump to any valid pixel
    (labelled or not: the returns beside a far column's border returns, across the jump, are
    often a wall's edge band in no region). With ``wrap`` (a 360-degree grid) the first and
    last columns are neighbours.

    A piece is grown by its links, not by the pixels a jump test marks: the border return of
    a column standing before a wall is a jump pixel, yet on the column's surface."""
    h, w = labels.shape
    size = h * w
    flat = labels.reshape(size)
    ok = valid.reshape(size)
    taken_flat = taken.reshape(size)
    rng = ranges.reshape(size)
    seen = np.zeros(size, np.bool_)
    piece_of = np.zeros(size, np.int64)  # the piece number + 1 of each member pixel
    stack = np.empty(size, np.int64)
    members = np.empty(size, np.int64)
    out = np.empty(size, np.int64)
    starts = [0]
    contacts = []
    jumps = []
    n_out = 0
    for seed in range(size):
        if seen[seed] or not ok[seed] or flat[seed] != 0 or taken_flat[seed] != 0:
            continue
        seen[seed] = True
        top, count, contact, jumped = 1, 0, 0, 0
        stack[0] = seed
        while top > 0:
            top -= 1
            i = stack[top]
            members[count] = i
            count += 1
            r = i // w
            for step in range(4):
                j = _grid_neighbour(i, r, i - r * w, step, h, w, wrap)
                if j < 0 or not ok[j] or seen[j] or taken_flat[j] != 0 or flat[j] != 0:
                    continue
                if not abs(rng[i] - rng[j]) > _jump_limit(rng[i], rng[j], jump_ratio, jump_min):
                    seen[j] = True
                    stack[top] = j
                    top += 1
        if count < min_size:
            continue
        piece_of[members[:count]] = seed + 1
        # (its links out of it, once it is whole: a jump to a free pixel is one too)
        for m in range(count):
            i = members[m]
            r = i // w
            for step in range(4):
                j = _grid_neighbour(i, r, i - r * w, step, h, w, wrap)
                if j < 0 or not ok[j] or piece_of[j] == seed + 1:
                    continue
                if abs(rng[i] - rng[j]) > _jump_limit(rng[i], rng[j], jump_ratio, jump_min):
                    jumped += 1
                elif flat[j] > 0:
                    contact += 1
        out[n_out:n_out + count] = np.sort(members[:count])
        n_out += count
        starts.append(n_out)
        contacts.append(contact)
        jumps.append(jumped)
    return (out[:n_out].copy(), np.array(starts, np.int64), np.array(contacts, np.int64),
            np.array(jumps, np.int64))
