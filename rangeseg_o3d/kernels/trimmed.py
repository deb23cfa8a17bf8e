"""The two proposals of the trimmed fit (fitting.robust.trimmed_fit) in one compiled call."""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .kinds import CYLINDER, PLANE, SPHERE
from .linalg import solve

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("kinds.py", "linalg.py")

__all__ = ["trimmed_proposals", "local_proposals", "pool_inliers"]

@njit(cache=True, nogil=True)
def _plane_frame(pts, support):
    # centre and eigenvectors (columns, ascending) of the scatter of pts[support]; the
    # sums in scalars (an array element or slice updated per point costs 4-5x the time),
    # the same additions in the same order, so the same values
    n = 0
    cx, cy, cz = 0.0, 0.0, 0.0
    for i in range(pts.shape[0]):
        if support[i]:
            n += 1
            cx += pts[i, 0]
            cy += pts[i, 1]
            cz += pts[i, 2]
    m = max(n, 1)
    cx, cy, cz = cx / m, cy / m, cz / m
    sxx, sxy, sxz, syy, syz, szz = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    for i in range(pts.shape[0]):
        if support[i]:
            dx, dy, dz = pts[i, 0] - cx, pts[i, 1] - cy, pts[i, 2] - cz
            sxx += dx * dx
            sxy += dx * dy
            sxz += dx * dz
            syy += dy * dy
            syz += dy * dz
            szz += dz * dz
    scatter = np.empty((3, 3))
    scatter[0, 0], scatter[0, 1], scatter[0, 2] = sxx, sxy, sxz
    scatter[1, 0], scatter[1, 1], scatter[1, 2] = sxy, syy, syz  # a product commutes exactly
    scatter[2, 0], scatter[2, 1], scatter[2, 2] = sxz, syz, szz
    c = np.empty(3)
    c[0], c[1], c[2] = cx, cy, cz
    return c, _eigenvectors3(scatter)


#: Jacobi sweeps at most (a 3 x 3 matrix is diagonal to rounding after four or five).
_JACOBI_SWEEPS = 30


@njit(cache=True, nogil=True)
def _eigenvectors3(a):
    """Eigenvectors (columns, eigenvalues ascending) of the symmetric 3 x 3 ``a``, by cyclic
    Jacobi rotations (``a`` is overwritten). A proposal's plane frame takes one per refit, a
    search dozens: LAPACK's eigh costs about 3 us a call from compiled code, the rotations
    a fraction of that. The frame equals eigh's to rounding, up to each vector's sign (the
    proposals' distances do not depend on it: the plane's are absolute, the quadric's
    height field takes every sign of its coordinates)."""
    v = np.eye(3)
    for _ in range(_JACOBI_SWEEPS):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        diag = a[0, 0] * a[0, 0] + a[1, 1] * a[1, 1] + a[2, 2] * a[2, 2]
        if not off > 1e-32 * diag:  # diagonal to rounding (or zero, or NaN)
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            apq = a[p, q]
            if apq == 0.0:
                continue
            theta = (a[q, q] - a[p, p]) / (2.0 * apq)
            t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
            if theta < 0.0:
                t = -t
            c = 1.0 / np.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):  # a <- a J, v <- v J (columns p and q)
                akp, akq = a[k, p], a[k, q]
                a[k, p], a[k, q] = c * akp - s * akq, s * akp + c * akq
                vkp, vkq = v[k, p], v[k, q]
                v[k, p], v[k, q] = c * vkp - s * vkq, s * vkp + c * vkq
            for k in range(3):  # a <- J^T a (rows p and q)
                apk, aqk = a[p, k], a[q, k]
                a[p, k], a[q, k] = c * apk - s * aqk, s * apk + c * aqk
    order = np.argsort(np.array([a[0, 0], a[1, 1], a[2, 2]]))
    out = np.empty((3, 3))
    for j in range(3):
        out[:, j] = v[:, order[j]]
    return out

@njit(cache=True, nogil=True)
def _plane_distances(pts, support, out):
    c, vecs = _plane_frame(pts, support)
    for i in range(pts.shape[0]):
        out[i] = abs((pts[i, 0] - c[0]) * vecs[0, 0] + (pts[i, 1] - c[1]) * vecs[1, 0]
                     + (pts[i, 2] - c[2]) * vecs[2, 0])

