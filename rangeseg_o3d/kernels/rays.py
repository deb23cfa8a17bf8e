"""Label-wise sums along a sensor's viewing rays (the range noise a plane's distances keep), and numpy's sums of
the planes fitted along them, bit for bit (the terms of :mod:`rangeseg_o3d.ray_planes`)."""

from __future__ import annotations

import numpy as np
from .growth import _ray_term
from .inline import _add_ray_terms, _jump_limit
from .linalg import solve_in_place
from .jit import njit  # numba.njit, with this package's cache locator installed

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("growth.py", "inline.py", "kinds.py", "linalg.py")

__all__ = ["plane_ray_sums", "trimmed_ray_plane", "band_bend", "settle_moves_along_rays", "ray_moment_sums",
           "pixel_ray_moments", "pairwise_sum",
           "box_ray_terms", "grid_line_order", "crease_cut_squares"]


@njit(cache=True, nogil=True)
def plane_ray_sums(xyz, labels, normals, offsets, sigma, origins, width):
    """``(counts, squares, ray_noise, range_noise)`` per label ``k`` whose plane
    ``(normals[k], offsets[k])`` is set (a zero normal: no plane): its pixels, the sum of
    their squared distances to it, of their range noise ``sigma`` times the incidence
    cosine squared, and of ``sigma`` squared. A pixel's ray starts at the origin, or at
    ``origins[row]`` when ``origins`` has rows (``(H, 3)``, a nodding laser's mirror; rows
    of ``width`` pixels). Pixels with a non-finite point or noise are skipped."""
    n = normals.shape[0]
    counts, squares = np.zeros(n), np.zeros(n)
    ray_noise, range_noise = np.zeros(n), np.zeros(n)
    planar = np.zeros(n, np.bool_)
    for k in range(1, n):
        planar[k] = normals[k, 0] != 0.0 or normals[k, 1] != 0.0 or normals[k, 2] != 0.0
    shifted = origins.shape[0] > 0
    ox, oy, oz = 0.0, 0.0, 0.0
    for i in range(labels.shape[0]):
        if shifted and i % width == 0:  # a new row: its rays' origin
            row = i // width
            ox, oy, oz = origins[row, 0], origins[row, 1], origins[row, 2]
        k = labels[i]
        if k <= 0 or k >= n or not planar[k]:
            continue
        x, y, z, s = xyz[i, 0] - ox, xyz[i, 1] - oy, xyz[i, 2] - oz, sigma[i]
        if not (np.isfinite(x + y + z) and np.isfinite(s)):
            continue
        nx, ny, nz = normals[k, 0], normals[k, 1], normals[k, 2]
        facing = x * nx + y * ny + z * nz  # n . (p - o): the range times the incidence cosine
        dist = facing + (ox * nx + oy * ny + oz * nz) - offsets[k]
        counts[k] += 1.0
        squares[k] += dist * dist
        # (sigma cos)^2 = sigma^2 (n . v)^2 / |v|^2: no square root
        ray_noise[k] += s * s * facing * facing / max(x * x + y * y + z * z, 1e-24)
        range_noise[k] += s * s
    return counts, squares, ray_noise, range_noise


