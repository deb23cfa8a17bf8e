"""Label-wise sums over a label image: moments and planes, quadric normal equations, distances to models."""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .grid import group_by_label
from .inline import NO_MOMENTS, _add_moments, _distance, _distance_noise
from .kinds import PARAM_SLOTS, PLANE
from .linalg import (NOISE_CHI2_SIGMAS, collinear, flat_by_quadric, hesse_form, noise_rms_bound, plane_tolerance,
                     quadric_resolved, solve)

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("grid.py", "inline.py", "kinds.py", "linalg.py")

__all__ = ["label_moments", "member_moments", "label_noise_sums", "member_centres", "planes_from_moment_rows", "plane_refit_rows", "quadric_sums", "quadric_shapes", "height_field_shape",
           "settle_planes", "count_inliers", "distance_stats", "within_plane_noise", "planes_may_hold_half", "rows_with_any",
           "piece_votes", "nearer_models", "voted_columns", "claim_parts"]

N_MOMENTS = 10  # count, sx, sy, sz, sxx, sxy, sxz, syy, syz, szz

@njit(cache=True, nogil=True)
def label_moments(xyz, labels, n):
    """(n, 10) moments per label: count, sums of x, y, z and of xx, xy, xz, yy, yz, zz.

    ``xyz`` is (N, 3), ``labels`` (N,); labels outside 1..n-1 and non-finite points are
    skipped. Sums are about the coordinate origin: in float64 the variance recovered from
    them keeps about 6 significant digits for millimetre noise at 100 m, far below what a
    threshold test needs.
    """
    return member_moments(xyz, labels, np.ones(n, np.bool_))


@njit(cache=True, nogil=True)
def member_moments(xyz, labels, members):
    """:func:`label_moments` of the labels ``k`` with ``members[k]`` (``n = len(members)``),
    zero rows for the others: each member's row is label_moments' to the bit (its pixels
    added in the same order), the other labels' pixels are only read (a refit of a few
    regions of a scan costs their pixels' sums, not the whole grid's)."""
    n = members.shape[0]
    out = np.zeros((n, N_MOMENTS))
    # Labels come in runs along the rows: a run's sums stay in registers (loaded from the
    # label's row when the run starts, stored when it ends: the same additions in the same
    # order), where a store and reload per pixel would chain each pixel to the last; a
    # run's membership is looked up once.
    last = -1
    seen, inside = -1, False
    sums = NO_MOMENTS
    for i in range(labels.shape[0]):
        k = labels[i]
        if k != seen:
            seen = k
            inside = 0 < k < n and members[k]
        if not inside:
            continue
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        if k != last:
            if last > 0:
                _store_moments(out[last], sums)
            o = out[k]
            sums = (o[0], o[1], o[2], o[3], o[4], o[5], o[6], o[7], o[8], o[9])
            last = k
        sums = _add_moments(sums, x, y, z)
    if last > 0:
        _store_moments(out[last], sums)
    return out


@njit(cache=True, nogil=True, inline="always")
def _store_moments(row, sums):
    for k in range(N_MOMENTS):
        row[k] = sums[k]


@njit(cache=True, nogil=True)
def label_noise_sums(labels, sigma, n):
    """(n,) per label ``0..n-1`` the sum of the finite ``sigma`` of its pixels (``labels``,
    ``sigma`` flat), added in pixel order: ``np.bincount(labels, weights=np.where(
    np.isfinite(sigma), sigma, 0.0), minlength=n)[:n]`` to the bit, without its whole-grid
    temporaries (the weights, the labels widened to 64 bits). Labels outside ``0..n-1``
    are skipped."""
    out = np.zeros(n)
    for i in range(labels.shape[0]):
        k = labels[i]
        if k < 0 or k >= n:
            continue
        value = sigma[i]
        out[k] += value if value - value == 0.0 else 0.0  # (non-finite: 0, as np.where gives)
    return out