@njit(cache=True, nogil=True)
def _quadric_distances(pts, support, out, frame):
    # height along the support's smallest principal axis minus the least-squares
    # h = a u^2 + b uv + c v^2 + d u + e v + f over the other two axes. ``frame`` (n, 3):
    # work space for each point's (h, u, v), computed once and read by the normal equations
    # and the distances alike (the same values as computing them in each pass)
    c, vecs = _plane_frame(pts, support)
    n = pts.shape[0]
    for i in range(n):
        x, y, z = pts[i, 0] - c[0], pts[i, 1] - c[1], pts[i, 2] - c[2]
        frame[i, 0] = x * vecs[0, 0] + y * vecs[1, 0] + z * vecs[2, 0]
        frame[i, 1] = x * vecs[0, 1] + y * vecs[1, 1] + z * vecs[2, 1]
        frame[i, 2] = x * vecs[0, 2] + y * vecs[1, 2] + z * vecs[2, 2]
    # the normal equations' sums in scalars (see _plane_frame), added in the same order
    # as a row-by-row accumulation of row[a] * row[b] (b >= a) and row[a] * h would
    a00 = a01 = a02 = a03 = a04 = a05 = a11 = a12 = a13 = a14 = a15 = 0.0
    a22 = a23 = a24 = a25 = a33 = a34 = a35 = a44 = a45 = a55 = 0.0
    b0 = b1 = b2 = b3 = b4 = b5 = 0.0
    for i in range(n):
        if not support[i]:
            continue
        h, u, v = frame[i, 0], frame[i, 1], frame[i, 2]
        r0, r1, r2 = u * u, u * v, v * v
        b0 += r0 * h
        a00 += r0 * r0
        a01 += r0 * r1
        a02 += r0 * r2
        a03 += r0 * u
        a04 += r0 * v
        a05 += r0 * 1.0
        b1 += r1 * h
        a11 += r1 * r1
        a12 += r1 * r2
        a13 += r1 * u
        a14 += r1 * v
        a15 += r1 * 1.0
        b2 += r2 * h
        a22 += r2 * r2
        a23 += r2 * u
        a24 += r2 * v
        a25 += r2 * 1.0
        b3 += u * h
        a33 += u * u
        a34 += u * v
        a35 += u * 1.0
        b4 += v * h
        a44 += v * v
        a45 += v * 1.0
        b5 += 1.0 * h
        a55 += 1.0 * 1.0
    ata = np.empty((6, 6))
    atb = np.empty(6)
    ata[0, 0], ata[0, 1], ata[0, 2], ata[0, 3], ata[0, 4], ata[0, 5] = a00, a01, a02, a03, a04, a05
    ata[1, 1], ata[1, 2], ata[1, 3], ata[1, 4], ata[1, 5] = a11, a12, a13, a14, a15
    ata[2, 2], ata[2, 3], ata[2, 4], ata[2, 5] = a22, a23, a24, a25
    ata[3, 3], ata[3, 4], ata[3, 5] = a33, a34, a35
    ata[4, 4], ata[4, 5] = a44, a45
    ata[5, 5] = a55
    atb[0], atb[1], atb[2], atb[3], atb[4], atb[5] = b0, b1, b2, b3, b4, b5
    for a in range(6):
        for b in range(a):
            ata[a, b] = ata[b, a]
    coef, ok = solve(ata, atb, 0.0)
    if not ok:
        coef[:] = 0.0
    for i in range(n):
        h, u, v = frame[i, 0], frame[i, 1], frame[i, 2]
        fitted = coef[0] * u * u + coef[1] * u * v + coef[2] * v * v + coef[3] * u + coef[4] * v + coef[5]
        out[i] = abs(h - fitted)


@njit(cache=True, nogil=True)
def _within_spread(dist, support, sigma, cap, out):
    # out = dist <= 3 min(max(sigma, rms of dist over support), cap sigma); out may be support
    ss, m = 0.0, 0
    for p in range(dist.shape[0]):
        if support[p]:
            ss += dist[p] * dist[p]
            m += 1
    limit = 3.0 * min(max(sigma, np.sqrt(ss / max(m, 1))), cap * sigma)
    for p in range(dist.shape[0]):
        out[p] = dist[p] <= limit

