"""Passes over the image grid: grouping pixels by label, jump edges, adjacency, growth, tile means,
the largest connected piece of a pixel set."""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .inline import _distance, _grid_neighbour, _jump_limit, _nearest_neighbour_model, _neighbour
from .kinds import PLANE

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("inline.py", "kinds.py")

__all__ = ["group_by_label", "count_either_side", "jump_mask", "adjacency_matrix", "grow_rings", "grow_rings_in_boxes", "claim_rings",
           "claim_rings_in_boxes", "settle_borders",
           "block_means", "largest_piece", "piece_ids", "labels_near", "free_pixels", "member_pixels", "member_counts", "group_counted", "box_members", "member_pixels_in_boxes",
           "differing_in_boxes", "free_pixels_in_boxes", "label_counts", "relabel", "ranges_and_noise"]

@njit(cache=True, nogil=True)
def group_by_label(labels, n):
    """Counting sort of pixel indices by label: ``(order, starts)``.

    ``order[starts[k]:starts[k + 1]]`` are the flat indices of label ``k`` in increasing
    order, for ``0 <= k < n``; labels outside that range are left out.
    """
    return _sort_by_label(labels, np.ones(n, np.bool_))


@njit(cache=True, nogil=True)
def group_members(labels, members):
    """:func:`group_by_label` of the labels ``k`` with ``members[k]`` only (``0 < k <
    len(members)``): ``order[starts[k]:starts[k + 1]]`` are label ``k``'s flat indices in
    increasing order (empty for the others). Pixels of other labels are only read."""
    keep = members.copy()
    if keep.shape[0]:
        keep[0] = False
    return _sort_by_label(labels, keep)


@njit(cache=True, nogil=True)
def _sort_by_label(labels, keep):
    # The counting sort of the labels k < len(keep) with keep[k].
    return _fill_by_label(labels, keep, _count_by_label(labels, keep))


@njit(cache=True, nogil=True)
def member_counts(labels, members):
    """Pixel count per label ``k`` with ``members[k]`` (``0 < k < len(members)``; 0 for the
    others): the first pass of :func:`group_members`, whose second (:func:`group_counted`)
    may then be asked for fewer labels."""
    keep = members.copy()
    if keep.shape[0]:
        keep[0] = False
    return _count_by_label(labels, keep)[1:]


@njit(cache=True, nogil=True)
def group_counted(labels, members, counts):
    """:func:`group_members` of ``members`` given ``counts`` (:func:`member_counts` of
    ``members`` or of more labels): one pass over the labels instead of two."""
    keep = members.copy()
    if keep.shape[0]:
        keep[0] = False
    shifted = np.zeros(keep.shape[0] + 1, np.int64)
    for k in range(keep.shape[0]):
        if keep[k]:
            shifted[k + 1] = counts[k]
    return _fill_by_label(labels, keep, shifted)