@njit(cache=True, nogil=True)
def trimmed_ray_plane(xyz, idx, sigma, origins, width, refits, band, cos_floor):
    """``(near, chi, noise, centroid, frame)`` of the pixels ``idx`` (rows of the flat ``xyz`` and
    ``sigma``): the least-squares plane of their points refitted ``refits`` times to those
    within ``band`` noises of it (each pixel's range noise ``sigma`` times the incidence
    cosine of its ray, at least ``cos_floor``; rays as :func:`plane_ray_sums` casts them,
    from ``origins[row]`` when it has rows); ``noise`` that noise of each pixel's distance
    and ``chi`` its squared distance over it, about the last plane, ``near`` those within ``band`` of it, ``frame`` rows the
    plane's normal (pointing away from the sensor along the rays) and its in-plane axes of
    least and most spread. ``near`` is all False when fewer than half the pixels, or fewer
    than four, were within ``band`` of a plane to refit. The refits stop early once the
    band keeps the same pixels (the plane would be the same)."""
    n = idx.shape[0]
    rays = np.empty((n, 3))
    shifted = origins.shape[0] > 0
    for i in range(n):
        q = idx[i]
        x, y, z = xyz[q, 0], xyz[q, 1], xyz[q, 2]
        if shifted:
            row = q // width
            x, y, z = x - origins[row, 0], y - origins[row, 1], z - origins[row, 2]
        norm = max(np.sqrt(x * x + y * y + z * z), 1e-12)
        rays[i, 0], rays[i, 1], rays[i, 2] = x / norm, y / norm, z / norm
    near = np.ones(n, np.bool_)
    chi = np.zeros(n)
    noise = np.zeros(n)
    centroid = np.zeros(3)
    frame = np.zeros((3, 3))
    cov = np.zeros((3, 3))
    for step in range(refits + 1):
        m = 0
        centroid[:] = 0.0
        for i in range(n):
            if near[i]:
                m += 1
                for a in range(3):
                    centroid[a] += xyz[idx[i], a]
        if m < 4 or 2 * m < n:
            near[:] = False
            return near, chi, noise, centroid, frame
        centroid /= m
        cov[:, :] = 0.0
        for i in range(n):
            if near[i]:
                q = idx[i]
                for a in range(3):
                    for b in range(3):
                        cov[a, b] += (xyz[q, a] - centroid[a]) * (xyz[q, b] - centroid[b])
        _, vecs = np.linalg.eigh(cov)
        facing = 0.0
        for i in range(n):
            facing += rays[i, 0] * vecs[0, 0] + rays[i, 1] * vecs[1, 0] + rays[i, 2] * vecs[2, 0]
        sign = 1.0 if facing >= 0.0 else -1.0
        for a in range(3):
            frame[0, a] = sign * vecs[a, 0]
            frame[1, a] = vecs[a, 1]
            frame[2, a] = vecs[a, 2]
        moved = 0
        for i in range(n):
            q = idx[i]
            dist = ((xyz[q, 0] - centroid[0]) * frame[0, 0] + (xyz[q, 1] - centroid[1]) * frame[0, 1]
                    + (xyz[q, 2] - centroid[2]) * frame[0, 2])
            cosine = max(abs(rays[i, 0] * frame[0, 0] + rays[i, 1] * frame[0, 1] + rays[i, 2] * frame[0, 2]), cos_floor)
            noise[i] = sigma[q] * cosine
            chi[i] = (dist / max(noise[i], 1e-300)) ** 2
            within = chi[i] <= band * band
            if within != near[i]:
                moved += 1
            near[i] = within
        if moved == 0 and step > 0:  # the band kept its pixels: the next refit is this plane again
            break
    return near, chi, noise, centroid, frame


@njit(cache=True, nogil=True)
def band_bend(xyz, idx, sigma, origins, width, refits, band, cos_floor):
    """``(kept, mean_square, bend)`` of the pixels ``idx`` about the plane of
    :func:`trimmed_ray_plane`: how many lie within ``band`` noises of it, their mean
    squared distance in that noise, and how many standard errors their distances (positive
    away from the sensor) grow with the square of their coordinate along the plane's axis
    of least spread, its tilt allowed (weighted least squares of known variance: the
    columns 1, that coordinate, the other in-plane one and its square). A bend seen from
    outside, its middle nearer the sensor than its sides, is positive. ``(0, 0, 0)`` when
    the band held too few to refit."""
    near, chi, noise, centroid, frame = trimmed_ray_plane(xyz, idx, sigma, origins, width, refits, band, cos_floor)
    normal_eq = np.zeros((4, 4))
    rhs = np.zeros(4)
    row = np.zeros(4)
    kept, squares = 0, 0.0
    for i in range(idx.shape[0]):
        if not near[i]:
            continue
        q = idx[i]
        dx, dy, dz = xyz[q, 0] - centroid[0], xyz[q, 1] - centroid[1], xyz[q, 2] - centroid[2]
        dist = dx * frame[0, 0] + dy * frame[0, 1] + dz * frame[0, 2]
        across = dx * frame[1, 0] + dy * frame[1, 1] + dz * frame[1, 2]
        along = dx * frame[2, 0] + dy * frame[2, 1] + dz * frame[2, 2]
        weight = 1.0 / max(noise[i] * noise[i], 1e-24)  # (a noiseless pixel: finite, as chi's floor)
        row[0], row[1], row[2], row[3] = 1.0, across, along, across * across
        for a in range(4):
            rhs[a] += weight * row[a] * dist
            for b in range(4):
                normal_eq[a, b] += weight * row[a] * row[b]
        kept += 1
        squares += chi[i]
    if kept < 4:
        return 0, 0.0, 0.0
    if abs(np.linalg.det(normal_eq)) <= 0.0:
        return kept, squares / kept, 0.0
    inverse = np.linalg.inv(normal_eq)
    coefficient = 0.0
    for a in range(4):
        coefficient += inverse[3, a] * rhs[a]
    return kept, squares / kept, coefficient / np.sqrt(max(inverse[3, 3], 1e-300))


