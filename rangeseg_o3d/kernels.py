"""Compiled (numba) loops over whole label images: one pass each, whatever the number of regions.

Region-level work in numpy costs a handful of small-array calls per region; at 10-50
regions per scan that Python overhead, not arithmetic, dominated the pipeline. These
kernels do per-pixel work for every region at once: label-wise moments, quadric normal
equations, growth of regions into the edge band, inlier counts and region adjacency.

Models are passed as a table indexed by label (see :func:`model_table`): ``kinds[k]`` is
0 (no model), 1 plane ``(nx, ny, nz, d)``, 2 sphere ``(cx, cy, cz, r)`` or 3 cylinder
``(ax, ay, az, px, py, pz, r)`` in ``params[k]``, and ``rms[k]`` its rms.

Compiled on first use and cached beside this module (``cache=True``), so only the first
run on a machine pays the compilation (a few seconds).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .fitting._compiled import _solve

__all__ = [
    "label_moments",
    "quadric_sums",
    "grow_rings",
    "count_inliers",
    "distance_stats",
    "adjacency_matrix",
    "block_means",
    "assign_tiles",
]

N_MOMENTS = 10  # count, sx, sy, sz, sxx, sxy, sxz, syy, syz, szz


@njit(cache=True, nogil=True)
def label_moments(xyz, labels, n):
    """(n, 10) moments per label: count, sums of x, y, z and of xx, xy, xz, yy, yz, zz.

    ``xyz`` is (N, 3), ``labels`` (N,); labels outside 1..n-1 and non-finite points are
    skipped. Sums are about the coordinate origin: in float64 the variance recovered from
    them keeps about 6 significant digits for millimetre noise at 100 m, far below what a
    threshold test needs.
    """
    out = np.zeros((n, N_MOMENTS))
    for i in range(labels.shape[0]):
        k = labels[i]
        if k <= 0 or k >= n:
            continue
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        o = out[k]
        o[0] += 1.0
        o[1] += x
        o[2] += y
        o[3] += z
        o[4] += x * x
        o[5] += x * y
        o[6] += x * z
        o[7] += y * y
        o[8] += y * z
        o[9] += z * z
    return out


@njit(cache=True, nogil=True)
def quadric_sums(xyz, labels, centre, e1, e2, normal, inv_spread, active):
    """Normal equations of the height field ``h = a u^2 + b uv + c v^2 + d u + e v + f`` per label.

    ``u, v`` are in-plane coordinates (frame ``e1, e2`` about ``centre``, scaled by
    ``inv_spread``) and ``h`` the height along ``normal``. Returns (n, 28): the 21 upper
    triangle entries of ``A^T A`` (row-major), the 6 of ``A^T h`` and ``h^T h``. Only
    labels with ``active[k]`` are summed.
    """
    n = centre.shape[0]
    out = np.zeros((n, 28))
    row = np.empty(6)
    for i in range(labels.shape[0]):
        k = labels[i]
        if k <= 0 or k >= n or not active[k]:
            continue
        rx = xyz[i, 0] - centre[k, 0]
        ry = xyz[i, 1] - centre[k, 1]
        rz = xyz[i, 2] - centre[k, 2]
        if not (np.isfinite(rx) and np.isfinite(ry) and np.isfinite(rz)):
            continue
        u = (rx * e1[k, 0] + ry * e1[k, 1] + rz * e1[k, 2]) * inv_spread[k]
        v = (rx * e2[k, 0] + ry * e2[k, 1] + rz * e2[k, 2]) * inv_spread[k]
        h = rx * normal[k, 0] + ry * normal[k, 1] + rz * normal[k, 2]
        row[0] = u * u
        row[1] = u * v
        row[2] = v * v
        row[3] = u
        row[4] = v
        row[5] = 1.0
        o = out[k]
        m = 0
        for a in range(6):
            for b in range(a, 6):
                o[m] += row[a] * row[b]
                m += 1
        for a in range(6):
            o[21 + a] += row[a] * h
        o[27] += h * h
    return out


@njit(cache=True, nogil=True, inline="always")
def _distance(kind, prm, x, y, z):
    # Absolute orthogonal distance of (x, y, z) from the model; inf for "no model".
    if kind == 1:
        return abs(prm[0] * x + prm[1] * y + prm[2] * z - prm[3])
    if kind == 2:
        dx, dy, dz = x - prm[0], y - prm[1], z - prm[2]
        return abs(np.sqrt(dx * dx + dy * dy + dz * dz) - prm[3])
    if kind == 3:
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


@njit(cache=True, nogil=True)
def count_inliers(xyz, labels, kinds, params, rms, sigma, factor):
    """Per label, the pixels within ``factor * max(sigma, rms)`` of the label's model."""
    return distance_stats(xyz, labels, kinds, params, rms, sigma, factor)[0]


