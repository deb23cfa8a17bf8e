"""Tile grid -> sensor grid: full-resolution labels from the tile models, with the
regions' distance statistics in the same pass, and the leftover blobs of the result.

The per-pixel work is what each pixel needs: the candidate models of a tile (the
regions of the tile and of the 8 around it) are listed once per tile, so a pixel inside
a region (one candidate) costs one distance, which serves both its label test and its
region's statistics; only pixels of tiles where regions meet test several models.
"""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .inline import _distance, _incidence, _nearest_neighbour_model, _neighbour

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("inline.py", "kinds.py")

__all__ = ["label_pixels", "leftover_blobs", "grow_free", "label_boxes", "labels_touch"]


@njit(cache=True, nogil=True)
def _tile_candidates(tile_labels, kinds):
    # Per tile: the models its pixels are tested against, in the order of the per-pixel
    # rule (own region first, then the 8 neighbours row by row), each label once.
    # count -1: the tile's region has no model and keeps the tile's pixels.
    th, tw = tile_labels.shape
    n = kinds.shape[0]
    table = np.zeros((th, tw, 9), np.int32)
    count = np.zeros((th, tw), np.int32)
    for tr in range(th):
        for tc in range(tw):
            own = tile_labels[tr, tc]
            if 0 < own < n and kinds[own] == 0:
                count[tr, tc] = -1
                continue
            m = 0
            if 0 < own < n:
                table[tr, tc, 0] = own
                m = 1
            for dr in range(-1, 2):
                rr = tr + dr
                if rr < 0 or rr >= th:
                    continue
                for dc in range(-1, 2):
                    cc = tc + dc
                    if cc < 0 or cc >= tw or (dr == 0 and dc == 0):
                        continue
                    k = tile_labels[rr, cc]
                    if k <= 0 or k >= n or kinds[k] == 0:
                        continue
                    seen = False
                    for j in range(m):
                        if table[tr, tc, j] == k:
                            seen = True
                    if not seen:
                        table[tr, tc, m] = k
                        m += 1
            count[tr, tc] = m
    return table, count