@njit(cache=True, nogil=True)
def member_centres(xyz, labels, members):
    """(len(members), 4): each member label's pixel count and the sums of its x, y and z.

    Every pixel of a label with ``members[label]`` counts, in raster order and with no
    finiteness test: the same additions, in the same order, as summing the label's rows of
    ``xyz`` gathered at its increasing pixel indices (a NaN point makes its sums NaN).
    """
    out = np.zeros((members.shape[0], 4))
    for i in range(labels.shape[0]):
        k = labels[i]
        if k <= 0 or k >= members.shape[0] or not members[k]:
            continue
        row = out[k]
        row[0] += 1.0
        row[1] += xyz[i, 0]
        row[2] += xyz[i, 1]
        row[3] += xyz[i, 2]
    return out

@njit(cache=True, nogil=True)
def planes_from_moment_rows(moments):
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
        scale = max(abs(c[0]), abs(c[1]), abs(c[2])) + np.sqrt(vals[0] + vals[1] + vals[2])
        nrm, dist = hesse_form(nrm, nrm @ c, max(scale, 1e-300))
        normal[i] = nrm
        frame[i, 0] = nrm
        d[i] = dist
        ok[i] = n >= 3 and not collinear(vals)
    return centroid, normal, d, eigvals, frame, ok

@njit(cache=True, nogil=True)
def plane_refit_rows(moments, plane_rms, noise_floor, rms_per_range2):
    """The least-squares plane of each row of (K, 10) moments with the fitter's rms
    threshold for it (``classify.refit_planes_from_moments``): :func:`planes_from_moment_rows`
    and, per row, :func:`.linalg.plane_tolerance` over its count plus ``rms_per_range2``
    times the centroid's squared norm (summed x, y, z, as numpy sums a row).

    Returns ``(normal (K, 3), d (K,), rms (K,), tolerance (K,), ok (K,))``.
    """
    centroid, normal, d, eigvals, _, ok = planes_from_moment_rows(moments)
    k = moments.shape[0]
    rms = np.empty(k)
    tolerance = np.empty(k)
    for i in range(k):
        rms[i] = np.sqrt(eigvals[i, 0])
        c = centroid[i]
        tolerance[i] = (plane_tolerance(plane_rms, noise_floor, moments[i, 0])
                        + rms_per_range2 * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]))
    return normal, d, rms, tolerance, ok

@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _height_field_sums(u, v, h, m, out):
    # The 28 sums of quadric_sums over the first m entries: 15 distinct monomials u^i v^j
    # (i + j <= 4) fill the 21 of A^T A. Reassociation lets the compiler vectorise.
    s0 = su = sv = suu = suv = svv = suuu = suuv = suvv = svvv = 0.0
    suuuu = suuuv = suuvv = suvvv = svvvv = 0.0
    sh = shu = shv = shuu = shuv = shvv = shh = 0.0
    for p in range(m):
        up, vp, hp = u[p], v[p], h[p]
        uu, uv, vv = up * up, up * vp, vp * vp
        s0 += 1.0
        su += up
        sv += vp
        suu += uu
        suv += uv
        svv += vv
        suuu += uu * up
        suuv += uu * vp
        suvv += up * vv
        svvv += vv * vp
        suuuu += uu * uu
        suuuv += uu * uv
        suuvv += uu * vv
        suvvv += uv * vv
        svvvv += vv * vv
        sh += hp
        shu += hp * up
        shv += hp * vp
        shuu += hp * uu
        shuv += hp * uv
        shvv += hp * vv
        shh += hp * hp
    # rows (u^2, uv, v^2, u, v, 1): upper triangle of A^T A row by row, A^T h, h^T h
    out[0], out[1], out[2], out[3], out[4], out[5] = suuuu, suuuv, suuvv, suuu, suuv, suu
    out[6], out[7], out[8], out[9], out[10] = suuvv, suvvv, suuv, suvv, suv
    out[11], out[12], out[13], out[14] = svvvv, suvv, svvv, svv
    out[15], out[16], out[17] = suu, suv, su
    out[18], out[19] = svv, sv
    out[20] = s0
    out[21], out[22], out[23], out[24], out[25], out[26] = shuu, shuv, shvv, shu, shv, sh
    out[27] = shh