@njit(cache=True, nogil=True)
def distance_stats(xyz, labels, kinds, params, rms, sigma, factor):
    """Per label: inliers (as :func:`count_inliers`), sum of squared distances, pixel count."""
    n = kinds.shape[0]
    inliers = np.zeros(n, np.int64)
    squares = np.zeros(n)
    counts = np.zeros(n, np.int64)
    for i in range(labels.shape[0]):
        k = labels[i]
        if k <= 0 or k >= n or kinds[k] == 0:
            continue
        dist = _distance(kinds[k], params[k], xyz[i, 0], xyz[i, 1], xyz[i, 2])
        if not np.isfinite(dist):
            continue
        counts[k] += 1
        squares[k] += dist * dist
        if dist <= factor * max(sigma[i], rms[k]):
            inliers[k] += 1
    return inliers, squares, counts


@njit(cache=True, nogil=True)
def grow_rings(xyz, labels, kinds, params, rms, sigma, ranges, iterations, k_sigma,
               jump_ratio, jump_min):
    """Grow regions into free valid pixels, one 4-connected ring per iteration (in place).

    A free pixel joins the 4-neighbouring region whose model is within
    ``k_sigma * max(sigma, rms)`` of it, the best-fitting one when several are, provided
    the range step to that neighbour is no jump (``<= max(jump_min, jump_ratio * r)``).
    Regions with ``kinds[k] == 0`` do not grow. Returns the number of pixels added.
    """
    h, w = labels.shape
    flat = labels.ravel()
    n = kinds.shape[0]
    total = 0
    # frontier: free valid pixels next to a labelled one
    frontier = np.empty(h * w, np.int64)
    n_front = 0
    mark = np.zeros(h * w, np.uint8)
    for i in range(h * w):
        if flat[i] != 0 or not np.isfinite(xyz[i, 2]):
            continue
        r, c = i // w, i % w
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
            i = frontier[f]
            best, best_score = 0, k_sigma
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
                score = _distance(kinds[k], params[k], xyz[i, 0], xyz[i, 1], xyz[i, 2]) / max(
                    sigma[i], rms[k])
                if score <= best_score and (best == 0 or score < best_score):
                    best, best_score = k, score
            chosen[f] = best
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
def adjacency_matrix(labels, n, reach):
    """(n, n) bool: regions ``a != b`` (both > 0) with pixels within ``reach`` rows and columns."""
    h, w = labels.shape
    adj = np.zeros((n, n), np.bool_)
    for r in range(h):
        for c in range(w):
            a = labels[r, c]
            if a <= 0:
                continue
            for dr in range(0, reach + 1):
                rr = r + dr
                if rr >= h:
                    break
                for dc in range(-reach, reach + 1):
                    if dr == 0 and dc <= 0:
                        continue
                    cc = c + dc
                    if cc < 0 or cc >= w:
                        continue
                    b = labels[rr, cc]
                    if b > 0 and b != a:
                        adj[a, b] = True
                        adj[b, a] = True
    return adj