# The plane proposal's band is at most this many noise sigmas wide (times 3): a plane's
# points lie within the noise, and a band following the support's own rms widened with
# every point of a crossing surface it took in (in a region holding a whole room, the
# band grew until no plane was left to judge).
_PLANE_SPREAD_CAP = 1.5


@njit(cache=True, nogil=True)
def trimmed_proposals(pts, sigma, rounds, keep, trials, seed):
    """The two proposals of ``fitting.robust.trimmed_fit``: points near its dominant plane and quadric.

    Plane: the best of ``trials`` random three-point planes (most points within
    ``3 sigma``), refitted ``rounds`` times on the points within ``3 max(sigma, rms)``,
    the band capped at ``4.5 sigma``.
    Quadric: a height field refitted ``rounds`` times on the ``keep`` closest points
    (least trimmed squares by concentration steps). Returns two boolean masks of the
    points within ``3 max(sigma, spread)`` of each (all False where a proposal had fewer
    than 6 supporting points).
    """
    n = pts.shape[0]
    np.random.seed(seed)
    tol = 3.0 * sigma
    # the coordinates as three rows: the count below is then one vectorised pass
    columns = np.ascontiguousarray(pts.T)
    xs, ys, zs = columns[0], columns[1], columns[2]
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
            count += abs(nx * xs[p] + ny * ys[p] + nz * zs[p] - d) <= tol
        if count > best_count:
            best_count = count
            best_n[0], best_n[1], best_n[2], best_d = nx, ny, nz, d
    plane_near = np.zeros(n, np.bool_)
    quad_near = np.zeros(n, np.bool_)
    dist = np.empty(n)
    frame = np.empty((n, 3))  # _quadric_distances' work space
    work = np.empty(n)  # kth_smallest's
    support = np.ones(n, np.bool_)
    following = np.empty(n, np.bool_)
    if best_count >= 0:
        for p in range(n):
            support[p] = abs(best_n[0] * pts[p, 0] + best_n[1] * pts[p, 1] + best_n[2] * pts[p, 2]
                             - best_d) <= tol
    # A step that keeps the support as it was has reached the fixed point: the steps left
    # would repeat it.
    settled = False
    for _ in range(rounds):
        if support.sum() < 6:
            break
        _plane_distances(pts, support, dist)
        _within_spread(dist, support, sigma, _PLANE_SPREAD_CAP, following)
        settled = same_mask(following, support)
        if settled:
            break
        support[:] = following
    if settled:
        plane_near[:] = support
    elif support.sum() >= 6:
        _plane_distances(pts, support, dist)
        _within_spread(dist, support, sigma, _PLANE_SPREAD_CAP, plane_near)
    support[:] = True
    settled = False
    for _ in range(rounds):
        _quadric_distances(pts, support, dist, frame)
        # the keep closest: a selection, not a sort (ties at the cut would all be kept)
        cut = kth_smallest(dist, keep - 1, work)
        for p in range(n):
            following[p] = dist[p] <= cut
        settled = same_mask(following, support)
        if settled:
            break
        support[:] = following
    if not settled:
        _quadric_distances(pts, support, dist, frame)
    _within_spread(dist, support, sigma, np.inf, quad_near)
    return plane_near, quad_near


@njit(cache=True, nogil=True)
def kth_smallest(values, k, work):
    """The ``k``-th smallest of ``values`` (0: the smallest), what ``np.partition(values, k)[k]``
    gives (an order statistic is one value however it is found), by quickselect in ``work``
    (as long as ``values``): np.partition copies and selects in numba's generic code, this
    in place about twice as fast. ``values`` without NaN."""
    n = values.shape[0]
    for i in range(n):
        work[i] = values[i]
    lo, hi = 0, n - 1
    while lo < hi:
        # Hoare partition about the median of the first, middle and last
        mid = (lo + hi) >> 1
        a, b, c = work[lo], work[mid], work[hi]
        if a < b:
            pivot = b if b < c else (c if a < c else a)
        else:
            pivot = a if a < c else (c if b < c else b)
        i, j = lo, hi
        while i <= j:
            while work[i] < pivot:
                i += 1
            while work[j] > pivot:
                j -= 1
            if i <= j:
                work[i], work[j] = work[j], work[i]
                i += 1
                j -= 1
        # work[lo..j] <= pivot <= work[i..hi], and any between equal the pivot
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return work[k]
    return work[k]


