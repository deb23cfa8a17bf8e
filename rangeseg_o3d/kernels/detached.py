"""The pieces of a region apart from its body, and the region each touches most, in one pass.

:func:`rangeseg_o3d.detached.give_detached_pieces` hands a curved region's small pieces that
lie apart from the rest of it (its model's continuation crossing another surface) to the
region around them; this lists those pieces, each with the label it shares most links with
when that label's model explains it.
"""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .grid import _find, _union
from .inline import _distance, _grid_neighbour, _jump_limit

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("grid.py", "inline.py", "kinds.py")

__all__ = ["detached_pieces"]


@njit(cache=True, nogil=True)
def detached_pieces(labels, donors, xyz, ranges, sigma, kinds, params, rms, k_sigma, jump_ratio, jump_min, max_size,
                    wrap):
    """The 4-connected pieces of each region of ``donors`` (a flag per label; ``labels`` (H, W)
    int32, C-contiguous; pixels joined where they share a label) but its largest (the first
    found of equals), of fewer than ``max_size`` pixels, that the label they touch most
    explains: ``(pixels, starts, hosts)``, piece ``s``'s flat pixels (increasing)
    ``pixels[starts[s]:starts[s + 1]]`` and the label ``hosts[s]`` they go to.

    A piece's host is the other label with the most 4-neighbour links to it across no range
    jump (``|a - b| <= max(jump_min, jump_ratio * min(a, b))`` on ``ranges``, NaN where
    invalid: no link), the smallest of equals; it explains the piece when its model (the model
    table ``kinds``, ``params``, ``rms``) lies within ``k_sigma`` times the larger of ``sigma``
    (each pixel's range noise, flat) and its rms of every pixel (``xyz`` (H*W, 3)), as the
    labelling by the tile models asks. With ``wrap`` (a 360-degree grid) the first and last
    columns are neighbours."""
    h, w = labels.shape
    size = h * w
    flat = labels.reshape(size)
    rng = ranges.reshape(size)
    # Runs of one label along each row, joined to the runs of the row above they overlap
    # (union-find over runs: a few thousand a frame, where a pass from pixel to pixel over
    # the whole grid cost 2.5 ms on a 640 x 480 frame).
    run_row = np.empty(size, np.int64)
    run_start = np.empty(size, np.int64)
    run_end = np.empty(size, np.int64)
    parent = np.empty(size, np.int64)
    n_runs = 0
    row_first = np.empty(h + 1, np.int64)
    for r in range(h):
        row_first[r] = n_runs
        c = 0
        while c < w:
            k = flat[r * w + c]
            if k <= 0:
                c += 1
                continue
            c0 = c
            while c < w and flat[r * w + c] == k:
                c += 1
            run_row[n_runs], run_start[n_runs], run_end[n_runs] = r, c0, c
            parent[n_runs] = n_runs
            n_runs += 1
    row_first[h] = n_runs
    for r in range(h):
        first, last = row_first[r], row_first[r + 1]
        if wrap and last - first >= 2 and run_start[first] == 0 and run_end[last - 1] == w \
                and flat[r * w] == flat[r * w + w - 1]:
            _union(parent, first, last - 1)
        if r == 0:
            continue
        above, above_last = row_first[r - 1], row_first[r]
        for q in range(first, last):
            while above < above_last and run_end[above] <= run_start[q]:
                above += 1
            a = above
            while a < above_last and run_start[a] < run_end[q]:
                if flat[(r - 1) * w + run_start[a]] == flat[r * w + run_start[q]]:
                    _union(parent, q, a)
                a += 1
    root_size = np.zeros(n_runs, np.int64)
    root_of = np.empty(n_runs, np.int64)
    n_labels = 1
    for q in range(n_runs):
        root_of[q] = _find(parent, q)
        root_size[root_of[q]] += run_end[q] - run_start[q]
        n_labels = max(n_labels, flat[run_row[q] * w + run_start[q]] + 1)
    body = np.full(n_labels, -1, np.int64)
    body_size = np.zeros(n_labels, np.int64)
    for q in range(n_runs):  # (runs in raster order: the first found of equals)
        if root_of[q] == q:
            k = flat[run_row[q] * w + run_start[q]]
            if root_size[q] > body_size[k]:
                body[k], body_size[k] = q, root_size[q]
    # the small pieces' pixels, piece after piece (runs grouped by their root)
    small = np.zeros(n_runs, np.int64)
    n_small = 0
    for q in range(n_runs):
        root = root_of[q]
        k = flat[run_row[q] * w + run_start[q]]
        if root != body[k] and root_size[root] < max_size and k < donors.shape[0] and donors[k]:
            small[n_small] = q
            n_small += 1
    small = small[:n_small]
    roots = np.empty(n_small, np.int64)
    for t in range(n_small):
        roots[t] = root_of[small[t]]
    by_root = small[np.argsort(roots, kind="mergesort")]
    order = np.empty(size, np.int64)
    bounds = [0]
    piece_label = []
    n_order = 0
    t = 0
    while t < n_small:
        root = root_of[by_root[t]]
        while t < n_small and root_of[by_root[t]] == root:
            q = by_root[t]
            for c in range(run_start[q], run_end[q]):
                order[n_order] = run_row[q] * w + c
                n_order += 1
            t += 1
        bounds.append(n_order)
        piece_label.append(flat[run_row[root] * w + run_start[root]])
    n_pieces = len(piece_label)
    links = np.zeros(n_labels, np.int64)
    touched = np.empty(n_labels, np.int64)
    out = np.empty(n_order, np.int64)
    starts = [0]
    hosts = []
    n_out = 0
    for p in range(n_pieces):
        k, first, last = piece_label[p], bounds[p], bounds[p + 1]
        n_touched = 0
        for t in range(first, last):
            i = order[t]
            r = i // w
            for step in range(4):
                j = _grid_neighbour(i, r, i - r * w, step, h, w, wrap)
                if j < 0:
                    continue
                other = flat[j]
                if other <= 0 or other == k:
                    continue
                a, b = rng[i], rng[j]
                if not abs(a - b) <= _jump_limit(a, b, jump_ratio, jump_min):
                    continue  # a jump, or a NaN range
                if links[other] == 0:
                    touched[n_touched] = other
                    n_touched += 1
                links[other] += 1
        host, most = 0, 0
        for t in range(n_touched):
            other = touched[t]
            if links[other] > most or (links[other] == most and other < host):
                host, most = other, links[other]
            links[other] = 0
        if host == 0 or host >= kinds.shape[0] or kinds[host] == 0:
            continue
        explained = True
        for t in range(first, last):
            i = order[t]
            limit = k_sigma * max(sigma[i], rms[host])
            if not _distance(kinds[host], params[host], xyz[i, 0], xyz[i, 1], xyz[i, 2]) < limit:
                explained = False
                break
        if not explained:
            continue
        members = np.sort(order[first:last])
        out[n_out:n_out + members.size] = members
        n_out += members.size
        starts.append(n_out)
        hosts.append(host)
    return out[:n_out].copy(), np.array(starts, np.int64), np.array(hosts, np.int64)