@njit(cache=True, nogil=True)
def block_means(xyz, stride, min_count):
    """Mean of the valid points of each ``stride x stride`` block, and their number.

    Returns ``(means (h, w, 3), counts (h, w) int64)`` with ``h = ceil(H / stride)``; the
    mean is NaN where a block has fewer than ``min_count`` (and at least 1) valid points.
    """
    big_h, big_w = xyz.shape[0], xyz.shape[1]
    h, w = (big_h + stride - 1) // stride, (big_w + stride - 1) // stride
    sums = np.zeros((h, w, 3))
    counts = np.zeros((h, w), np.int64)
    for r in range(big_h):
        br = r // stride
        for c in range(big_w):
            x, y, z = xyz[r, c, 0], xyz[r, c, 1], xyz[r, c, 2]
            if np.isfinite(x) and np.isfinite(y) and np.isfinite(z):
                bc = c // stride
                sums[br, bc, 0] += x
                sums[br, bc, 1] += y
                sums[br, bc, 2] += z
                counts[br, bc] += 1
    for br in range(h):
        for bc in range(w):
            if counts[br, bc] >= max(min_count, 1):
                for a in range(3):
                    sums[br, bc, a] /= counts[br, bc]
            else:
                for a in range(3):
                    sums[br, bc, a] = np.nan
    return sums, counts


@njit(cache=True, nogil=True)
def assign_tiles(xyz, height, width, tile_labels, tile, kinds, params, rms, sigma, k_sigma):
    """Full-resolution labels from labels of ``tile x tile`` means and the regions' models.

    Each valid pixel joins, among the regions of its own tile and the 8 tiles around it,
    the one whose model is nearest in units of ``max(sigma, rms)``, if within
    ``k_sigma`` (its own tile's region wins ties). Pixels of a tile whose region has no
    model (``kinds == 0``) keep that region. ``xyz`` and ``sigma`` are flat (H*W).
    """
    th, tw = tile_labels.shape
    out = np.zeros((height, width), np.int32)
    n = kinds.shape[0]
    for r in range(height):
        tr = r // tile
        for c in range(width):
            i = r * width + c
            x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            if not np.isfinite(z):
                continue
            tc = c // tile
            own = tile_labels[tr, tc]
            if own > 0 and own < n and kinds[own] == 0:
                out[r, c] = own
                continue
            best, best_score = 0, k_sigma
            if own > 0 and own < n:
                score = _distance(kinds[own], params[own], x, y, z) / max(sigma[i], rms[own])
                if score <= best_score:
                    best, best_score = own, score
            for dr in range(-1, 2):
                rr = tr + dr
                if rr < 0 or rr >= th:
                    continue
                for dc in range(-1, 2):
                    cc = tc + dc
                    if cc < 0 or cc >= tw or (dr == 0 and dc == 0):
                        continue
                    k = tile_labels[rr, cc]
                    if k <= 0 or k >= n or k == best or kinds[k] == 0:
                        continue
                    score = _distance(kinds[k], params[k], x, y, z) / max(sigma[i], rms[k])
                    if score < best_score:
                        best, best_score = k, score
            out[r, c] = best
    return out