@njit(cache=True, nogil=True)
def label_pixels(xyz, height, width, tile_labels, tile, kinds, params, rms, sigma, k_sigma,
                 inlier_factor):
    """Full-resolution labels from labels of ``tile x tile`` means and the regions' models.

    Each valid pixel joins, among the regions of its own tile and the 8 tiles around it,
    the one whose model is nearest in units of ``max(sigma, rms)``, if within ``k_sigma``
    (its own tile's region wins ties, then the first neighbour in row order). Pixels of a
    tile whose region has no model (``kinds == 0``) keep that region. ``xyz`` and
    ``sigma`` are flat (H*W).

    Returns ``(labels (H, W) int32, inliers, squares, counts)``: per label, the pixels
    within ``inlier_factor * sigma`` of its model, the sum of their squared distances and
    the number of pixels with a finite distance (pixels taken in raster order, as
    :func:`rangeseg_o3d.kernels.distance_stats` counts them with a zero rms).
    """
    table, count = _tile_candidates(tile_labels, kinds)
    n = kinds.shape[0]
    th, tw = tile_labels.shape
    out = np.zeros((height, width), np.int32)
    inliers = np.zeros(n, np.int64)
    squares = np.zeros(n)
    counts = np.zeros(n, np.int64)
    # Row by row (the statistics sum in raster order), tile by tile along the row: no
    # division per pixel, and a pixel of a tile inside a region tests one model.
    for r in range(height):
        tr = min(r // tile, th - 1)
        for tc in range(tw):
            c0, c1 = tc * tile, min(tc * tile + tile, width)
            m = count[tr, tc]
            if m == 0:
                continue
            own = tile_labels[tr, tc]
            if m < 0:  # a region without a model keeps its tile
                for c in range(c0, c1):
                    if np.isfinite(xyz[r * width + c, 2]):
                        out[r, c] = own
                continue
            if m == 1:
                k = table[tr, tc, 0]
                kind, prm, floor = kinds[k], params[k], rms[k]
                ties = k == own  # the own region wins ties
                # the region's statistics in registers along the tile's row (the same
                # additions in the same order as _take's)
                taken, total, near = counts[k], squares[k], inliers[k]
                for c in range(c0, c1):
                    i = r * width + c
                    z = xyz[i, 2]
                    if not np.isfinite(z):
                        continue
                    noise = sigma[i]
                    dist = _distance(kind, prm, xyz[i, 0], xyz[i, 1], z)
                    score = dist / max(noise, floor)
                    if score < k_sigma or (ties and score <= k_sigma):
                        out[r, c] = k
                        taken += 1
                        total += dist * dist
                        if dist <= inlier_factor * max(noise, 0.0):
                            near += 1
                counts[k], squares[k], inliers[k] = taken, total, near
                continue
            own_first = table[tr, tc, 0] == own
            for c in range(c0, c1):
                i = r * width + c
                x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
                if not np.isfinite(z):
                    continue
                noise = sigma[i]
                best, best_score, best_dist = 0, np.inf, 0.0
                for j in range(m):
                    k = table[tr, tc, j]
                    dist = _distance(kinds[k], params[k], x, y, z)
                    # explained within k_sigma (the own region at the bound too)...
                    limit = k_sigma * max(noise, rms[k])
                    if not (dist < limit or (j == 0 and own_first and dist <= limit)):
                        continue
                    # ...and of those, the one it is fewest noise sigmas off, each in the noise
                    # of its own distances (range noise x incidence cosine: a pipe's end cap
                    # faces the sensor, the pipe's flanks graze it; a box face seen edge-on
                    # takes no pixel of the face beside it that the noise along the rays
                    # could not have moved onto it)
                    score = dist / max(noise * _incidence(kinds[k], params[k], x, y, z), rms[k])
                    # neighbours must beat what is found so far
                    if score < best_score or (j == 0 and own_first and score <= best_score):
                        best, best_score, best_dist = k, score, dist
                if best != 0:
                    _take(out, inliers, squares, counts, r, c, best, best_dist, noise, inlier_factor)
    return out, inliers, squares, counts


@njit(cache=True, nogil=True, inline="always")
def _take(out, inliers, squares, counts, r, c, k, dist, noise, inlier_factor):
    # pixel (r, c) joins region k at distance dist (finite: it passed the test)
    out[r, c] = k
    counts[k] += 1
    squares[k] += dist * dist
    if dist <= inlier_factor * max(noise, 0.0):
        inliers[k] += 1


@njit(cache=True, nogil=True)
def leftover_blobs(labels, valid, min_size, first_label, thin_min_size=0):
    """Compact blobs of valid, unlabelled pixels: :func:`rangeseg_o3d.refinement.recover.leftover_candidates`
    without a jump mask, in one pass over the grid and then work on the leftover pixels only.

    Cores are the leftover pixels whose 3x3 neighbourhood is all leftover (the grid border
    replicated); 4-connected cores are numbered in raster order of their first pixel, each
    leftover pixel takes the largest core number in its 3x3 neighbourhood, and blobs of at
    least ``min_size`` pixels are renumbered from ``first_label``. With ``thin_min_size > 0``
    the leftover pixels no such blob took (strips too thin for a core, and what is left of
    blobs under ``min_size``) follow as thin blobs: their 4-connected pieces of at least
    ``thin_min_size`` pixels, numbered on after the others in raster order of their first pixel.

    Returns ``(candidates (H, W) int32, boxes (n, 4) int64, n_cored)``: each blob's bounding box
    ``(row0, row1, col0, col1)`` (half-open), blob ``first_label + j`` in row ``j``; the
    first ``n_cored`` blobs are the cored ones.
    """
    h, w = labels.shape
    candidates = np.zeros((h, w), np.int32)
    none = np.zeros((0, 4), np.int64)
    free = np.zeros((h, w), np.uint8)
    n_free = 0
    for r in range(h):
        for c in range(w):
            f = valid[r, c] and labels[r, c] == 0
            free[r, c] = f
            n_free += f
    if n_free == 0:
        return candidates, none, 0
    # the leftover pixels in raster order (a few percent of a frame): all later work is theirs
    rows = np.empty(n_free, np.int64)
    cols = np.empty(n_free, np.int64)
    m = 0
    for r in range(h):
        for c in range(w):
            if free[r, c]:
                rows[m], cols[m] = r, c
                m += 1
    # cores: leftover pixels whose 3x3 neighbourhood (border replicated) is all leftover
    core = np.zeros((h, w), np.int32)  # -1: a core pixel not yet numbered
    n_core_pixels = 0
    for j in range(n_free):
        r, c = rows[j], cols[j]
        if _all_free_around(free, r, c, h, w):
            core[r, c] = -1
            n_core_pixels += 1
    n_cores = _number_listed(core, rows, cols, n_core_pixels) if n_core_pixels else 0
    # every leftover pixel takes the largest core number around it (3x3, border replicated)
    sizes = np.zeros(n_cores + 1, np.int64)
    for j in range(n_free):
        r, c = rows[j], cols[j]
        k = _max_around(core, r, c, h, w)
        candidates[r, c] = k
        sizes[k] += 1
    lut = np.zeros(n_cores + 1, np.int32)
    kept = 0
    for k in range(1, n_cores + 1):
        if sizes[k] >= min_size:
            lut[k] = first_label + kept
            kept += 1
    n_cored = kept
    # the leftover pixels no kept blob took, marked -1 in ``thin`` (when asked for)
    thin = np.zeros((h, w) if thin_min_size > 0 else (1, 1), np.int32)
    n_thin_pixels = 0
    for j in range(n_free):
        r, c = rows[j], cols[j]
        k = candidates[r, c]
        if k != 0:
            k = lut[k]
            candidates[r, c] = k
        if k == 0 and thin_min_size > 0:
            thin[r, c] = -1
            n_thin_pixels += 1
    thin_lut = np.zeros(1, np.int32)
    n_thin = _number_listed(thin, rows, cols, n_thin_pixels) if n_thin_pixels else 0
    if n_thin:
        thin_sizes = np.zeros(n_thin + 1, np.int64)
        for j in range(n_free):
            r, c = rows[j], cols[j]
            if candidates[r, c] == 0:
                thin_sizes[thin[r, c]] += 1
        thin_lut = np.zeros(n_thin + 1, np.int32)
        for k in range(1, n_thin + 1):
            if thin_sizes[k] >= thin_min_size:
                thin_lut[k] = first_label + kept
                kept += 1
    if kept == 0:
        return candidates, none, 0
    boxes = np.empty((kept, 4), np.int64)
    boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3] = h, 0, w, 0
    for j in range(n_free):
        r, c = rows[j], cols[j]
        k = candidates[r, c]
        if k == 0 and n_thin:
            k = thin_lut[thin[r, c]]
            candidates[r, c] = k
        if k:
            b = k - first_label
            boxes[b, 0], boxes[b, 1] = min(boxes[b, 0], r), max(boxes[b, 1], r + 1)
            boxes[b, 2], boxes[b, 3] = min(boxes[b, 2], c), max(boxes[b, 3], c + 1)
    return candidates, boxes, n_cored