@njit(cache=True, nogil=True, inline="always")
def same_mask(a, b):
    """Whether the boolean arrays ``a`` and ``b`` (of one length) are equal everywhere."""
    for i in range(a.shape[0]):
        if a[i] != b[i]:
            return False
    return True


@njit(cache=True, nogil=True)
def local_proposals(pts, sigma, rounds, seeds, support_size):
    """Points near a quadric grown from each of ``seeds`` (indices into ``pts``).

    Each start is the ``support_size`` points nearest the seed (one surface, unless the
    seed lies at a crease); the quadratic height field fitted to them is refitted
    ``rounds`` times on the points within ``3 max(sigma, rms)`` of it (the band capped as
    the plane proposal's), so the support spreads over the seed's surface and no
    further. Where a region holds several surfaces of about equal size (a floor and the
    two columns standing on it), the global proposals straddle them; a start on one
    surface does not. Returns a (len(seeds), N) boolean array of the points near each.
    """
    n = pts.shape[0]
    out = np.zeros((seeds.shape[0], n), np.bool_)
    dist = np.empty(n)
    frame = np.empty((n, 3))  # _quadric_distances' work space
    work = np.empty(n)  # kth_smallest's
    support = np.empty(n, np.bool_)
    following = np.empty(n, np.bool_)
    m = min(max(support_size, 6), n)
    for s in range(seeds.shape[0]):
        i = seeds[s]
        for p in range(n):
            dx, dy, dz = pts[p, 0] - pts[i, 0], pts[p, 1] - pts[i, 1], pts[p, 2] - pts[i, 2]
            dist[p] = dx * dx + dy * dy + dz * dz
        cut = kth_smallest(dist, m - 1, work)
        for p in range(n):
            support[p] = dist[p] <= cut
        for _ in range(rounds):
            if support.sum() < 6:
                break
            _quadric_distances(pts, support, dist, frame)
            _within_spread(dist, support, sigma, _PLANE_SPREAD_CAP, following)
            if same_mask(following, support):
                break
            support[:] = following
        if support.sum() >= 6:
            _quadric_distances(pts, support, dist, frame)
            _within_spread(dist, support, sigma, _PLANE_SPREAD_CAP, out[s])
    return out


@njit(cache=True, nogil=True)
def pool_inliers(xyz, pool, kind, prm, tolerance, noise_tolerance):
    """A model's inliers among the points ``xyz[pool]`` (the trimmed fit's count, one pass).

    ``kind`` and ``prm`` as a row of a model table (:mod:`.kinds`). Distances are
    computed as the models' own ``distances`` methods do (the same operations in the same
    order). Returns ``(inliers, n_inliers, n_noise)``: the mask of the pool's points within
    ``tolerance`` of the model, their number, and the number within ``noise_tolerance``.
    A kind without a model has no inliers.
    """
    m = pool.shape[0]
    inliers = np.zeros(m, np.bool_)
    n_inliers, n_noise = 0, 0
    for i in range(m):
        p = pool[i]
        x, y, z = xyz[p, 0], xyz[p, 1], xyz[p, 2]
        if kind == PLANE:
            dist = abs((x * prm[0] + y * prm[1] + z * prm[2]) - prm[3])
        elif kind == SPHERE:
            dx, dy, dz = x - prm[0], y - prm[1], z - prm[2]
            dist = abs(np.sqrt(dx * dx + dy * dy + dz * dz) - prm[3])
        elif kind == CYLINDER:
            rx, ry, rz = x - prm[3], y - prm[4], z - prm[5]
            along = rx * prm[0] + ry * prm[1] + rz * prm[2]
            qx, qy, qz = rx - along * prm[0], ry - along * prm[1], rz - along * prm[2]
            dist = abs(np.sqrt(qx * qx + qy * qy + qz * qz) - prm[6])
        else:
            continue
        if dist <= tolerance:
            inliers[i] = True
            n_inliers += 1
        if dist <= noise_tolerance:
            n_noise += 1
    return inliers, n_inliers, n_noise