@njit(cache=True, nogil=True)
def planes_from_moment_rows(moments, degenerate_ratio):
    """Least-squares plane of each row of (K, 10) moments (see :func:`label_moments`).

    Returns ``(centroid (K,3), normal (K,3), d (K,), eigvals (K,3) ascending, frame (K,3,3)
    rows normal/middle/largest, ok (K,))`` with ``d >= 0`` (through the origin: the largest
    normal component positive); ``ok`` is False for < 3 points or collinear points.
    """
    k = moments.shape[0]
    centroid = np.zeros((k, 3))
    normal = np.zeros((k, 3))
    d = np.zeros(k)
    eigvals = np.zeros((k, 3))
    frame = np.zeros((k, 3, 3))
    ok = np.zeros(k, np.bool_)
    cov = np.empty((3, 3))
    for i in range(k):
        n = moments[i, 0]
        if n < 1:
            continue
        c = moments[i, 1:4] / n
        centroid[i] = c
        cov[0, 0] = moments[i, 4] / n - c[0] * c[0]
        cov[0, 1] = cov[1, 0] = moments[i, 5] / n - c[0] * c[1]
        cov[0, 2] = cov[2, 0] = moments[i, 6] / n - c[0] * c[2]
        cov[1, 1] = moments[i, 7] / n - c[1] * c[1]
        cov[1, 2] = cov[2, 1] = moments[i, 8] / n - c[1] * c[2]
        cov[2, 2] = moments[i, 9] / n - c[2] * c[2]
        vals, vecs = np.linalg.eigh(cov)
        for a in range(3):
            vals[a] = max(vals[a], 0.0)
            eigvals[i, a] = vals[a]
            for b in range(3):
                frame[i, a, b] = vecs[b, a]
        nrm = vecs[:, 0].copy()
        dist = nrm[0] * c[0] + nrm[1] * c[1] + nrm[2] * c[2]
        scale = max(abs(c[0]), abs(c[1]), abs(c[2])) + np.sqrt(vals[0] + vals[1] + vals[2])
        if abs(dist) <= 1e-12 * max(scale, 1e-300):
            big = 0
            for a in range(1, 3):
                if abs(nrm[a]) > abs(nrm[big]):
                    big = a
            if nrm[big] < 0:
                nrm = -nrm
            dist = 0.0
        elif dist < 0:
            nrm = -nrm
            dist = -dist
        normal[i] = nrm
        frame[i, 0] = nrm
        d[i] = dist
        ok[i] = n >= 3 and vals[2] > 0 and vals[1] > degenerate_ratio * degenerate_ratio * vals[2]
    return centroid, normal, d, eigvals, frame, ok


@njit(cache=True, nogil=True)
def quadric_shapes(sums, counts, active):
    """``(gain, roundness)`` per row of :func:`quadric_sums` output (see ``moments.quadric_gains``).

    Rows not ``active``, or whose 6x6 normal equations are numerically singular (pivot
    below 1e-12 of the largest: points on a conic), get ``(1.0, 0.5)``.
    """
    k = sums.shape[0]
    gain = np.ones(k)
    roundness = np.full(k, 0.5)
    ata = np.empty((6, 6))
    atb = np.empty(6)
    for i in range(k):
        if not active[i] or counts[i] < 1:
            continue
        m = 0
        for a in range(6):
            for b in range(a, 6):
                ata[a, b] = ata[b, a] = sums[i, m]
                m += 1
            atb[a] = sums[i, 21 + a]
        # points on a conic make the equations numerically singular: no height field
        coef, ok = _solve(ata, atb, 1e-12)
        if not ok:
            continue
        hh = sums[i, 27]
        quad_ss = hh
        for a in range(6):
            quad_ss -= 2.0 * coef[a] * atb[a]
            for b in range(6):
                quad_ss += coef[a] * ata[a, b] * coef[b]
        quad_ms = max(quad_ss, 0.0) / counts[i]
        plane_ms = hh / counts[i]
        if quad_ms > 0:
            gain[i] = np.sqrt(plane_ms / quad_ms)
        else:
            gain[i] = np.inf if plane_ms > 0 else 1.0
        a2, b2, c2 = coef[0], coef[1], coef[2]
        mean, diff = a2 + c2, np.sqrt((a2 - c2) ** 2 + b2 * b2)
        k1, k2 = abs(mean + diff), abs(mean - diff)
        big = max(k1, k2)
        roundness[i] = min(k1, k2) / big if big > 0 else 0.5
    return gain, roundness


@njit(cache=True, nogil=True)
def group_by_label(labels, n):
    """Counting sort of pixel indices by label: ``(order, starts)``.

    ``order[starts[k]:starts[k + 1]]`` are the flat indices of label ``k`` in increasing
    order, for ``0 <= k < n``; labels outside that range are left out.
    """
    counts = np.zeros(n + 1, np.int64)
    for i in range(labels.shape[0]):
        k = labels[i]
        if 0 <= k < n:
            counts[k + 1] += 1
    starts = np.cumsum(counts)
    fill = starts[:-1].copy()
    order = np.empty(starts[-1], np.int64)
    for i in range(labels.shape[0]):
        k = labels[i]
        if 0 <= k < n:
            order[fill[k]] = i
            fill[k] += 1
    return order, starts