@njit(cache=True, nogil=True, inline="always")
def _all_free_around(free, r, c, h, w):
    # every pixel of the 3x3 neighbourhood of (r, c) free, the grid's border replicated
    for rr in (max(r - 1, 0), r, min(r + 1, h - 1)):
        for cc in (max(c - 1, 0), c, min(c + 1, w - 1)):
            if not free[rr, cc]:
                return False
    return True


@njit(cache=True, nogil=True, inline="always")
def _max_around(image, r, c, h, w):
    # the largest value of the 3x3 neighbourhood of (r, c), the grid's border replicated
    best = image[r, c]
    for rr in (max(r - 1, 0), r, min(r + 1, h - 1)):
        for cc in (max(c - 1, 0), c, min(c + 1, w - 1)):
            best = max(best, image[rr, cc])
    return best


@njit(cache=True, nogil=True)
def _number_listed(marks, rows, cols, n_marked):
    # Number the 4-connected pieces of the pixels marked -1 (all among the listed pixels,
    # listed in raster order) as 1, 2, ... in raster order of their first pixel (OpenCV's
    # order); returns how many there are.
    h, w = marks.shape
    stack_r = np.empty(n_marked, np.int64)
    stack_c = np.empty(n_marked, np.int64)
    pieces = 0
    for j in range(rows.shape[0]):
        r, c = rows[j], cols[j]
        if marks[r, c] != -1:
            continue
        pieces += 1
        marks[r, c] = pieces
        stack_r[0], stack_c[0], depth = r, c, 1
        while depth:
            depth -= 1
            pr, pc = stack_r[depth], stack_c[depth]
            if pr > 0 and marks[pr - 1, pc] == -1:
                marks[pr - 1, pc] = pieces
                stack_r[depth], stack_c[depth] = pr - 1, pc
                depth += 1
            if pr < h - 1 and marks[pr + 1, pc] == -1:
                marks[pr + 1, pc] = pieces
                stack_r[depth], stack_c[depth] = pr + 1, pc
                depth += 1
            if pc > 0 and marks[pr, pc - 1] == -1:
                marks[pr, pc - 1] = pieces
                stack_r[depth], stack_c[depth] = pr, pc - 1
                depth += 1
            if pc < w - 1 and marks[pr, pc + 1] == -1:
                marks[pr, pc + 1] = pieces
                stack_r[depth], stack_c[depth] = pr, pc + 1
                depth += 1
    return pieces