@njit(cache=True, nogil=True, inline="always")
def _range_sigmas(xyz, i, normals, offsets, k, sigma, ox, oy, oz, cos_floor):
    # how many range sigmas pixel i lies from where its ray (from (ox, oy, oz)) meets plane k:
    # its distance over the range noise times the incidence cosine (floored at cos_floor)
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    nx, ny, nz = normals[k, 0], normals[k, 1], normals[k, 2]
    rx, ry, rz = x - ox, y - oy, z - oz
    length = max(np.sqrt(rx * rx + ry * ry + rz * rz), 1e-12)
    cosine = max(abs(rx * nx + ry * ny + rz * nz) / length, cos_floor)
    return abs(x * nx + y * ny + z * nz - offsets[k]) / (max(sigma[i], 1e-12) * cosine)


@njit(cache=True, nogil=True)
def settle_moves_along_rays(xyz, labels, normals, offsets, sigma, ranges, origins, k_sigma, margin,
                            jump_ratio, jump_min, cos_floor, wrap):
    """``(pixels, targets)`` of one ring of :func:`rangeseg_o3d.refinement.along_rays.settle_along_rays`:
    the flat pixels of plane regions (``normals[k]`` not zero; plane ``normals[k] . p =
    offsets[k]``) that go to a 4-neighbouring plane region, and that region. A pixel moves
    to the neighbour (no range jump between them: ``<= max(jump_min, jump_ratio * r)``)
    whose plane meets its ray nearest in range sigmas (its distance over ``sigma`` times
    the incidence cosine, at least ``cos_floor``; the first of equals, neighbours taken up,
    down, left, right), within ``k_sigma`` and nearer than its own plane by more than
    ``margin``. Rays start at ``origins[row]`` when ``origins`` has rows, else at the
    origin; with ``wrap`` the first and last columns are neighbours. Decided on ``labels``
    as they are (not changed)."""
    h, w = labels.shape
    n = normals.shape[0]
    planar = np.zeros(n, np.bool_)
    for k in range(1, n):
        planar[k] = normals[k, 0] != 0.0 or normals[k, 1] != 0.0 or normals[k, 2] != 0.0
    shifted = origins.shape[0] > 0
    pixels = np.empty(h * w, np.int64)
    targets = np.empty(h * w, np.int64)
    moved = 0
    for r in range(h):
        ox, oy, oz = (origins[r, 0], origins[r, 1], origins[r, 2]) if shifted else (0.0, 0.0, 0.0)
        for c in range(w):
            own = labels[r, c]
            if own <= 0 or own >= n or not planar[own]:
                continue
            # inside its region (every neighbour the loop below would look at holds its own
            # label): nothing to decide, as the loop would find (most pixels of a scan)
            if ((r == 0 or labels[r - 1, c] == own) and (r == h - 1 or labels[r + 1, c] == own)
                    and (labels[r, c - 1] == own if c > 0 else (not wrap or w < 2 or labels[r, w - 1] == own))
                    and (labels[r, c + 1] == own if c < w - 1 else (not wrap or w < 2 or labels[r, 0] == own))):
                continue
            i = r * w + c
            mine = -1.0  # its own plane's, asked when a neighbour could take it
            best, best_k = np.inf, 0
            for step in range(4):
                rr, cc = r + (step == 1) - (step == 0), c + (step == 3) - (step == 2)
                if wrap:
                    cc = cc % w
                if rr < 0 or rr >= h or cc < 0 or cc >= w:
                    continue
                k = labels[rr, cc]
                if k == own or k <= 0 or k >= n or not planar[k]:
                    continue
                j = rr * w + cc
                if not (abs(ranges[i] - ranges[j]) <= _jump_limit(ranges[i], ranges[j], jump_ratio, jump_min)):
                    continue
                if mine < 0.0:
                    mine = _range_sigmas(xyz, i, normals, offsets, own, sigma, ox, oy, oz, cos_floor)
                    if mine <= margin:  # no neighbour can be nearer by the margin
                        break
                score = _range_sigmas(xyz, i, normals, offsets, k, sigma, ox, oy, oz, cos_floor)
                if score < best:
                    best, best_k = score, k
            if best_k > 0 and best <= k_sigma and best < mine - margin:
                pixels[moved], targets[moved] = i, best_k
                moved += 1
    return pixels[:moved], targets[:moved]