@njit(cache=True, nogil=True)
def quadric_sums(xyz, labels, centre, e1, e2, normal, inv_spread, active):
    """Normal equations of the height field ``h = a u^2 + b uv + c v^2 + d u + e v + f`` per label.

    ``u, v`` are in-plane coordinates (frame ``e1, e2`` about ``centre``, scaled by
    ``inv_spread``) and ``h`` the height along ``normal``. Returns (n, 28): the 21 upper
    triangle entries of ``A^T A`` (row-major), the 6 of ``A^T h`` and ``h^T h``. Only
    labels with ``active[k]`` are summed; non-finite points are skipped.
    """
    n = centre.shape[0]
    out = np.zeros((n, 28))
    order, starts = group_by_label(labels, n)
    largest = 0
    for k in range(1, n):
        largest = max(largest, starts[k + 1] - starts[k])
    u, v, h = np.empty(largest), np.empty(largest), np.empty(largest)
    for k in range(1, n):
        if not active[k]:
            continue
        cx, cy, cz = centre[k, 0], centre[k, 1], centre[k, 2]
        s = inv_spread[k]
        a1, a2, a3 = e1[k, 0] * s, e1[k, 1] * s, e1[k, 2] * s
        b1, b2, b3 = e2[k, 0] * s, e2[k, 1] * s, e2[k, 2] * s
        n1, n2, n3 = normal[k, 0], normal[k, 1], normal[k, 2]
        m = np.intp(0)  # not a literal 0: see settle_planes
        for p in range(starts[k], starts[k + 1]):
            i = order[p]
            rx, ry, rz = xyz[i, 0] - cx, xyz[i, 1] - cy, xyz[i, 2] - cz
            if not (np.isfinite(rx) and np.isfinite(ry) and np.isfinite(rz)):
                continue
            u[m] = rx * a1 + ry * a2 + rz * a3
            v[m] = rx * b1 + ry * b2 + rz * b3
            h[m] = rx * n1 + ry * n2 + rz * n3
            m += 1
        _height_field_sums(u, v, h, m, out[k])
    return out