@njit(cache=True, nogil=True)
def _grown(array, size):
    # ``array`` with room for at least ``size`` items (doubled), its items kept
    if size <= array.shape[0]:
        return array
    out = np.empty(max(size, 2 * array.shape[0]), array.dtype)
    out[: array.shape[0]] = array
    return out


@njit(cache=True, nogil=True)
def grow_free(xyz, labels, kinds, params, rms, sigma, ranges, k_sigma, jump_ratio, jump_min,
              inlier_factor, inliers, squares, counts, touch):
    """Grow regions into free valid pixels, ring after ring until no pixel joins (in place).

    A free pixel joins the 4-neighbouring region whose model is within
    ``k_sigma * max(sigma, rms)`` of it, the nearest in those units when several are, when
    the range step to that neighbour is no jump (``<= max(jump_min, jump_ratio * r)``, or,
    into a plane, within that of the plane's own step between the two rays); each ring is decided on the labels as they were at its start. Regions with
    ``kinds[k] == 0`` do not grow. ``inliers``, ``squares`` and ``counts`` (per label, as
    :func:`label_pixels` returns them) take each pixel that joins. A pixel is looked at
    again only when a neighbour joined a region in the ring before (nothing else changes its
    answer). ``touch`` (n x n bool, n = ``kinds.shape[0]``) is set for every pair of labels
    below n that a pixel which joined made 4-neighbours. Returns the number of pixels added.
    The work arrays grow with the frontier (a frame-sized one per call costs more than the
    growth on a frame with few free pixels).
    """
    h, w = labels.shape
    flat = labels.ravel()
    n = kinds.shape[0]
    front = np.empty(1024, np.int64)
    n_front = 0
    # one pass: the first frontier, free valid pixels next to a labelled one; a listed
    # pixel is marked -1 in ``labels`` until its ring decides it
    for r in range(h):
        for c in range(w):
            if labels[r, c] != 0:
                continue
            i = r * w + c
            if not np.isfinite(xyz[i, 2]):
                continue
            if ((r > 0 and labels[r - 1, c] > 0) or (r < h - 1 and labels[r + 1, c] > 0)
                    or (c > 0 and labels[r, c - 1] > 0) or (c < w - 1 and labels[r, c + 1] > 0)):
                front = _grown(front, n_front + 1)
                front[n_front] = i
                n_front += 1
    for f in range(n_front):
        flat[front[f]] = -1
    following = np.empty(front.shape[0], np.int64)
    chosen = np.empty(front.shape[0], np.int32)
    gaps = np.empty(front.shape[0])
    added = np.empty(1024, np.int64)
    total = 0
    while n_front > 0:
        chosen = _grown(chosen, n_front)
        gaps = _grown(gaps, n_front)
        for f in range(n_front):
            chosen[f], gaps[f] = _nearest_neighbour_model(front[f], flat, h, w, xyz, kinds, params, rms, sigma,
                                                          ranges, k_sigma, jump_ratio, jump_min, True)
        for f in range(n_front):
            i = front[f]
            k = chosen[f]
            flat[i] = k  # 0 again when nothing took it
            if k == 0:
                continue
            added = _grown(added, total + 1)
            added[total] = i
            total += 1
            counts[k] += 1
            squares[k] += gaps[f] * gaps[f]
            if gaps[f] <= inlier_factor * sigma[i]:
                inliers[k] += 1
        n_next = 0
        for f in range(n_front):
            if chosen[f] == 0:
                continue
            i = front[f]
            for step in range(4):
                j = _neighbour(i, step, h, w)
                if j >= 0 and flat[j] == 0 and np.isfinite(xyz[j, 2]):
                    flat[j] = -1
                    following = _grown(following, n_next + 1)
                    following[n_next] = j
                    n_next += 1
        front, following = following, front
        n_front = n_next
    for a in range(total):  # the pairs the grown pixels made
        i = added[a]
        k = flat[i]
        for step in range(4):
            j = _neighbour(i, step, h, w)
            if j >= 0 and 0 < flat[j] < n and flat[j] != k:
                touch[k, flat[j]] = touch[flat[j], k] = True
    return total