@njit(cache=True, nogil=True, inline="always")
def _block_sum(a, lo, n):
    # numpy's pairwise leaf: up to 7 in a row from 0, else eight running sums joined in pairs
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - n % 8:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True, nogil=True)
def pairwise_sum(a, lo, n):
    """The sum of ``a[lo:lo + n]`` as numpy sums a contiguous float64 vector (from 0, spans of
    up to 128 in eight running sums, larger spans halved at a multiple of 8 and their halves'
    sums added): the same bits as ``a[lo:lo + n].sum()``. The halving runs on a stack of its
    own (a cached recursive kernel crashed when loaded from the cache)."""
    if n <= 128:
        return _block_sum(a, lo, n)
    spans = np.empty((128, 3), np.int64)  # (lo, n, halves done): depth <= 2 log2(n)
    sums = np.empty(128)
    top, count = 0, 0
    spans[0, 0], spans[0, 1], spans[0, 2] = lo, n, 0
    while top >= 0:
        s_lo, s_n, done = spans[top, 0], spans[top, 1], spans[top, 2]
        if s_n <= 128:
            sums[count] = _block_sum(a, s_lo, s_n)
            count += 1
            top -= 1
        elif done:  # both halves summed: the left's sum below the right's
            sums[count - 2] = sums[count - 2] + sums[count - 1]
            count -= 1
            top -= 1
        else:
            half = s_n // 2
            half -= half % 8
            spans[top, 2] = 1
            spans[top + 1, 0], spans[top + 1, 1], spans[top + 1, 2] = s_lo + half, s_n - half, 0
            spans[top + 2, 0], spans[top + 2, 1], spans[top + 2, 2] = s_lo, half, 0
            top += 2
    return sums[0]


@njit(cache=True, nogil=True)
def ray_moment_sums(rays, inverse, weight):
    """``(outer, first, second)``: ``sum w u u^T`` (3 x 3), ``sum w q u`` (3) and ``sum w q^2``
    over the points' unit rays ``rays`` (N, 3), inverse ranges ``inverse`` and weights
    ``weight`` (:func:`rangeseg_o3d.ray_planes.ray_terms`). Each term is numpy's (``(w u_a) u_b``,
    ``(w q) u_a``, ``(w q) q``) and each sum is numpy's too (the (N, 3, 3) and (N, 3) terms
    summed point by point in their order, the (N,) squares pairwise, :func:`pairwise_sum`):
    the same bits as :func:`rangeseg_o3d.ray_planes.ray_moments`' numpy form, without its
    (N, 3, 3) products."""
    outer = np.zeros((3, 3))
    first = np.zeros(3)
    squares = np.empty(inverse.shape[0])
    for i in range(inverse.shape[0]):
        wi = weight[i]
        wq = wi * inverse[i]
        _add_ray_terms(outer, first, wi, wq, rays[i, 0], rays[i, 1], rays[i, 2])
        squares[i] = wq * inverse[i]
    return outer, first, pairwise_sum(squares, 0, squares.shape[0])


@njit(cache=True, nogil=True)
def pixel_ray_moments(xyz, sigma, pixels):
    """:func:`ray_moment_sums` of the pixels ``pixels`` (flat, into ``xyz`` (N, 3) and their
    range noise ``sigma`` (N,)), their terms made as :func:`rangeseg_o3d.ray_planes.ray_terms`
    makes them (:func:`rangeseg_o3d.kernels.growth._ray_term`, NaN kept as numpy keeps it): the same bits as ``ray_moments(*ray_terms(xyz[pixels],
    sigma[pixels]))`` in one pass, without the gathers and the terms' arrays."""
    n = pixels.shape[0]
    outer = np.zeros((3, 3))
    first = np.zeros(3)
    squares = np.empty(n)
    for i in range(n):
        p = pixels[i]
        u0, u1, u2, q, wi = _ray_term(xyz[p, 0], xyz[p, 1], xyz[p, 2], sigma[p])
        wq = wi * q
        _add_ray_terms(outer, first, wi, wq, u0, u1, u2)
        squares[i] = wq * q
    return outer, first, pairwise_sum(squares, 0, n)