@njit(cache=True, nogil=True)
def quadric_shapes(sums, counts, active):
    """``(gain, roundness)`` per row of :func:`quadric_sums` output (see ``batch_planes.quadric_gains``).

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
        coef, ok = solve(ata, atb, 1e-12)
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
    # a run of one label sums in registers (as label_moments: the same additions in order)
    last, taken, total, near = -1, 0, 0.0, 0
    for i in range(labels.shape[0]):
        k = labels[i]
        if k <= 0 or k >= n or kinds[k] == 0:
            continue
        dist = _distance(kinds[k], params[k], xyz[i, 0], xyz[i, 1], xyz[i, 2])
        if not np.isfinite(dist):
            continue
        if k != last:
            if last > 0:
                counts[last], squares[last], inliers[last] = taken, total, near
            last, taken, total, near = k, counts[k], squares[k], inliers[k]
        taken += 1
        total += dist * dist
        if dist <= factor * max(sigma[i], rms[k]):
            near += 1
    if last > 0:
        counts[last], squares[last], inliers[last] = taken, total, near
    return inliers, squares, counts

@njit(cache=True, nogil=True)
def height_field_shape(centred, normal, e1, e2):
    """``(gain, roundness)`` of one set of centred points: :func:`quadric_shapes` of the
    height field over the plane through their centroid with ``normal`` and in-plane unit
    axes ``e1, e2``."""
    n = centred.shape[0]
    squares = 0.0
    for i in range(n):
        u = centred[i, 0] * e1[0] + centred[i, 1] * e1[1] + centred[i, 2] * e1[2]
        v = centred[i, 0] * e2[0] + centred[i, 1] * e2[1] + centred[i, 2] * e2[2]
        squares += u * u + v * v
    spread = np.sqrt(squares / max(n, 1))
    # unit spread keeps the 6x6 normal equations well conditioned
    inv_spread = np.array([1.0, 1.0 / spread if spread > 0 else 1.0])
    frame = np.zeros((3, 2, 3))
    frame[0, 1], frame[1, 1], frame[2, 1] = e1, e2, normal
    active = np.array([False, True])
    # int32 labels, as settle_planes': one compiled group_by_label
    sums = quadric_sums(centred, np.ones(n, np.int32), np.zeros((2, 3)), frame[0], frame[1], frame[2],
                        inv_spread, active)
    gain, roundness = quadric_shapes(sums, np.array([0.0, float(n)]), active)
    return gain[1], roundness[1]

@njit(cache=True, nogil=True)
def _labelled_only(xyz, labels, count):
    # the ``count`` points and labels of the labelled pixels, in pixel order
    points = np.empty((count, 3))
    kept = np.empty(count, labels.dtype)
    m = 0
    for i in range(labels.shape[0]):
        if labels[i] > 0:
            points[m] = xyz[i]
            kept[m] = labels[i]
            m += 1
    return points, kept

@njit(cache=True, nogil=True)
def settle_planes(xyz, labels, n, plane_rms, rms_per_range2, min_points, curvature_gain, inlier_factor,
                  noise_floor=0.0, bends=0.0):
    """The batched plane test of ``classify.fit_planes_batch`` in one call.

    Per label ``1..n-1``: the plane from its moments, accepted when it is determined, has
    at least ``min_points`` points, an rms within ``max(plane_rms, noise_floor) +
    rms_per_range2 |centroid|^2`` (a plane over that, within the chi-square spread of
    :func:`.linalg.plane_tolerance`, is left to the full decision)
    and no significant curvature (quadric gain below ``curvature_gain`` by
    :func:`.linalg.flat_by_quadric`; not tested when
    the rms is under a tenth of the threshold). With ``bends`` (the independent samples
    each point carries, > 0) a plane within the noise whose quadric resolves a bend over its
    points' samples (:func:`.linalg.quadric_resolved`) is not settled either, nor is a plane
    beyond what ``noise_floor`` gives its points' samples up their chi-square
    (``NOISE_CHI2_SIGMAS``: the decision's marginal plane). Returns ``(settled, normal, d,
    rms, inliers)``, the inliers counted within ``inlier_factor`` times the threshold.
    """
    # np.intp, not a literal 0: while numba's type inference settles, a variable seen only as
    # the literal 0 so far compiles the call below once more for that literal type
    labelled = np.intp(0)
    for i in range(labels.shape[0]):
        if labels[i] > 0:
            labelled += 1
    if 2 * labelled < labels.shape[0]:
        # a few blobs in a large image: the passes below over the labelled pixels alone
        # give the same sums, in the same order
        xyz, labels = _labelled_only(xyz, labels, labelled)
    moments = label_moments(xyz, labels, n)
    centroid, normal, d, eigvals, frame, ok = planes_from_moment_rows(moments)
    rms = np.sqrt(np.maximum(eigvals[:, 0], 0.0))
    tolerance = np.empty(n)
    candidate = np.zeros(n, np.bool_)
    active = np.zeros(n, np.bool_)
    inv_spread = np.ones(n)
    for k in range(1, n):
        extra = rms_per_range2 * (centroid[k] @ centroid[k])
        tolerance[k] = plane_tolerance(plane_rms, noise_floor, moments[k, 0]) + extra
        # a plane over the noise itself, within its chi-square spread only, is left to the
        # full decision (which tries the curved models against it)
        candidate[k] = (ok[k] and moments[k, 0] >= max(min_points, 3)
                        and rms[k] <= min(tolerance[k], max(plane_rms, noise_floor) + extra))
        # with bends (a region's final pixels) so is a plane within a threshold over the noise
        # (a preset's plane_rms over a quiet sensor's noise) yet beyond what that noise gives
        # its independent samples up their chi-square: the decision calls it marginal too and
        # tries the curved models against it (fitting._decide.primitive_decision). Points whose
        # noise errs together (bends < 1) spread their rms as fewer samples do
        if (candidate[k] and bends > 0.0 and noise_floor > 0.0
                and rms[k] > noise_rms_bound(noise_floor + extra, moments[k, 0] * min(bends, 1.0) - 3.0,
                                             NOISE_CHI2_SIGMAS)):
            candidate[k] = False
        # The floor keeps rounding-level residuals of exact planes from looking "curved".
        active[k] = candidate[k] and rms[k] > 0.1 * tolerance[k]
        spread = np.sqrt(eigvals[k, 1] + eigvals[k, 2])
        if spread > 0:
            inv_spread[k] = 1.0 / spread
    tolerance[0] = 0.0
    sums = quadric_sums(xyz, labels, centroid, frame[:, 1].copy(), frame[:, 2].copy(), normal, inv_spread,
                        active)
    gain, _ = quadric_shapes(sums, moments[:, 0].copy(), active)
    settled = np.zeros(n, np.bool_)
    for k in range(n):
        # the quadric's gain is uncertain only where the plane's rms is the noise's
        noise = noise_floor + rms_per_range2 * (centroid[k] @ centroid[k])
        within = rms[k] <= noise
        spread_points = moments[k, 0] if within else np.inf
        settled[k] = candidate[k] and flat_by_quadric(gain[k], curvature_gain, spread_points)
        if (settled[k] and not within and 0.0 < bends < 1.0 and noise_floor > 0.0
                and rms[k] <= noise_rms_bound(noise, moments[k, 0] - 3.0, NOISE_CHI2_SIGMAS)):
            # as the decision (fitting._decide.primitive_decision): where the points' noise
            # errs together (under one independent sample each) an rms that noise gives
            # them up its chi-square is noise too, and the bend test counts their samples
            spread_points = moments[k, 0]
        if settled[k] and bends > 0.0 and quadric_resolved(gain[k], spread_points * bends):
            settled[k] = False
    kinds = np.zeros(n, np.int8)
    params = np.zeros((n, PARAM_SLOTS))
    for k in range(n):
        if settled[k]:
            kinds[k] = PLANE
            params[k, :3] = normal[k]
            params[k, 3] = d[k]
    inliers = distance_stats(xyz, labels, kinds, params, inlier_factor * tolerance, np.zeros(xyz.shape[0]),
                             1.0)[0]
    return settled, normal, d, rms, inliers


@njit(cache=True, nogil=True)
def within_plane_noise(points, sigma, normals, offsets, rms, k_sigma):
    """(N, P) whether each point lies within ``k_sigma`` noises of each plane ``(normals[j],
    offsets[j])``: the noise of its distance is the range noise ``sigma`` times the incidence
    cosine, or the plane's ``rms`` when larger.

    One pass without the (N, P) temporaries of the numpy expression; the same operations in
    the same order (the dot product summed x, y, z; the norm as ``sqrt(x*x + y*y + z*z)``),
    so the answer is numpy's to the bit.
    """
    n, p = points.shape[0], normals.shape[0]
    out = np.empty((n, p), np.bool_)
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        norm = max(np.sqrt(x * x + y * y + z * z), 1e-12)
        for j in range(p):
            along = x * normals[j, 0] + y * normals[j, 1] + z * normals[j, 2]
            noise = max(sigma[i] * (abs(along) / norm), rms[j])
            out[i, j] = abs(along - offsets[j]) <= k_sigma * noise
    return out


@njit(cache=True, nogil=True)
def planes_may_hold_half(xyz, sigma, idx, normals, offsets, scatter, limit, slack):
    """Per plane ``j`` (rows of ``normals``, ``offsets``, ``scatter``): whether at least
    ``ceil(n / 2)`` of the n pixels ``idx`` (rows of the flat ``xyz`` and ``sigma``) lie within
    ``limit * max(sigma, scatter[j])`` of it, that bound widened by ``slack`` of itself and
    of the terms of the distance (``|x nx| + |y ny| + |z nz| + |d|``): far above the rounding
    of any way of computing it.

    A necessary test for the median of the pixels' noise-scaled distances to be within
    ``limit`` (fewer values within it put the median over it, whatever rounding the numpy
    form's matrix product made): False only where that median is certainly over it. One
    pass per plane that stops at the half, without gathering the points or a (pixels x
    planes) array.
    """
    n, p = idx.shape[0], normals.shape[0]
    need = (n + 1) // 2
    out = np.zeros(p, np.bool_)
    for j in range(p):
        hits = 0
        if need == 0:  # no pixel: no median to refuse (numpy's count test passes too)
            out[j] = True
            continue
        for i in range(n):
            q = idx[i]
            tx, ty, tz = xyz[q, 0] * normals[j, 0], xyz[q, 1] * normals[j, 1], xyz[q, 2] * normals[j, 2]
            along = tx + ty + tz
            terms = abs(tx) + abs(ty) + abs(tz) + abs(offsets[j])
            reach = limit * max(sigma[q], scatter[j]) * (1.0 + slack) + slack * terms
            if abs(along - offsets[j]) <= reach:
                hits += 1
                if hits >= need:
                    out[j] = True
                    break
    return out


@njit(cache=True, nogil=True)
def rows_with_any(within):
    """Indices (increasing) of the rows of the (N, P) bool ``within`` with a True:
    ``np.flatnonzero(within.any(axis=1))`` in one pass that stops at a row's first True."""
    n, p = within.shape
    out = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        for j in range(p):
            if within[i, j]:
                out[m] = i
                m += 1
                break
    return out[:m]


@njit(cache=True, nogil=True)
def piece_votes(ids, within, n_pieces):
    """(n_pieces, P) int64: for each piece number of ``ids`` (one per row of the (N, P) bool
    ``within``), how many of its rows have each column True (the bincount of
    ``ids[row] * P + column`` over ``within``'s True entries, without their index arrays)."""
    p = within.shape[1]
    votes = np.zeros((n_pieces, p), np.int64)
    for i in range(within.shape[0]):
        for j in range(p):
            if within[i, j]:
                votes[ids[i], j] += 1
    return votes


@njit(cache=True, nogil=True)
def nearer_models(points, sigma, owner, kinds, params, margin):
    """``(owner, moved)``: ``owner`` (a row of the model table ``kinds, params`` per point) with
    each point given to the model nearest it (the first of equals) when that is nearer than
    its owner by more than ``margin`` times the noise of its distance to its owner (its range
    noise ``sigma`` times the incidence cosine of its ray on the owner's surface, with the
    sagitta term on a curved owner: fitting.robust.distance_noise), and how
    many moved. One pass over the points and models, no (models x points) distances."""
    out = owner.copy()
    moved = 0
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        best, best_distance = 0, np.inf
        for j in range(kinds.shape[0]):
            d = _distance(kinds[j], params[j], x, y, z)
            if d < best_distance:
                best, best_distance = j, d
        own = owner[i]
        if best == own:
            continue
        noise = _distance_noise(kinds[own], params[own], x, y, z, sigma[i])
        if _distance(kinds[own], params[own], x, y, z) - best_distance - margin * noise > 0.0:
            out[i] = best
            moved += 1
    return out, moved


@njit(cache=True, nogil=True)
def voted_columns(ids, within, n_pieces):
    """For each row of the (N, P) bool ``within``: the column most rows of its piece
    (``ids``, numbers below ``n_pieces``) have True (the first of equal counts, as
    ``np.argmax`` of :func:`piece_votes`' rows), and whether the row itself has it True.
    Returns ``(member, column)``."""
    votes = piece_votes(ids, within, n_pieces)
    best = np.zeros(n_pieces, np.int64)
    for k in range(n_pieces):
        for j in range(1, votes.shape[1]):
            if votes[k, j] > votes[k, best[k]]:
                best[k] = j
    n = ids.shape[0]
    member = np.empty(n, np.bool_)
    column = np.empty(n, np.int64)
    for i in range(n):
        column[i] = best[ids[i]]
        member[i] = within[i, column[i]]
    return member, column


@njit(cache=True, nogil=True)
def claim_parts(labels, width, xyz, sigma, pixels, columns, parts, sizes, normals, offsets, plane_rms,
                plane_labels, column_of, min_size, apart, sigmas):
    """One claim of connected parts of free pixels by planes (``refinement.recover``'s
    claim round after the vote), in one pass; returns whether a pixel was claimed.

    ``pixels`` (flat, increasing) each lie within the noise of the plane of column
    ``columns[i]`` (rows of ``normals``, ``offsets``, ``plane_rms``; region label
    ``plane_labels[j]``) and form the 4-connected parts ``parts`` of ``sizes`` pixels. A
    part is claimed when its rms distance to its pixels' planes is within the chi-square
    bound (``sigmas``, :func:`.linalg.noise_rms_bound`) of the rms of their distance noise
    (range noise ``sigma`` times the incidence cosine, or the plane's rms when larger)
    and it has ``min_size`` pixels (with ``apart``) or a pixel whose 4-neighbour on the
    grid is in the region of its own plane (``column_of[label]``, -1 or beyond it: no
    plane). Its pixels then take their plane's label in ``labels`` (flat int, in place;
    every test reads the labels as they were). The sums run in the pixels' order, the
    arithmetic as numpy's per-pixel expressions: the same answer to the bit.
    """
    n_parts = sizes.shape[0]
    squares = np.zeros(n_parts)
    noise_squares = np.zeros(n_parts)
    touches = np.zeros(n_parts, np.bool_)
    n = labels.shape[0]
    height = n // width
    for i in range(pixels.shape[0]):
        p, j, k = pixels[i], columns[i], parts[i]
        x, y, z = xyz[p, 0], xyz[p, 1], xyz[p, 2]
        along = x * normals[j, 0] + y * normals[j, 1] + z * normals[j, 2]
        norm = max(np.sqrt(x * x + y * y + z * z), 1e-12)
        noise = max(sigma[p] * (abs(along) / norm), plane_rms[j])
        distance = along - offsets[j]
        squares[k] += distance * distance
        noise_squares[k] += noise * noise
        if not touches[k]:
            row, col = p // width, p % width
            for step in range(4):
                if step == 0:
                    other = p - width if row > 0 else -1
                elif step == 1:
                    other = p + width if row < height - 1 else -1
                elif step == 2:
                    other = p - 1 if col > 0 else -1
                else:
                    other = p + 1 if col < width - 1 else -1
                if other >= 0:
                    label = labels[other]
                    if 0 <= label < column_of.shape[0] and column_of[label] == j:
                        touches[k] = True
    kept = np.zeros(n_parts, np.bool_)
    claimed = False
    for k in range(n_parts):
        count = float(max(sizes[k], 1))
        bound = noise_rms_bound(np.sqrt(noise_squares[k] / count), count, sigmas)
        kept[k] = ((sizes[k] >= min_size and apart) or touches[k]) and np.sqrt(squares[k] / count) <= bound
        claimed |= kept[k]
    if claimed:
        for i in range(pixels.shape[0]):
            if kept[parts[i]]:
                labels[pixels[i]] = plane_labels[columns[i]]
    return claimed