@njit(cache=True, nogil=True)
def label_boxes(labels, n):
    """(n, 4) int64: label ``k``'s bounding box ``(row0, row1, col0, col1)`` (half-open) in
    row ``k``; ``(h, 0, w, 0)`` for a label without pixels (and for labels >= n)."""
    h, w = labels.shape
    boxes = np.empty((n, 4), np.int64)
    boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3] = h, 0, w, 0
    # a row's runs of one label update its box once each (first and last column of the
    # run), not once per pixel
    for r in range(h):
        c = 0
        while c < w:
            k = labels[r, c]
            end = c + 1
            while end < w and labels[r, end] == k:
                end += 1
            if 0 < k < n:
                boxes[k, 0] = min(boxes[k, 0], r)
                boxes[k, 1] = max(boxes[k, 1], r + 1)
                boxes[k, 2] = min(boxes[k, 2], c)
                boxes[k, 3] = max(boxes[k, 3], end)
            c = end
    return boxes


@njit(cache=True, nogil=True)
def labels_touch(labels, a, b, row0, row1, col0, col1):
    """Whether a pixel of label ``a`` and one of label ``b`` are 4-neighbours within rows
    ``row0:row1`` and columns ``col0:col1`` (stops at the first such pair)."""
    for r in range(row0, row1):
        for c in range(col0, col1):
            k = labels[r, c]
            if k != a and k != b:
                continue
            other = b if k == a else a
            if (c + 1 < col1 and labels[r, c + 1] == other) or (r + 1 < row1 and labels[r + 1, c] == other):
                return True
    return False