@njit(cache=True, nogil=True)
def grid_line_order(keys, order):
    """``order`` (N,) filled with ``np.argsort(keys, kind="stable")``, the same positions, in
    linear time on the positions of pixels across a line of the grid: a counting sort into
    N buckets of equal width in key (floor of ``(key - min) * scale`` never decreases with the
    key, so the buckets keep the keys' order; positions enter them in increasing order), each
    bucket then sorted by key keeping that order among equal keys (insertion sort; numba's
    stable merge sort for a bucket of more than 16). numpy's timsort of the 32 directions
    of a 16384-pixel search took a third of :func:`crease_cut_squares`' time."""
    n = keys.shape[0]
    if n == 0:
        return
    low, high = keys[0], keys[0]
    for j in range(n):
        low = min(low, keys[j])
        high = max(high, keys[j])
    scale = (n - 1) / (high - low) if high > low else 0.0
    bucket = np.empty(n, np.int64)
    first = np.zeros(n + 1, np.int64)
    for j in range(n):
        b = min(int((keys[j] - low) * scale), n - 1)
        bucket[j] = b
        first[b + 1] += 1
    for b in range(n):
        first[b + 1] += first[b]
    fill = first[:n].copy()
    for j in range(n):
        b = bucket[j]
        order[fill[b]] = j
        fill[b] += 1
    for b in range(n):
        lo, hi = first[b], first[b + 1]
        ordered = True  # a bucket of equal keys (a grid line across the direction) is common
        for t in range(lo + 1, hi):
            if keys[order[t]] < keys[order[t - 1]]:
                ordered = False
                break
        if ordered:
            continue
        if hi - lo > 16:
            part = order[lo:hi].copy()
            sub = np.argsort(keys[part], kind="mergesort")
            for t in range(hi - lo):
                order[lo + t] = part[sub[t]]
            continue
        for t in range(lo + 1, hi):  # insertion sort: a later position moves only past larger keys
            j = order[t]
            key = keys[j]
            s = t - 1
            while s >= lo and keys[order[s]] > key:
                order[s + 1] = order[s]
                s -= 1
            order[s + 1] = j


@njit(cache=True, nogil=True, inline="always")
def _cut_squares(sums, m, x):
    # The chi-square of the plane fitted along the rays from its 10 sums (sum w u u^T's
    # 00 01 02 11 12 22, sum w q u, sum w q^2): ray_fits' ridge of 1e-12 of the trace on
    # the diagonal, the 3 x 3 system solved by elimination (scratch ``m``, ``x``); inf when
    # it is singular (numpy's solve would raise).
    ridge = 1e-12 * ((sums[0] + sums[3]) + sums[5])
    m[0, 0], m[0, 1], m[0, 2] = sums[0] + ridge, sums[1], sums[2]
    m[1, 0], m[1, 1], m[1, 2] = sums[1], sums[3] + ridge, sums[4]
    m[2, 0], m[2, 1], m[2, 2] = sums[2], sums[4], sums[5] + ridge
    x[0], x[1], x[2] = sums[6], sums[7], sums[8]
    if not solve_in_place(m, x):
        return np.inf
    return sums[9] - (sums[6] * x[0] + sums[7] * x[1] + sums[8] * x[2])