@njit(cache=True, nogil=True)
def _plane_frame(pts, support):
    # centre and eigenvectors (columns, ascending) of the scatter of pts[support]
    n = 0
    c = np.zeros(3)
    for i in range(pts.shape[0]):
        if support[i]:
            n += 1
            c += pts[i]
    c /= max(n, 1)
    scatter = np.zeros((3, 3))
    for i in range(pts.shape[0]):
        if support[i]:
            for a in range(3):
                for b in range(3):
                    scatter[a, b] += (pts[i, a] - c[a]) * (pts[i, b] - c[b])
    return c, np.linalg.eigh(scatter)[1]


@njit(cache=True, nogil=True)
def _plane_distances(pts, support, out):
    c, vecs = _plane_frame(pts, support)
    for i in range(pts.shape[0]):
        out[i] = abs((pts[i, 0] - c[0]) * vecs[0, 0] + (pts[i, 1] - c[1]) * vecs[1, 0]
                     + (pts[i, 2] - c[2]) * vecs[2, 0])


@njit(cache=True, nogil=True)
def _quadric_distances(pts, support, out):
    # height along the support's smallest principal axis minus the least-squares
    # h = a u^2 + b uv + c v^2 + d u + e v + f over the other two axes
    c, vecs = _plane_frame(pts, support)
    n = pts.shape[0]
    local = np.empty((n, 3))
    for i in range(n):
        for a in range(3):
            local[i, a] = ((pts[i, 0] - c[0]) * vecs[0, a] + (pts[i, 1] - c[1]) * vecs[1, a]
                           + (pts[i, 2] - c[2]) * vecs[2, a])
    ata = np.zeros((6, 6))
    atb = np.zeros(6)
    row = np.empty(6)
    for i in range(n):
        if not support[i]:
            continue
        u, v = local[i, 1], local[i, 2]
        row[0], row[1], row[2], row[3], row[4], row[5] = u * u, u * v, v * v, u, v, 1.0
        for a in range(6):
            atb[a] += row[a] * local[i, 0]
            for b in range(6):
                ata[a, b] += row[a] * row[b]
    coef, ok = _solve(ata, atb, 0.0)
    if not ok:
        coef[:] = 0.0
    for i in range(n):
        u, v = local[i, 1], local[i, 2]
        fitted = coef[0] * u * u + coef[1] * u * v + coef[2] * v * v + coef[3] * u + coef[4] * v + coef[5]
        out[i] = abs(local[i, 0] - fitted)


@njit(cache=True, nogil=True)
def _within_spread(dist, support, sigma, out):
    # out = dist <= 3 max(sigma, rms of dist over support); out may be support itself
    ss, m = 0.0, 0
    for p in range(dist.shape[0]):
        if support[p]:
            ss += dist[p] * dist[p]
            m += 1
    limit = 3.0 * max(sigma, np.sqrt(ss / max(m, 1)))
    for p in range(dist.shape[0]):
        out[p] = dist[p] <= limit