@njit(cache=True, nogil=True)
def even_samples(labels, members, target):
    """Per label ``k`` with ``members[k]`` (``0 < k < len(members)``): every ``step``-th of
    its flat indices in increasing order, ``step = max(1, count // target)`` of its pixel
    ``count`` -- :func:`group_members`' ``order[starts[k]:starts[k + 1]][::step]`` -- from
    a count pass and a pass that writes only the samples (no list of every pixel). Returns
    ``(order, starts, counts)``: label ``k``'s samples ``order[starts[k]:starts[k + 1]]``,
    its pixel count ``counts[k]`` (0 for the others)."""
    keep = members.copy()
    if keep.shape[0]:
        keep[0] = False
    n = keep.shape[0]
    counts = _count_by_label(labels, keep)[1:]
    steps = np.ones(n, np.int64)
    sizes = np.zeros(n + 1, np.int64)
    for k in range(n):
        if keep[k] and counts[k] > 0:
            steps[k] = max(1, counts[k] // max(target, 1))
            sizes[k + 1] = (counts[k] + steps[k] - 1) // steps[k]
    starts = np.cumsum(sizes)
    fill = starts[:-1].copy()
    # pixels of each label still to pass before its next sample (0: the next one is); a run
    # of one label takes its samples at once (a sample every step pixels from the first due)
    left = np.zeros(n, np.int64)
    order = np.empty(starts[-1], np.int64)
    size = labels.shape[0]
    i = 0
    while i < size:
        k = labels[i]
        end = i + 1
        while end < size and labels[end] == k:
            end += 1
        if 0 <= k < n and keep[k]:
            step, pos = steps[k], fill[k]
            j = i + left[k]
            while j < end:
                order[pos] = j
                pos += 1
                j += step
            fill[k], left[k] = pos, j - end
        i = end
    return order, starts, counts


@njit(cache=True, nogil=True)
def _count_by_label(labels, keep):
    # counts[k + 1]: pixels of label k (k < len(keep), keep[k]). Labels come in runs along
    # the rows: a run's count is kept in a register, where a store and reload per pixel
    # would chain each pixel to the last.
    n = keep.shape[0]
    counts = np.zeros(n + 1, np.int64)
    last, run, kept = -1, 0, False
    for i in range(labels.shape[0]):
        k = labels[i]
        if k != last:
            if kept:
                counts[last + 1] += run
            last, run = k, 0
            kept = 0 <= k < n and keep[k]
        run += 1
    if kept:
        counts[last + 1] += run
    return counts


@njit(cache=True, nogil=True)
def _fill_by_label(labels, keep, counts):
    # (order, starts) of the kept labels from their counts (counts[k + 1], as
    # _count_by_label's); a run's write position is kept in a register
    n = keep.shape[0]
    starts = np.cumsum(counts)
    fill = starts[:-1].copy()
    order = np.empty(starts[-1], np.int64)
    last, pos, kept = -1, 0, False
    for i in range(labels.shape[0]):
        k = labels[i]
        if k != last:
            if kept:
                fill[last] = pos
            last = k
            kept = 0 <= k < n and keep[k]
            if kept:
                pos = fill[k]
        if kept:
            order[pos] = i
            pos += 1
    return order, starts


@njit(cache=True, nogil=True)
def _continues(ranges, r, c, dr, dc, step, continuation, noise, jump_ratio, jump_min):
    # Is the step ``step`` from (r, c) to (r + dr, c + dc) continued on both sides along
    # the same line by steps within ``continuation`` of it (a surface seen at a grazing
    # angle: its range steps change slowly)? An occlusion onto such a surface has the
    # occluder's small steps on one side. With ``noise`` > 0 (a laser's single returns,
    # each range off by that rms alone) a step continued on one side is enough when it is
    # continued beyond the noise's reach: the difference of two steps carries sqrt(6)
    # noises, and within ``continuation`` of the step by ``_NOISE_REACH`` of them it is the
    # steady stepping of a face two to four grid lines wide (see jump_mask), not chance.
    h, w = ranges.shape
    limit = continuation * abs(step)
    rp, cp = r - dr, c - dc
    rn, cn = r + 2 * dr, c + 2 * dc
    before = np.nan
    after = np.nan
    if rp >= 0 and cp >= 0:
        before = ranges[r, c] - ranges[rp, cp]
    if rn < h and cn < w:
        after = ranges[rn, cn] - ranges[r + dr, c + dc]
    # (NaN compares False: an invalid or missing neighbour continues nothing)
    before_ok = before * step > 0 and abs(before - step) <= limit
    after_ok = after * step > 0 and abs(after - step) <= limit
    if before_ok and after_ok:
        return True
    if noise <= 0:
        return False
    strict = limit - _NOISE_REACH * np.sqrt(6.0) * noise
    # a pair of steps continuing each other between two small steps (no jump on either side
    # of the pair) is a mixed return, one footprint straddling an occlusion: its two steps
    # split the gap. A narrow face's pair has the jump onto what lies behind it on one side.
    if after_ok and abs(after - step) <= strict:
        if not (_small(ranges, rp, cp, r, c, jump_ratio, jump_min)
                and _small(ranges, rn, cn, rn + dr, cn + dc, jump_ratio, jump_min)):
            return True
    if before_ok and abs(before - step) <= strict:
        if not (_small(ranges, rp - dr, cp - dc, rp, cp, jump_ratio, jump_min)
                and _small(ranges, r + dr, c + dc, rn, cn, jump_ratio, jump_min)):
            return True
    return False


@njit(cache=True, nogil=True)
def _small(ranges, r0, c0, r1, c1, jump_ratio, jump_min):
    # whether the step from (r0, c0) to (r1, c1) is no jump; off the grid or NaN counts as
    # small (nothing there tells the pair from a mixed return)
    h, w = ranges.shape
    if r0 < 0 or c0 < 0 or r1 < 0 or c1 < 0 or r0 >= h or c0 >= w or r1 >= h or c1 >= w:
        return True
    a, b = ranges[r0, c0], ranges[r1, c1]
    if not (abs(a - b) > _jump_limit(a, b, jump_ratio, jump_min)):
        return True
    return False


#: Noise sigmas (of a difference of two steps) by which a one-sided continuation must hold.
_NOISE_REACH = 3.0


@njit(cache=True, nogil=True)
def jump_mask(ranges, jump_ratio, jump_min, continuation, noise):
    """The farther pixel of every 4-neighbour pair whose ranges differ by more than
    ``max(jump_min, jump_ratio * nearer)`` (see ``edges.jump_edges``); NaN is no jump.
    With ``continuation > 0`` a step that the steps before and after it along the same
    line continue (within that share of itself) is a grazing surface, no jump; with
    ``noise > 0`` (the range noise of a laser's single returns) so is a step that one side
    continues within that share less three noises of the steps' difference."""
    h, w = ranges.shape
    mask = np.zeros((h, w), np.bool_)
    for r in range(h):
        for c in range(w):
            a = ranges[r, c]
            for dr, dc in ((0, 1), (1, 0)):
                if r + dr >= h or c + dc >= w:
                    continue
                b = ranges[r + dr, c + dc]
                if abs(a - b) > _jump_limit(a, b, jump_ratio, jump_min):
                    if continuation > 0 and _continues(ranges, r, c, dr, dc, b - a, continuation, noise, jump_ratio, jump_min):
                        continue
                    if a > b:
                        mask[r, c] = True
                    else:
                        mask[r + dr, c + dc] = True
    return mask


@njit(cache=True, nogil=True)
def _row_runs(labels):
    # Runs of one positive label along each row: (row_start, start, stop, label) with
    # row r's runs at row_start[r]:row_start[r + 1].
    h, w = labels.shape
    row_start = np.zeros(h + 1, np.int64)
    starts = np.empty(h * w, np.int64)
    stops = np.empty(h * w, np.int64)
    owner = np.empty(h * w, labels.dtype)
    m = 0
    for r in range(h):
        c = 0
        while c < w:
            k = labels[r, c]
            end = c + 1
            while end < w and labels[r, end] == k:
                end += 1
            if k > 0:
                starts[m], stops[m], owner[m] = c, end, k
                m += 1
            c = end
        row_start[r + 1] = m
    return row_start, starts, stops, owner


@njit(cache=True, nogil=True)
def adjacency_matrix(labels, n, reach):
    """(n, n) bool: regions ``a != b`` (both > 0) with pixels within ``reach`` rows and columns."""
    h, w = labels.shape
    adj = np.zeros((n, n), np.bool_)
    # On runs of one label per row: two runs ``dr <= reach`` rows apart are that close
    # when their column spans, one widened by ``reach``, overlap. A row holds a few runs
    # where it holds a hundred pixels.
    row_start, starts, stops, owner = _row_runs(labels)
    for r in range(h):
        for dr in range(0, min(reach, h - 1 - r) + 1):
            first = row_start[r + dr]
            for i in range(row_start[r], row_start[r + 1]):
                a = owner[i]
                lo, hi = starts[i] - reach, stops[i] + reach
                for j in range(first, row_start[r + dr + 1]):
                    if stops[j] <= lo:
                        first = j + 1  # runs are ordered: later runs of row r start further right
                        continue
                    if starts[j] >= hi:
                        break
                    b = owner[j]
                    if a != b and b < n and a < n:
                        adj[a, b] = True
                        adj[b, a] = True
    return adj


@njit(cache=True, nogil=True)
def grow_rings(xyz, labels, kinds, params, rms, sigma, ranges, iterations, k_sigma,
               jump_ratio, jump_min, row0=0, row1=-1, col0=0, col1=-1):
    """Grow regions into free valid pixels, one 4-connected ring per iteration (in place).

    A free pixel joins the 4-neighbouring region whose model is within
    ``k_sigma * max(sigma, rms)`` of it, the best-fitting one when several are, provided
    the range step to that neighbour is no jump (``<= max(jump_min, jump_ratio * r)``).
    Regions with ``kinds[k] == 0`` do not grow. Returns the number of pixels added.

    The first ring is looked for in rows ``row0:row1`` and columns ``col0:col1`` only (-1:
    to the grid's end): a caller that knows every growing region lies in a box, and passes
    it grown by ``iterations``, gets the same answer without a pass over the whole grid
    (:func:`grow_rings_in_boxes`: in several boxes).
    """
    h, w = labels.shape
    r1 = h if row1 < 0 else row1
    c1 = w if col1 < 0 else col1
    boxes = np.empty((1, 4), np.int64)
    boxes[0, 0], boxes[0, 1], boxes[0, 2], boxes[0, 3] = row0, r1, col0, c1
    return grow_rings_in_boxes(xyz, labels, kinds, params, rms, sigma, ranges, iterations, k_sigma,
                               jump_ratio, jump_min, boxes)


@njit(cache=True, nogil=True)
def first_ring_grows(xyz, labels, kinds, params, rms, sigma, ranges, k_sigma, jump_ratio, jump_min):
    """Whether :func:`grow_rings` over the whole grid, with the same arguments, adds a pixel
    in its first ring: some free pixel (``labels == 0``, a finite point) that growth's own
    test (the same compiled function: the answer is its, to the bit) gives to a 4-neighbouring
    region with a model. When none, growth adds no pixel at all (it stops at the first ring
    that adds none). ``xyz`` (N, 3), ``sigma`` and ``ranges`` flat, ``labels`` C-contiguous
    (H, W); nothing is changed.
    """
    h, w = labels.shape
    flat = labels.reshape(h * w)
    for i in range(h * w):
        if flat[i] != 0 or not np.isfinite(xyz[i, 2]):
            continue
        if _nearest_neighbour_model(i, flat, h, w, xyz, kinds, params, rms, sigma, ranges, k_sigma, jump_ratio,
                                    jump_min)[0] > 0:
            return True
    return False


@njit(cache=True, nogil=True)
def grow_rings_in_boxes(xyz, labels, kinds, params, rms, sigma, ranges, iterations, k_sigma,
                        jump_ratio, jump_min, boxes):
    """:func:`grow_rings` with the first ring looked for in the boxes ``(row0, row1, col0,
    col1)`` (half-open, rows of ``boxes``; they may overlap) only: a caller that knows every
    growing region lies in them, each grown by ``iterations``, gets the same answer
    (every ring is decided from the labels at its start, so the order in which its pixels
    are listed changes nothing) without a pass over the box holding them all.
    """
    h, w = labels.shape
    flat = labels.ravel()
    total = 0
    # frontier: free valid pixels next to a labelled one
    frontier = np.empty(h * w, np.int64)
    n_front = 0
    mark = np.zeros(h * w, np.uint8)
    for b in range(boxes.shape[0]):
        r0, r1 = max(boxes[b, 0], 0), min(boxes[b, 1], h)
        c0, c1 = max(boxes[b, 2], 0), min(boxes[b, 3], w)
        for r in range(r0, r1):
            for c in range(c0, c1):
                i = r * w + c
                if flat[i] != 0 or mark[i] != 0 or not np.isfinite(xyz[i, 2]):
                    continue
                if ((r > 0 and flat[i - w] > 0) or (r < h - 1 and flat[i + w] > 0)
                        or (c > 0 and flat[i - 1] > 0) or (c < w - 1 and flat[i + 1] > 0)):
                    frontier[n_front] = i
                    n_front += 1
                    mark[i] = 1
    chosen = np.empty(h * w, np.int32)
    for _ in range(iterations):
        if n_front == 0:
            break
        # decide every frontier pixel from the labels as they were at the ring's start
        for f in range(n_front):
            chosen[f] = _nearest_neighbour_model(frontier[f], flat, h, w, xyz, kinds, params, rms, sigma,
                                                 ranges, k_sigma, jump_ratio, jump_min)[0]
        grown = 0
        for f in range(n_front):
            if chosen[f] > 0:
                flat[frontier[f]] = chosen[f]
                grown += 1
        if grown == 0:
            break
        total += grown
        # next frontier: free valid neighbours of the pixels just added, plus the pixels
        # that stayed free (a neighbour may have joined a region this ring)
        new_front = np.empty(h * w, np.int64)
        n_new = 0
        for f in range(n_front):
            i = frontier[f]
            if chosen[f] == 0:
                new_front[n_new] = i
                n_new += 1
                continue
            mark[i] = 0
            for step in range(4):
                j = _neighbour(i, step, h, w)
                if j < 0:
                    continue
                if flat[j] == 0 and mark[j] == 0 and np.isfinite(xyz[j, 2]):
                    mark[j] = 1
                    new_front[n_new] = j
                    n_new += 1
        frontier, n_front = new_front, n_new
    return total

@njit(cache=True, nogil=True)
def claim_rings(xyz, labels, kinds, params, rms, sigma, challengers, iterations, k_sigma, box):
    """Let ``challengers`` take over neighbouring pixels their models explain better (in place).

    Only pixels inside ``box``, an int64 array ``(row0, row1, col0, col1)`` (half-open), are considered
    (:func:`claim_rings_in_boxes`: inside any of several boxes).

    Per iteration, a pixel labelled with a non-challenger region and 4-adjacent to a
    challenger joins the challenger whose model is within ``k_sigma * max(sigma, rms)`` and
    nearer (in those units) than its own region's. A region found after its neighbours
    had already taken the pixels they could explain wins back those it explains better.
    Returns the number of pixels moved.
    """
    return claim_rings_in_boxes(xyz, labels, kinds, params, rms, sigma, challengers, iterations, k_sigma,
                                box.reshape((1, 4)))


@njit(cache=True, nogil=True)
def claim_rings_in_boxes(xyz, labels, kinds, params, rms, sigma, challengers, iterations, k_sigma, boxes):
    """:func:`claim_rings` with only the pixels inside any of the boxes ``(row0, row1, col0,
    col1)`` (half-open, rows of ``boxes``; they may overlap) considered: the challengers'
    pixels are looked for within a pixel of each box, not in the box holding them all."""
    h, w = labels.shape
    flat = labels.ravel()
    n = kinds.shape[0]
    clipped = np.empty((boxes.shape[0], 4), np.int64)
    m = 0
    area = 0
    for b in range(boxes.shape[0]):
        r0, r1, c0, c1 = max(boxes[b, 0], 0), min(boxes[b, 1], h), max(boxes[b, 2], 0), min(boxes[b, 3], w)
        if r1 > r0 and c1 > c0:
            clipped[m, 0], clipped[m, 1], clipped[m, 2], clipped[m, 3] = r0, r1, c0, c1
            area += (r1 - r0) * (c1 - c0)
            m += 1
    if m == 0:
        return 0
    clipped = clipped[:m]
    # The pixels to decide: those touching a challenger (the first ring's are the
    # neighbours of the challengers' pixels within a pixel of a box). A pixel whose label
    # and 4 neighbours did not change keeps its answer, so each later ring decides only
    # the neighbours of the pixels just moved. Each ring is decided from the labels at its
    # start: the order its pixels are listed in changes nothing.
    front = np.empty(min(area, h * w), np.int64)  # (a pixel is listed once per ring, in a box)
    stamp = np.zeros(h * w, np.int32)  # ring + 1 when a pixel was listed for that ring
    n_front = 0
    for b in range(m):
        r0, r1, c0, c1 = clipped[b, 0], clipped[b, 1], clipped[b, 2], clipped[b, 3]
        for r in range(max(r0 - 1, 0), min(r1 + 1, h)):
            for c in range(max(c0 - 1, 0), min(c1 + 1, w)):
                k = flat[r * w + c]
                if k <= 0 or k >= n or not challengers[k]:
                    continue
                n_front = _list_claimable(flat, r * w + c, h, w, n, challengers, clipped, stamp, 1,
                                          front, n_front)
    chosen = np.empty(front.shape[0], np.int32)
    following = np.empty_like(front)
    moved = 0
    for ring in range(iterations):
        # decide every listed pixel from the labels as they were at the ring's start
        changed = 0
        for f in range(n_front):
            i = front[f]
            chosen[f] = _claimant(flat, xyz, i, h, w, n, kinds, params, rms, sigma, challengers, k_sigma)
            changed += chosen[f] > 0
        if changed == 0:
            break
        for f in range(n_front):
            if chosen[f] > 0:
                flat[front[f]] = chosen[f]
        moved += changed
        n_next = 0
        for f in range(n_front):
            if chosen[f] > 0:
                n_next = _list_claimable(flat, front[f], h, w, n, challengers, clipped, stamp, ring + 2,
                                         following, n_next)
        front, following, n_front = following, front, n_next
    return moved


@njit(cache=True, nogil=True, inline="always")
def _list_claimable(flat, i, h, w, n, challengers, boxes, stamp, mark, out, count):
    # append to out[count:] the claimable 4-neighbours of pixel i within one of ``boxes``
    # (rows (row0, row1, col0, col1), clipped to the grid) not yet stamped ``mark``,
    # stamping them; returns the new count
    for step in range(4):
        j = _neighbour(i, step, h, w)
        if j < 0 or stamp[j] == mark:
            continue
        if _in_boxes(j // w, j % w, boxes) and _claimable(flat, j, h, w, n, challengers):
            stamp[j] = mark
            out[count] = j
            count += 1
    return count


@njit(cache=True, nogil=True, inline="always")
def _in_boxes(r, c, boxes):
    # whether (r, c) lies in one of the boxes (rows (row0, row1, col0, col1), half-open)
    for b in range(boxes.shape[0]):
        if boxes[b, 0] <= r < boxes[b, 1] and boxes[b, 2] <= c < boxes[b, 3]:
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def _claimable(flat, i, h, w, n, challengers):
    # a pixel of a non-challenger region with a challenger among its 4 neighbours
    own = flat[i]
    if own <= 0 or own >= n or challengers[own]:
        return False
    for step in range(4):
        j = _neighbour(i, step, h, w)
        if j >= 0 and 0 < flat[j] < n and challengers[flat[j]]:
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def _claimant(flat, xyz, i, h, w, n, kinds, params, rms, sigma, challengers, k_sigma):
    # the challenger that takes pixel i (0: none): nearest in units of max(sigma, rms), within
    # k_sigma and nearer than the pixel's own region
    own = flat[i]
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    own_score = np.inf
    if kinds[own] > 0:
        own_score = _distance(kinds[own], params[own], x, y, z) / max(sigma[i], rms[own])
    best, best_score = 0, min(own_score, k_sigma)
    for step in range(4):  # up, down, left, right
        j = _neighbour(i, step, h, w)
        if j < 0:
            continue
        k = flat[j]
        if k <= 0 or k >= n or not challengers[k] or kinds[k] == 0:
            continue
        score = _distance(kinds[k], params[k], x, y, z) / max(sigma[i], rms[k])
        if score < best_score:
            best, best_score = k, score
    return best


@njit(cache=True, nogil=True, inline="always")
def _same_or_free(k, own):
    # whether a neighbour labelled k takes no pixel of region ``own`` (its own, or unlabelled)
    return k == own or k <= 0


@njit(cache=True, nogil=True, inline="always")
def _settled_label(xyz, flat, i, r, c, h, w, n, kinds, params, rms, sigma, ranges, k_sigma, margin, jump_ratio,
                   jump_min, plane_margin, wrap):
    # the region settle_borders moves pixel i at (r, c) to (0: it stays), by the labels ``flat``
    # as they are (a pixel inside its region stays: no neighbour of another region)
    own = flat[i]
    if own <= 0 or own >= n or kinds[own] == 0:
        return 0
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    own_score = -1.0  # (measured at the first neighbour that may take the pixel)
    best, best_score = 0, k_sigma
    for step in range(4):
        j = _grid_neighbour(i, r, c, step, h, w, wrap)
        if j < 0:
            continue
        k = flat[j]
        if k == own or k <= 0 or k >= n or kinds[k] == 0:
            continue
        if not (abs(ranges[i] - ranges[j]) <= _jump_limit(ranges[i], ranges[j], jump_ratio, jump_min)):
            continue
        if own_score < 0.0:
            own_score = _distance(kinds[own], params[own], x, y, z) / max(sigma[i], rms[own])
        score = _distance(kinds[k], params[k], x, y, z) / max(sigma[i], rms[k])
        need = plane_margin if (kinds[own] != PLANE and kinds[k] == PLANE) else margin
        if score < best_score and score < own_score - need:
            best, best_score = k, score
    return best


@njit(cache=True, nogil=True)
def settle_borders(xyz, labels, kinds, params, rms, sigma, ranges, iterations, k_sigma, margin,
                   jump_ratio, jump_min, plane_margin, wrap):
    """Move border pixels to the neighbouring region whose model explains them clearly better (in place).

    Per iteration, a labelled pixel 4-adjacent to another region (no range jump between
    them: ``<= max(jump_min, jump_ratio * r)``) joins the neighbour whose model is within
    ``k_sigma`` and more than ``margin`` nearer than its own region's, both in units of
    ``max(sigma, rms)`` (``plane_margin`` instead when its own model is curved and the
    neighbour's a plane); the best such neighbour wins. With ``wrap`` (a 360-degree grid)
    the first and last columns are neighbours. Decisions are taken on the labels as they
    were at the iteration's start; the models do not change, so a pixel never moves back.
    Returns the number of pixels moved.

    A pixel's decision depends on its own label and its neighbours' only: after the first
    pass over the grid, each iteration asks again only the pixels that moved and their
    neighbours (the same answers as a pass over the grid per iteration, which cost a
    640 x 480 frame 0.5 ms each, 48 of them when a band settles that deep).
    """
    h, w = labels.shape
    n = kinds.shape[0]
    flat = labels.reshape(-1)
    size = h * w
    movers = np.empty(size, np.int64)
    targets = np.empty(size, np.int32)
    changed = 0
    if iterations > 0:
        for r in range(h):
            for c in range(w):
                i = r * w + c
                own = flat[i]
                # (most pixels have no neighbour of another region, but for unlabelled ones:
                # asked in place, not by the decision's call; a loop over _grid_neighbour's steps
                # here made a frame's pass ten times slower)
                if (own <= 0 or (r == 0 or _same_or_free(flat[i - w], own))
                        and (r == h - 1 or _same_or_free(flat[i + w], own))
                        and (_same_or_free(flat[i - 1], own) if c > 0
                             else (not wrap or _same_or_free(flat[i + w - 1], own)))
                        and (_same_or_free(flat[i + 1], own) if c < w - 1
                             else (not wrap or _same_or_free(flat[i - w + 1], own)))):
                    continue
                best = _settled_label(xyz, flat, i, r, c, h, w, n, kinds, params, rms, sigma, ranges, k_sigma,
                                      margin, jump_ratio, jump_min, plane_margin, wrap)
                if best > 0:
                    movers[changed] = i
                    targets[changed] = best
                    changed += 1
    if changed == 0:  # (most calls: nothing to ask again, nothing more to allocate)
        return 0
    asked = np.empty(size, np.int64)
    stamp = np.zeros(size, np.int32)
    count = 0
    moved = 0
    for iteration in range(iterations):
        if iteration > 0:
            changed = 0
            for q in range(count):
                i = asked[q]
                r = i // w
                best = _settled_label(xyz, flat, i, r, i - r * w, h, w, n, kinds, params, rms, sigma, ranges,
                                      k_sigma, margin, jump_ratio, jump_min, plane_margin, wrap)
                if best > 0:
                    movers[changed] = i
                    targets[changed] = best
                    changed += 1
        if changed == 0:
            break
        for q in range(changed):
            flat[movers[q]] = targets[q]
        moved += changed
        # the next iteration asks the pixels whose own or neighbours' labels changed
        mark = iteration + 1
        count = 0
        for q in range(changed):
            i = movers[q]
            r = i // w
            c = i - r * w
            for step in range(5):
                j = i if step == 4 else _grid_neighbour(i, r, c, step, h, w, wrap)
                if j >= 0 and stamp[j] != mark:
                    stamp[j] = mark
                    asked[count] = j
                    count += 1
    return moved

@njit(cache=True, nogil=True)
def block_means(xyz, stride, min_count):
    """Mean of the valid points of each ``stride x stride`` block, and their number.

    Returns ``(means (h, w, 3), counts (h, w) int64)`` with ``h = ceil(H / stride)``; the
    mean is NaN where a block has fewer than ``min_count`` (and at least 1) valid points.
    """
    big_h, big_w = xyz.shape[0], xyz.shape[1]
    h, w = (big_h + stride - 1) // stride, (big_w + stride - 1) // stride
    sums = np.empty((h, w, 3))
    counts = np.zeros((h, w), np.int64)
    least = max(min_count, 1)
    # Block by block, its rows in turn: the block's sums stay in registers from its first
    # pixel to its mean (the same additions in the same order: row by row, each row left
    # to right), where a pass row by row across the frame stored and reloaded every
    # block's sums once per row.
    for br in range(h):
        r1 = min(br * stride + stride, big_h)
        for bc in range(w):
            c1 = min(bc * stride + stride, big_w)
            sx, sy, sz, m = 0.0, 0.0, 0.0, 0
            for r in range(br * stride, r1):
                for c in range(bc * stride, c1):
                    x, y, z = xyz[r, c, 0], xyz[r, c, 1], xyz[r, c, 2]
                    if np.isfinite(x) and np.isfinite(y) and np.isfinite(z):
                        sx += x
                        sy += y
                        sz += z
                        m += 1
            counts[br, bc] = m
            if m >= least:
                sums[br, bc, 0], sums[br, bc, 1], sums[br, bc, 2] = sx / m, sy / m, sz / m
            else:
                sums[br, bc, 0] = sums[br, bc, 1] = sums[br, bc, 2] = np.nan
    return sums, counts

@njit(cache=True, nogil=True)
def piece_ids(idx, width):
    """The 4-connected pieces that the flat pixel indices ``idx`` (increasing) form.

    Returns ``(ids, sizes)``: ``ids[p]`` the piece of ``idx[p]`` (int32), pieces numbered
    from 0 in the raster order of their first pixel (as OpenCV's connected components
    number them), and each piece's pixel count.
    """
    n = idx.shape[0]
    piece = np.full(n, -1, np.int32)
    sizes = np.zeros(n, np.int64)
    if n == 0:
        return piece, sizes
    # Union-find over the positions in idx, each set's root its first position: idx
    # increases, so a pixel's left neighbour is the position before it and its upper
    # neighbour is found by a second cursor one row behind. No array of the pixels'
    # bounding box (pixels spread over a frame would fill a frame-sized one per call).
    root = np.empty(n, np.int64)
    above = 0
    for p in range(n):
        root[p] = p
        if p > 0 and idx[p] % width > 0 and idx[p - 1] == idx[p] - 1:
            _union(root, p - 1, p)
        up = idx[p] - width
        while above < p and idx[above] < up:
            above += 1
        if above < p and idx[above] == up:
            _union(root, above, p)
    pieces = 0
    for p in range(n):
        r = _find(root, p)
        if r == p:
            piece[p] = pieces
            pieces += 1
        else:
            piece[p] = piece[r]
        sizes[piece[p]] += 1
    return piece, sizes[:pieces]


@njit(cache=True, nogil=True, inline="always")
def _find(root, p):
    # the root of p's set, halving the path on the way
    while root[p] != p:
        root[p] = root[root[p]]
        p = root[p]
    return p


@njit(cache=True, nogil=True, inline="always")
def _union(root, a, b):
    # join the sets of a and b under the smaller root (each set's first position)
    ra, rb = _find(root, a), _find(root, b)
    if ra < rb:
        root[rb] = ra
    elif rb < ra:
        root[ra] = rb

@njit(cache=True, nogil=True)
def largest_piece(idx, width):
    """The flat pixel indices ``idx`` (increasing) of the largest 4-connected piece they form.

    Ties go to the piece holding the first pixel in raster order, as with OpenCV's labels.
    """
    piece, sizes = piece_ids(idx, width)
    if sizes.shape[0] == 0:
        return idx.copy()
    best = np.argmax(sizes)  # the first of equal sizes
    out = np.empty(sizes[best], idx.dtype)
    m = 0
    for p in range(idx.shape[0]):
        if piece[p] == best:
            out[m] = idx[p]
            m += 1
    return out

@njit(cache=True, nogil=True)
def labels_near(labels, idx, reach):
    """The positive labels (increasing) of the 2-D ``labels`` within ``reach`` rows and
    columns of the flat pixels ``idx`` (increasing): the labels under the pixels' mask
    dilated by a ``2 reach + 1`` square. Each run of pixels along a row reads the
    rectangle its squares cover (no patch, dilation or sort of its bounding box), once
    (again only from a run that met a label beyond the mask, after growing it)."""
    seen = np.zeros(256, np.bool_)
    start = 0
    while True:
        start, top = _runs_near(labels, idx, reach, seen, start)
        if start < 0:
            return np.flatnonzero(seen[1:]) + 1
        grown = np.zeros(max(2 * seen.size, top + 1), np.bool_)
        grown[:seen.size] = seen
        seen = grown


@njit(cache=True, nogil=True)
def _runs_near(labels, idx, reach, seen, start):
    # over the rectangles the runs of idx from ``start`` cover, grown by reach: marks each
    # label in ``seen``; ``(-1, 0)`` when done, or the start of the run that met a label
    # beyond ``seen`` and that label (a first read of every rectangle for the largest label,
    # to size the mask, doubled the time: 2 ms of a stereo scan's joins along the rays)
    h, w = labels.shape
    n = idx.shape[0]
    size = seen.shape[0]
    while start < n:
        # a run: consecutive pixels of one row
        end = start + 1
        row = idx[start] // w
        while end < n and idx[end] == idx[end - 1] + 1 and idx[end] // w == row:
            end += 1
        c0, c1 = idx[start] - row * w, idx[end - 1] - row * w
        for r in range(max(row - reach, 0), min(row + reach + 1, h)):
            for c in range(max(c0 - reach, 0), min(c1 + reach + 1, w)):
                k = labels[r, c]
                if k >= size:
                    return start, int(k)
                if k > 0:
                    seen[k] = True
        start = end
    return -1, 0


@njit(cache=True, nogil=True)
def free_pixels(labels, valid):
    """Flat indices (increasing) of the valid pixels without a label:
    ``np.flatnonzero((labels == 0) & valid)`` without its two whole-grid temporaries."""
    flat, ok = labels.ravel(), valid.ravel()
    count = 0
    for i in range(flat.shape[0]):
        if flat[i] == 0 and ok[i]:
            count += 1
    out = np.empty(count, np.int64)
    m = 0
    for i in range(flat.shape[0]):
        if flat[i] == 0 and ok[i]:
            out[m] = i
            m += 1
    return out


@njit(cache=True, nogil=True)
def member_pixels(labels, members):
    """Flat indices (increasing) of the pixels whose label ``k`` has ``members[k]`` (k > 0)."""
    flat = labels.ravel()
    n = members.shape[0]
    # one pass into a frame-sized buffer (only its written pages are touched), each label
    # run's membership looked up once: a count pass and a fill pass read the labels twice
    out = np.empty(flat.shape[0], np.int64)
    m = 0
    last, inside = -1, False
    for i in range(flat.shape[0]):
        k = flat[i]
        if k != last:
            last = k
            inside = 0 < k < n and members[k]
        if inside:
            out[m] = i
            m += 1
    return out[:m].copy()

@njit(cache=True, nogil=True)
def _clipped_boxes(boxes, h, w):
    # (K, 4) boxes (row0, row1, col0, col1), half-open, clipped to an h x w grid (an empty
    # box keeps row1 <= row0 or col1 <= col0)
    out = np.empty((boxes.shape[0], 4), np.int64)
    for j in range(boxes.shape[0]):
        out[j, 0], out[j, 1] = max(boxes[j, 0], 0), min(boxes[j, 1], h)
        out[j, 2], out[j, 3] = max(boxes[j, 2], 0), min(boxes[j, 3], w)
    return out


@njit(cache=True, nogil=True, inline="always")
def _in_earlier_box(r, c, boxes, j):
    # whether (r, c) lies in one of boxes 0..j-1 (a pixel of overlapping boxes is listed once)
    for b in range(j):
        if boxes[b, 0] <= r < boxes[b, 1] and boxes[b, 2] <= c < boxes[b, 3]:
            return True
    return False


@njit(cache=True, nogil=True)
def _area(boxes):
    total = 0
    for j in range(boxes.shape[0]):
        total += max(boxes[j, 1] - boxes[j, 0], 0) * max(boxes[j, 3] - boxes[j, 2], 0)
    return total


@njit(cache=True, nogil=True)
def _increasing(out, m, n_boxes):
    # the first m entries, increasing: one box lists its pixels in raster order already
    return out[:m].copy() if n_boxes < 2 else np.sort(out[:m])


@njit(cache=True, nogil=True)
def member_pixels_in_boxes(labels, members, boxes):
    """:func:`member_pixels` of the pixels within ``boxes`` ((K, 4) int64, rows ``(row0, row1,
    col0, col1)``, half-open, clipped to the grid): flat indices, increasing, each once where
    boxes overlap. Costs the boxes' area, not the grid's."""
    h, w = labels.shape
    clipped = _clipped_boxes(boxes, h, w)
    n = members.shape[0]
    out = np.empty(_area(clipped), np.int64)
    m = 0
    for j in range(clipped.shape[0]):
        for r in range(clipped[j, 0], clipped[j, 1]):
            for c in range(clipped[j, 2], clipped[j, 3]):
                k = labels[r, c]
                if 0 < k < n and members[k] and not _in_earlier_box(r, c, clipped, j):
                    out[m] = r * w + c
                    m += 1
    return _increasing(out, m, clipped.shape[0])


@njit(cache=True, nogil=True)
def differing_in_boxes(a, b, boxes):
    """Flat indices (increasing, each once) of the pixels within ``boxes`` ((K, 4) int64, rows
    ``(row0, row1, col0, col1)``, half-open, clipped to the grid) where the label images ``a``
    and ``b`` (same shape) differ. Costs the boxes' area, not the grid's."""
    h, w = a.shape
    clipped = _clipped_boxes(boxes, h, w)
    out = np.empty(_area(clipped), np.int64)
    m = 0
    for j in range(clipped.shape[0]):
        for r in range(clipped[j, 0], clipped[j, 1]):
            for c in range(clipped[j, 2], clipped[j, 3]):
                if a[r, c] != b[r, c] and not _in_earlier_box(r, c, clipped, j):
                    out[m] = r * w + c
                    m += 1
    return _increasing(out, m, clipped.shape[0])


@njit(cache=True, nogil=True)
def free_pixels_in_boxes(labels, valid, free, boxes):
    """:func:`free_pixels` of ``labels`` and ``valid`` when only the pixels within ``boxes``
    ((K, 4) int64, rows ``(row0, row1, col0, col1)``, half-open, clipped to the grid) may have
    changed label since ``free`` (flat, increasing) listed the free pixels: those of ``free``
    outside every box, and the valid unlabelled pixels within the boxes, increasing. Costs
    the free pixels and the boxes' area, not the grid's."""
    h, w = labels.shape
    clipped = _clipped_boxes(boxes, h, w)
    n_boxes = clipped.shape[0]
    kept = np.empty(free.shape[0], np.int64)  # the listed pixels outside every box, increasing
    a = 0
    for i in range(free.shape[0]):
        p = free[i]
        if not _in_earlier_box(p // w, p % w, clipped, n_boxes):
            kept[a] = p
            a += 1
    found = np.empty(_area(clipped), np.int64)  # the free pixels within the boxes
    b = 0
    for j in range(n_boxes):
        for r in range(clipped[j, 0], clipped[j, 1]):
            for c in range(clipped[j, 2], clipped[j, 3]):
                if labels[r, c] == 0 and valid[r, c] and not _in_earlier_box(r, c, clipped, j):
                    found[b] = r * w + c
                    b += 1
    found = _increasing(found, b, n_boxes)
    # the two increasing lists (no pixel in both) merged: no sort of the listed pixels
    out = np.empty(a + b, np.int64)
    i = j = m = 0
    while i < a and j < b:
        if kept[i] < found[j]:
            out[m] = kept[i]
            i += 1
        else:
            out[m] = found[j]
            j += 1
        m += 1
    out[m:m + a - i] = kept[i:a]
    m += a - i
    out[m:] = found[j:b]
    return out


@njit(cache=True, nogil=True)
def box_members(labels, boxes, first_label):
    """``group_by_label`` for the labels ``first_label + j`` found within their boxes alone:
    ``(order, starts)``, ``order[starts[j]:starts[j + 1]]`` the flat indices (increasing) of
    label ``first_label + j``, which must lie within ``boxes[j] = (row0, row1, col0, col1)``
    (half-open). Costs the boxes' area, not the grid's."""
    h, w = labels.shape
    n = boxes.shape[0]
    starts = np.zeros(n + 1, np.int64)
    for j in range(n):
        k = first_label + j
        for r in range(max(boxes[j, 0], 0), min(boxes[j, 1], h)):
            for c in range(max(boxes[j, 2], 0), min(boxes[j, 3], w)):
                starts[j + 1] += labels[r, c] == k
    starts = np.cumsum(starts)
    order = np.empty(starts[n], np.int64)
    for j in range(n):
        k, m = first_label + j, starts[j]
        for r in range(max(boxes[j, 0], 0), min(boxes[j, 1], h)):
            for c in range(max(boxes[j, 2], 0), min(boxes[j, 3], w)):
                if labels[r, c] == k:
                    order[m] = r * w + c
                    m += 1
    return order, starts

@njit(cache=True, nogil=True)
def label_counts(labels):
    """``np.bincount`` of a non-negative label image (any shape), in one compiled pass each
    for the largest label and the counts."""
    flat = labels.ravel()
    top = 0
    for i in range(flat.shape[0]):
        top = max(top, flat[i])
    counts = np.zeros(top + 1, np.int64)
    # Labels come in runs along the rows: a run is counted in a register and added when it
    # ends, where an increment per pixel would chain each pixel's store to the last's load.
    last, run = -1, 0
    for i in range(flat.shape[0]):
        k = flat[i]
        if k != last:
            if run:
                counts[last] += run
            last, run = k, 0
        run += 1
    if run:
        counts[last] += run
    return counts

@njit(cache=True, nogil=True)
def relabel(labels, lut):
    """``lut[labels]`` for a 2-D label image, as int32 (labels within ``lut``)."""
    h, w = labels.shape
    out = np.empty((h, w), np.int32)
    for r in range(h):
        for c in range(w):
            out[r, c] = lut[labels[r, c]]
    return out

@njit(cache=True, nogil=True)
def ranges_and_noise(ranges, valid, sigma0, quadratic):
    """``np.where(valid, ranges, nan)`` and the noise ``sigma0 + quadratic * r**2`` there, for
    2-D images, in one pass (NaN where invalid; the same operations as numpy's, in order)."""
    h, w = ranges.shape
    out = np.empty((h, w))
    noise = np.empty((h, w))
    for r in range(h):
        for c in range(w):
            value = ranges[r, c] if valid[r, c] else np.nan
            out[r, c] = value
            noise[r, c] = sigma0 + quadratic * (value * value)
    return out, noise


@njit(cache=True, nogil=True)
def count_either_side(values, idx, low, high):
    """``(count of values[idx] <= low, count >= high, whether one is NaN)`` in one pass over
    ``idx``, without gathering ``values[idx]`` (a union's noise values on a tunnel's wall:
    190000 pixels, three temporaries)."""
    below, above, nan = 0, 0, False
    for i in idx:
        v = values[i]
        if v <= low:
            below += 1
        if v >= high:
            above += 1
        if np.isnan(v):
            nan = True
    return below, above, nan