@njit(cache=True, nogil=True)
def crease_cut_squares(rows, cols, rays, inverse, weight, sizes, cosines, sines):
    """``(total, orders)`` of the straight lines that cut pixels of the grid (``rows``,
    ``cols``; their :func:`rangeseg_o3d.ray_planes.ray_terms` ``rays``, ``inverse``,
    ``weight``) across each direction ``(cosines[d], sines[d])`` after their ``sizes[b]``
    first pixels (increasing, each in 1..N-1): ``orders[d]`` the pixels' positions ordered by
    ``cols * cosines[d] + rows * sines[d]``, ties in position order (the same positions as
    numpy's stable argsort, :func:`grid_line_order`), and ``total[d, b]`` the chi-squares of
    the two sides' planes fitted along the rays, added (:func:`rangeseg_o3d.ray_planes.ray_fits`,
    inf where a side's system is singular).

    Each side's sums run along the order in one pass (a running sum; the second side is
    every pixel's sums less the first's) and each 3 x 3 system is solved by elimination
    with partial pivoting (:func:`rangeseg_o3d.kernels.linalg.solve_in_place`), not by
    numpy's pairwise blocks and LAPACK: other rounding, a relative difference of about
    1e-12 of the sums (tests/kernels/test_crease_cuts.py)."""
    n = rows.shape[0]
    d_count, b_count = cosines.shape[0], sizes.shape[0]
    terms = np.empty((n, 10))  # each pixel's 10 sums, made as ray_planes.moment_columns makes them
    for j in range(n):
        w, q = weight[j], inverse[j]
        u0, u1, u2 = rays[j, 0], rays[j, 1], rays[j, 2]
        wq = w * q
        terms[j, 0], terms[j, 1], terms[j, 2] = (w * u0) * u0, (w * u0) * u1, (w * u0) * u2
        terms[j, 3], terms[j, 4], terms[j, 5] = (w * u1) * u1, (w * u1) * u2, (w * u2) * u2
        terms[j, 6], terms[j, 7], terms[j, 8], terms[j, 9] = wq * u0, wq * u1, wq * u2, wq * q
    every = np.zeros(10)
    for j in range(n):
        for c in range(10):
            every[c] += terms[j, c]
    total = np.empty((d_count, b_count))
    orders = np.empty((d_count, n), np.int64)
    keys = np.empty(n)
    running = np.empty(10)
    rest = np.empty(10)
    m = np.empty((3, 3))
    x = np.empty(3)
    for d in range(d_count):
        cosine, sine = cosines[d], sines[d]
        for j in range(n):
            keys[j] = cols[j] * cosine + rows[j] * sine
        order = orders[d]
        grid_line_order(keys, order)
        # the running sums in scalars (kept in registers; an array row updated per pixel
        # costs several times the time)
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = s9 = 0.0
        at = 0
        for b in range(b_count):
            for t in range(at, sizes[b]):
                row = terms[order[t]]
                s0, s1, s2, s3, s4 = s0 + row[0], s1 + row[1], s2 + row[2], s3 + row[3], s4 + row[4]
                s5, s6, s7, s8, s9 = s5 + row[5], s6 + row[6], s7 + row[7], s8 + row[8], s9 + row[9]
            at = sizes[b]
            running[0], running[1], running[2], running[3], running[4] = s0, s1, s2, s3, s4
            running[5], running[6], running[7], running[8], running[9] = s5, s6, s7, s8, s9
            for c in range(10):
                rest[c] = every[c] - running[c]
            total[d, b] = _cut_squares(running, m, x) + _cut_squares(rest, m, x)
    return total, orders


@njit(cache=True, nogil=True)
def box_ray_terms(xyz, sigma, valid):
    """``(valid, rays, inverse, weight)`` of the pixels of a box of the grid, row by row
    (``xyz`` (H, W, 3), ``sigma`` and ``valid`` (H, W), views of the frame's): a pixel is valid
    when ``valid`` says so and its point is finite; its terms are
    :func:`rangeseg_o3d.ray_planes.ray_terms`', bit for bit, of its point, or of the point
    (1, 1, 1) where it is not valid (numpy's ``np.where(valid, points, 1.0)``), without the
    box's copies."""
    h, w = valid.shape
    n = h * w
    ok = np.empty(n, np.bool_)
    rays = np.empty((n, 3))
    inverse = np.empty(n)
    weight = np.empty(n)
    for row in range(h):
        for col in range(w):
            i = row * w + col
            x, y, z = xyz[row, col, 0], xyz[row, col, 1], xyz[row, col, 2]
            ok[i] = valid[row, col] and np.isfinite(x) and np.isfinite(y) and np.isfinite(z)
            if not ok[i]:
                x, y, z = 1.0, 1.0, 1.0
            rays[i, 0], rays[i, 1], rays[i, 2], inverse[i], weight[i] = _ray_term(x, y, z, sigma[row, col])
    return ok, rays, inverse, weight