@njit(cache=True, nogil=True)
def trimmed_proposals(pts, sigma, rounds, keep, trials, seed):
    """The two proposals of ``robust.trimmed_fit``: points near its dominant plane and quadric.

    Plane: the best of ``trials`` random three-point planes (most points within
    ``3 sigma``), refitted ``rounds`` times on the points within ``3 max(sigma, rms)``.
    Quadric: a height field refitted ``rounds`` times on the ``keep`` closest points
    (least trimmed squares by concentration steps). Returns two boolean masks of the
    points within ``3 max(sigma, spread)`` of each (all False where a proposal had fewer
    than 6 supporting points).
    """
    n = pts.shape[0]
    np.random.seed(seed)
    tol = 3.0 * sigma
    best_count, best_n, best_d = -1, np.zeros(3), 0.0
    for _ in range(trials):
        i, j, k = np.random.randint(0, n), np.random.randint(0, n), np.random.randint(0, n)
        ux, uy, uz = pts[j, 0] - pts[i, 0], pts[j, 1] - pts[i, 1], pts[j, 2] - pts[i, 2]
        vx, vy, vz = pts[k, 0] - pts[i, 0], pts[k, 1] - pts[i, 1], pts[k, 2] - pts[i, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        if length <= 1e-12:
            continue
        nx, ny, nz = nx / length, ny / length, nz / length
        d = nx * pts[i, 0] + ny * pts[i, 1] + nz * pts[i, 2]
        count = 0
        for p in range(n):
            if abs(nx * pts[p, 0] + ny * pts[p, 1] + nz * pts[p, 2] - d) <= tol:
                count += 1
        if count > best_count:
            best_count = count
            best_n[0], best_n[1], best_n[2], best_d = nx, ny, nz, d
    plane_near = np.zeros(n, np.bool_)
    quad_near = np.zeros(n, np.bool_)
    dist = np.empty(n)
    support = np.ones(n, np.bool_)
    if best_count >= 0:
        for p in range(n):
            support[p] = abs(best_n[0] * pts[p, 0] + best_n[1] * pts[p, 1] + best_n[2] * pts[p, 2]
                             - best_d) <= tol
    for _ in range(rounds):
        if support.sum() < 6:
            break
        _plane_distances(pts, support, dist)
        _within_spread(dist, support, sigma, support)
    if support.sum() >= 6:
        _plane_distances(pts, support, dist)
        _within_spread(dist, support, sigma, plane_near)
    support[:] = True
    for _ in range(rounds):
        _quadric_distances(pts, support, dist)
        order = np.argsort(dist)
        support[:] = False
        for p in range(keep):
            support[order[p]] = True
    _quadric_distances(pts, support, dist)
    _within_spread(dist, support, sigma, quad_near)
    return plane_near, quad_near


@njit(cache=True, nogil=True)
def claim_rings(xyz, labels, kinds, params, rms, sigma, challengers, iterations, k_sigma, box):
    """Let ``challengers`` take over neighbouring pixels their models explain better (in place).

    Only pixels inside ``box = (row0, row1, col0, col1)`` (half-open) are considered.

    Per iteration, a pixel labelled with a non-challenger region and 4-adjacent to a
    challenger joins the challenger whose model is within ``k_sigma * max(sigma, rms)`` and
    nearer (in those units) than its own region's. A region found after its neighbours
    had already taken the pixels they could explain wins back those it explains better.
    Returns the number of pixels moved.
    """
    h, w = labels.shape
    n = kinds.shape[0]
    moved = 0
    new = labels.copy()
    r0, r1, c0, c1 = max(box[0], 0), min(box[1], h), max(box[2], 0), min(box[3], w)
    for _ in range(iterations):
        changed = 0
        for r in range(r0, r1):
            for c in range(c0, c1):
                own = labels[r, c]
                if own <= 0 or own >= n or challengers[own]:
                    continue
                # integer tests first: most pixels touch no challenger
                up = labels[r - 1, c] if r > 0 else 0
                down = labels[r + 1, c] if r < h - 1 else 0
                left = labels[r, c - 1] if c > 0 else 0
                right = labels[r, c + 1] if c < w - 1 else 0
                if not ((0 < up < n and challengers[up]) or (0 < down < n and challengers[down])
                        or (0 < left < n and challengers[left]) or (0 < right < n and challengers[right])):
                    continue
                i = r * w + c
                x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
                own_score = np.inf
                if kinds[own] > 0:
                    own_score = _distance(kinds[own], params[own], x, y, z) / max(sigma[i], rms[own])
                best, best_score = 0, min(own_score, k_sigma)
                for k in (up, down, left, right):
                    if k <= 0 or k >= n or not challengers[k] or kinds[k] == 0:
                        continue
                    score = _distance(kinds[k], params[k], x, y, z) / max(sigma[i], rms[k])
                    if score < best_score:
                        best, best_score = k, score
                if best > 0:
                    new[r, c] = best
                    changed += 1
        if changed == 0:
            break
        labels[r0:r1, c0:c1] = new[r0:r1, c0:c1]
        moved += changed
    return moved
