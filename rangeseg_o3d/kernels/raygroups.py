"""Compiled passes for the faces fitted along the rays: the screen of the tile groups
:func:`rangeseg_o3d.off_model.faces_along_rays` fits (the groups whose robust ray plane
certainly fails its first gates are ruled out in one pass, so that numpy fits only the few
that may stand: a numpy fit per group cost about a millisecond, on groups of which most are a
bend of their owner's surface), and the free pieces :func:`rangeseg_o3d.free_faces.faces_from_free`
grows faces from."""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed
from .growth import _ray_term
from .linalg import noise_rms_bound, solve_in_place

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("growth.py", "inline.py", "kinds.py", "linalg.py")

__all__ = ["ray_groups_ruled_out", "robust_ray_sets", "free_pieces", "tilt_noise", "plane_scores", "pixel_plane_scores"]


@njit(cache=True, nogil=True)
def _ray_terms(xyz, noise, idx, rays, inverse, weight):
    """Each pixel's unit ray, inverse range and inverse-range weight, as
    :func:`rangeseg_o3d.ray_planes.ray_terms` computes them (into the arrays given)."""
    for i in range(idx.shape[0]):
        p = idx[i]
        x, y, z = xyz[p, 0], xyz[p, 1], xyz[p, 2]
        r = max(np.sqrt(x * x + y * y + z * z), 1e-12)
        s = max(noise[p], 1e-12) / (r * r)
        rays[i, 0], rays[i, 1], rays[i, 2] = x / r, y / r, z / r
        inverse[i] = 1.0 / r
        weight[i] = 1.0 / (s * s)


@njit(cache=True, nogil=True)
def _add_terms(sums, row, u, q, w):
    """Add one pixel's 13 moment terms (``w u u^T``, ``w q u``, ``w q^2``) to ``sums[row]``."""
    for a in range(3):
        for b in range(3):
            sums[row, 3 * a + b] += w * u[a] * u[b]
        sums[row, 9 + a] += w * q * u[a]
    sums[row, 12] += w * q * q


@njit(cache=True, nogil=True)
def _terms(out, u, q, w):
    """One pixel's 13 moment terms into ``out``, each rounded as
    :func:`rangeseg_o3d.ray_planes.moment_columns` rounds it (``(w u_a) u_b``, ``(w q) u_a``,
    ``(w q) q``)."""
    for a in range(3):
        for b in range(3):
            out[3 * a + b] = w * u[a] * u[b]
        out[9 + a] = w * q * u[a]
    out[12] = w * q * q


@njit(cache=True, nogil=True)
def _plane_of(moments, a):
    """The plane ``a`` (in place) of the moment row ``moments`` with the ridge of
    :func:`rangeseg_o3d.ray_planes.ray_solutions`; False when the system is singular."""
    m = np.empty((3, 3))
    trace = moments[0] + moments[4] + moments[8]
    for r in range(3):
        for c in range(3):
            m[r, c] = moments[3 * r + c]
        m[r, r] += 1e-12 * trace
        a[r] = moments[9 + r]
    return solve_in_place(m, a)


@njit(cache=True, nogil=True)
def _near(value, threshold, tolerance):
    """Whether ``value`` is within ``tolerance`` (relative) of ``threshold``: a decision that
    numpy's arithmetic, a few roundings apart, might take the other way."""
    return abs(value - threshold) <= tolerance * abs(threshold)


@njit(cache=True, nogil=True)
def _squares(rays, inverse, weight, a, out):
    """Each pixel's squared inverse-range residual to the plane ``a`` in noise units (into ``out``)."""
    for i in range(inverse.shape[0]):
        e = inverse[i] - (rays[i, 0] * a[0] + rays[i, 1] * a[1] + rays[i, 2] * a[2])
        out[i] = weight[i] * e * e


@njit(cache=True, nogil=True)
def _robust_plane(rays, inverse, weight, along, chunks, passes, trim_square, tolerance, a, keep, fitted):
    """:func:`rangeseg_o3d.ray_planes.robust_ray_plane` in compiled arithmetic: ``a`` and
    ``keep`` (in place) and the mean square of the kept pixels; ``(status, mean square)``
    with status 0 for a plane, 1 for none, 2 when a decision on the way (the best set of
    chunks, a pixel within the trim) lies within ``tolerance`` of going the other way.
    ``fitted`` (in place): the pixels ``a`` was last fitted to (``keep`` but after a last
    pass that changed the kept set: the trimmed fit's passes ran out)."""
    n = inverse.shape[0]
    order = np.argsort(along, kind="mergesort")
    chunk = np.empty(n, np.int64)
    for i in range(n):
        chunk[order[i]] = i * chunks // n
    sums = np.zeros((chunks, 13))
    for i in range(n):
        _add_terms(sums, chunk[i], rays[i], inverse[i], weight[i])
    total = np.zeros(13)
    for c in range(chunks):
        total += sums[c]
    squares = np.empty(n)
    best, second = np.inf, np.inf
    best_a = np.zeros(3)
    trial = np.empty(3)
    # every set leaving out none, one or two chunks (left == right: one; -1: none)
    for left in range(-1, chunks):
        for right in range(max(left, 0), chunks) if left >= 0 else range(-1, 0):
            moments = total.copy()
            if left >= 0:
                moments -= sums[left]
                if right != left:
                    moments -= sums[right]
            if not _plane_of(moments, trial):
                return 2, 0.0
            _squares(rays, inverse, weight, trial, squares)
            cost = 0.0
            for i in range(n):
                cost += min(squares[i], trim_square)
            if not np.isfinite(cost):  # (numpy's argmin would pick a NaN)
                return 2, 0.0
            if cost < best:
                best, second = cost, best
                best_a[:] = trial
            elif cost < second:
                second = cost
    if _near(second, best, tolerance):
        return 2, 0.0
    a[:] = best_a
    _squares(rays, inverse, weight, a, squares)
    kept = 0
    for i in range(n):
        if _near(squares[i], trim_square, tolerance):
            return 2, 0.0
        keep[i] = squares[i] <= trim_square
        kept += keep[i]
    if kept == 0:
        return 1, 0.0
    now = np.empty(n, np.bool_)
    sums_keep = np.empty((1, 13))
    for _ in range(passes):
        fitted[:] = keep
        sums_keep[:] = 0.0
        for i in range(n):
            if keep[i]:
                _add_terms(sums_keep, 0, rays[i], inverse[i], weight[i])
        if not _plane_of(sums_keep[0], a):
            return 2, 0.0
        _squares(rays, inverse, weight, a, squares)
        same, any_now = True, False
        for i in range(n):
            if _near(squares[i], trim_square, tolerance):
                return 2, 0.0
            now[i] = squares[i] <= trim_square
            same = same and now[i] == keep[i]
            any_now = any_now or now[i]
        if same or not any_now:
            break
        keep[:] = now
    total_square, kept = 0.0, 0
    for i in range(n):
        if keep[i]:
            total_square += squares[i]
            kept += 1
    return 0, total_square / kept


@njit(cache=True, nogil=True)
def _tilt_turned(rays, inverse, weight, keep, a, facing, max_angle, sigmas, tolerance):
    """:func:`rangeseg_o3d.off_model._tilt_bound` and ``_turned_from`` in compiled arithmetic:
    0 when the plane ``a`` is turned from the unit normal ``facing`` by less than its bound,
    1 when by more, 2 when that is within ``tolerance`` or the fit's sums are ill-conditioned
    (their smallest eigenvalue under 1e-9 of the largest: numpy's inverse may differ)."""
    size = np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    if not np.isfinite(size) or size <= 0.0:
        return 2
    normal = a / size
    outer = np.zeros((3, 3))
    for i in range(inverse.shape[0]):
        if keep[i]:
            for r in range(3):
                for c in range(3):
                    outer[r, c] += weight[i] * rays[i, r] * rays[i, c]
    spreads = np.linalg.eigvalsh(outer)
    if not spreads[0] > 1e-9 * spreads[2]:
        return 2
    covariance = np.linalg.inv(outer)
    across = np.eye(3) - np.outer(normal, normal)
    tilt = np.sqrt(max(np.linalg.eigvalsh(across @ covariance @ across)[2], 0.0)) / size
    bound = max(max_angle, sigmas * tilt)
    cosine = abs(normal[0] * facing[0] + normal[1] * facing[1] + normal[2] * facing[2])
    angle = np.arccos(min(cosine, 1.0))
    if not (np.isfinite(angle) and np.isfinite(bound)) or _near(angle, bound, tolerance):
        return 2
    return 1 if angle > bound else 0


@njit(cache=True, nogil=True)
def ray_groups_ruled_out(xyz, noise, idx, bounds, width, floor, facing, max_angle, sigmas, trim, chunks, passes,
                         tolerance):
    """Per group ``g`` (its flat pixels ``idx[bounds[g]:bounds[g + 1]]``, in the order
    :func:`rangeseg_o3d.off_model.faces_along_rays` takes them; rows of ``width`` pixels):
    True when its plane fitted along the rays (:func:`rangeseg_o3d.ray_planes.robust_ray_plane`,
    ``chunks`` pieces, ``passes`` trims at ``trim`` noises) certainly fails the gates
    ``faces_along_rays`` puts first: fewer than ``max(floor, 3 chunks)`` pixels, no plane,
    at most half the group or fewer than ``floor`` pixels kept, a mean square beyond the
    chi-square bound ``sigmas`` deviations up, or (where ``facing[g]``, the unit normal of the
    plane that owns the group, is finite) turned from it by no more than ``max_angle``
    (radians) and ``sigmas`` noises of its tilt. A decision within ``tolerance`` (relative) of
    going the other way, or taken on ill-conditioned sums, rules nothing out: such a group is
    left to numpy, whose arithmetic decides."""
    groups = bounds.shape[0] - 1
    out = np.zeros(groups, np.bool_)
    trim_square = trim * trim
    for g in range(groups):
        b0, b1 = bounds[g], bounds[g + 1]
        n = b1 - b0
        if n < max(floor, 3 * chunks):
            out[g] = True
            continue
        pixels = idx[b0:b1]
        rays, inverse, weight = np.empty((n, 3)), np.empty(n), np.empty(n)
        _ray_terms(xyz, noise, pixels, rays, inverse, weight)
        rows, cols = pixels // width, pixels % width
        along = cols if cols.max() - cols.min() >= rows.max() - rows.min() else rows
        a, keep = np.zeros(3), np.zeros(n, np.bool_)
        status, mean_square = _robust_plane(rays, inverse, weight, along, chunks, passes, trim_square, tolerance,
                                            a, keep, np.zeros(n, np.bool_))
        if status == 1:
            out[g] = True
        if status != 0:
            continue
        kept = 0
        for i in range(n):
            kept += keep[i]
        if 2 * kept <= n or kept < floor:
            out[g] = True
            continue
        bound = noise_rms_bound(1.0, float(kept), sigmas) ** 2
        if _near(mean_square, bound, tolerance):
            continue
        if mean_square > bound:
            out[g] = True
            continue
        if np.isfinite(facing[g, 0]):
            out[g] = _tilt_turned(rays, inverse, weight, keep, a, facing[g], max_angle, sigmas, tolerance) == 0
    return out


@njit(cache=True, nogil=True)
def robust_ray_sets(rays, inverse, weight, along, chunks, passes, trim, tolerance):
    """The decisions of :func:`rangeseg_o3d.ray_planes.robust_ray_plane` (``chunks`` pieces
    along ``along``, ``passes`` trims at ``trim`` noises) taken in compiled arithmetic, and the
    sums its plane is solved from in numpy's arithmetic, so that its caller solves that plane
    as numpy does: ``(status, keep, sums)``. Status 0: a plane, ``keep`` the pixels it keeps,
    ``sums`` the 13 moment sums (:func:`rangeseg_o3d.ray_planes.moment_columns`) of the pixels
    its last fit took, added row after row as numpy's ``columns[fitted].sum(axis=0)`` adds
    them; 1: no plane; 2: a decision on the way lies within ``tolerance`` (relative) of going
    the other way, or a system is singular: numpy must fit the strip itself. The chosen set of
    chunks and the trims are those of numpy's fit wherever a decision is clear (numpy's own
    solves differ from these in the last bits only)."""
    n = inverse.shape[0]
    a, keep, fitted = np.zeros(3), np.zeros(n, np.bool_), np.zeros(n, np.bool_)
    sums = np.zeros(13)
    for i in range(n):  # (non-finite terms: numpy's NaN comparisons decide, not these)
        if not (np.isfinite(inverse[i]) and np.isfinite(weight[i]) and np.isfinite(rays[i, 0])
                and np.isfinite(rays[i, 1]) and np.isfinite(rays[i, 2])):
            return 2, keep, sums
    status, _ = _robust_plane(rays, inverse, weight, along, chunks, passes, trim * trim, tolerance, a, keep,
                              fitted)
    if status != 0:
        return status, keep, sums
    terms = np.empty(13)
    first = True
    for i in range(n):
        if not fitted[i]:
            continue
        _terms(terms, rays[i], inverse[i], weight[i])
        if first:  # (numpy's sum starts from the first row: a -0.0 stays -0.0)
            sums[:] = terms
            first = False
        else:
            sums += terms
    return 0, keep, sums


@njit(cache=True, nogil=True)
def tilt_noise(rays, weight, keep, a):
    """The noise of the tilt of the plane ``a . p = 1`` fitted along the ``keep`` pixels' ``rays``
    (inverse-range weights ``weight``): the largest standard deviation of its unit normal
    across itself, from the fit's covariance ``(sum w u u^T)^-1`` projected off the normal,
    over ``|a|`` (:func:`rangeseg_o3d.off_model._tilt_bound`). -1.0 when ``a`` is no plane or
    the sums are singular (a zero or non-finite determinant).

    numpy's form (a BLAS product, LAPACK's inverse and ``eigvalsh`` of the projected 3x3
    matrix) rounds differently: here the sums are added pixel after pixel, the inverse is
    the adjugate over the determinant and the largest eigenvalue is that of the 2x2 matrix
    the covariance makes in a basis across the normal (the projected matrix's other
    eigenvalue is its zero along the normal), in closed form."""
    size = np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    if not np.isfinite(size) or size <= 0.0:
        return -1.0
    n0, n1, n2 = a[0] / size, a[1] / size, a[2] / size
    s00 = s01 = s02 = s11 = s12 = s22 = 0.0
    for i in range(weight.shape[0]):
        if keep[i]:
            w, u0, u1, u2 = weight[i], rays[i, 0], rays[i, 1], rays[i, 2]
            s00 += w * u0 * u0
            s01 += w * u0 * u1
            s02 += w * u0 * u2
            s11 += w * u1 * u1
            s12 += w * u1 * u2
            s22 += w * u2 * u2
    # the symmetric inverse: cofactors over the determinant
    c00 = s11 * s22 - s12 * s12
    c01 = s02 * s12 - s01 * s22
    c02 = s01 * s12 - s02 * s11
    det = s00 * c00 + s01 * c01 + s02 * c02
    if not np.isfinite(det) or det == 0.0:
        return -1.0
    c11 = (s00 * s22 - s02 * s02) / det
    c12 = (s01 * s02 - s00 * s12) / det
    c22 = (s00 * s11 - s01 * s01) / det
    c00 /= det
    c01 /= det
    c02 /= det
    # e, f: unit vectors across the normal (e off its smallest component's axis)
    if abs(n0) <= abs(n1) and abs(n0) <= abs(n2):
        e0, e1, e2 = 0.0, n2, -n1
    elif abs(n1) <= abs(n2):
        e0, e1, e2 = -n2, 0.0, n0
    else:
        e0, e1, e2 = n1, -n0, 0.0
    norm = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    e0, e1, e2 = e0 / norm, e1 / norm, e2 / norm
    f0, f1, f2 = n1 * e2 - n2 * e1, n2 * e0 - n0 * e2, n0 * e1 - n1 * e0
    ce0 = c00 * e0 + c01 * e1 + c02 * e2
    ce1 = c01 * e0 + c11 * e1 + c12 * e2
    ce2 = c02 * e0 + c12 * e1 + c22 * e2
    cf0 = c00 * f0 + c01 * f1 + c02 * f2
    cf1 = c01 * f0 + c11 * f1 + c12 * f2
    cf2 = c02 * f0 + c12 * f1 + c22 * f2
    bee = e0 * ce0 + e1 * ce1 + e2 * ce2
    bef = f0 * ce0 + f1 * ce1 + f2 * ce2
    bff = f0 * cf0 + f1 * cf1 + f2 * cf2
    half = 0.5 * (bee - bff)
    largest = 0.5 * (bee + bff) + np.sqrt(half * half + bef * bef)
    if not np.isfinite(largest):
        return -1.0
    return np.sqrt(max(largest, 0.0)) / size


@njit(cache=True, nogil=True, inline="always")
def _score_pixel(u0, u1, u2, q, w, planes, own, bound, counts, totals, owns):
    """Add one pixel (its ray ``u``, inverse range ``q``, weight ``w``) to :func:`plane_scores`'
    sums of every plane that keeps it within ``bound`` (a square in noise units)."""
    r = q - (u0 * own[0] + u1 * own[1] + u2 * own[2])
    mine = w * r * r
    for k in range(planes.shape[0]):
        r = q - (u0 * planes[k, 0] + u1 * planes[k, 1] + u2 * planes[k, 2])
        square = w * r * r
        if square <= bound:
            counts[k] += 1
            totals[k] += square
            owns[k] += mine


@njit(cache=True, nogil=True, inline="always")
def _score_means(counts, totals, owns):
    """:func:`plane_scores`' means from its sums (in place in ``owns``; NaN where a plane keeps none)."""
    means = np.full(counts.shape[0], np.nan)
    for k in range(counts.shape[0]):
        if counts[k] > 0:
            means[k] = totals[k] / counts[k]
            owns[k] = owns[k] / counts[k]
        else:
            owns[k] = np.nan
    return means


@njit(cache=True, nogil=True)
def plane_scores(rays, inverse, weight, keep, planes, own, trim):
    """For each row ``a`` of ``planes`` (m, 3), over the ``keep`` pixels (their ``rays``,
    ``inverse`` ranges and weights ``weight``, :func:`rangeseg_o3d.ray_planes.ray_terms`),
    the squares ``w (q - a . u)^2`` within ``trim`` (noise units): ``(counts, means, owns)``,
    how many there are, the mean of their squares and the mean over them of the squares of
    the plane ``own`` (NaN when none is or ``own`` is not finite). One pass for the tests of
    :func:`rangeseg_o3d.plane_faces.planes_keeping` on every plane at once (numpy takes ~6
    calls a plane; the sums here are added pixel after pixel, numpy's pairwise: the means
    differ in the last bits)."""
    m = planes.shape[0]
    counts, totals, owns = np.zeros(m, np.int64), np.zeros(m), np.zeros(m)
    bound = trim * trim
    for i in range(inverse.shape[0]):
        if keep[i]:
            _score_pixel(rays[i, 0], rays[i, 1], rays[i, 2], inverse[i], weight[i], planes, own, bound, counts,
                         totals, owns)
    return counts, _score_means(counts, totals, owns), owns


@njit(cache=True, nogil=True)
def pixel_plane_scores(xyz, noise, idx, planes, own, trim):
    """:func:`plane_scores` of the flat pixels ``idx`` of the points ``xyz`` (N, 3) and their
    range noise ``noise`` (N,), their ray terms made here as ``ray_terms`` makes them
    (:func:`rangeseg_o3d.kernels.growth._ray_term`, the same bits): no gather, no term arrays."""
    m = planes.shape[0]
    counts, totals, owns = np.zeros(m, np.int64), np.zeros(m), np.zeros(m)
    bound = trim * trim
    for i in range(idx.shape[0]):
        p = idx[i]
        u0, u1, u2, q, w = _ray_term(xyz[p, 0], xyz[p, 1], xyz[p, 2], noise[p])
        _score_pixel(u0, u1, u2, q, w, planes, own, bound, counts, totals, owns)
    return counts, _score_means(counts, totals, owns), owns


@njit(cache=True, nogil=True)
def free_pieces(labels, valid, min_pixels):
    """``(pixels, bounds)``: the 4-connected pieces of free pixels (label 0 and ``valid``) of at
    least ``min_pixels`` pixels, piece ``j``'s flat pixels ``pixels[bounds[j]:bounds[j + 1]]`` in
    raster order, the pieces in the order of their first pixel in raster order (the order of
    ``scipy.ndimage.label``'s numbers): one pass, where labelling the frame and slicing each
    piece's box in numpy cost about 11 ms of a 1280 x 720 frame, most of it for pieces of a
    few pixels."""
    h, w = labels.shape
    n = h * w
    flat, ok = labels.ravel(), valid.ravel()
    # free and not yet in a piece: cleared as the pieces take their pixels
    free = np.empty(n, np.bool_)
    for i in range(n):
        free[i] = flat[i] == 0 and ok[i]
    stack = np.empty(n, np.int32)
    pixels = np.empty(0, np.int64)
    ends = np.empty(16, np.int64)
    pieces, found = 0, 0
    for start in range(n):
        if not free[start]:
            continue
        free[start] = False
        stack[0] = start
        top, size = 1, 0
        # (the stack holds every pixel of the piece once: it is popped only to count it)
        while size < top:
            i = stack[size]
            size += 1
            c = i - (i // w) * w
            for j in (i - w, i + w, i - 1, i + 1):
                if j < 0 or j >= n or (j == i - 1 and c == 0) or (j == i + 1 and c == w - 1):
                    continue
                if free[j]:
                    free[j] = False
                    stack[top] = j
                    top += 1
        if size < min_pixels:
            continue
        if found + size > pixels.size:
            grown = np.empty(max(2 * pixels.size, found + size), np.int64)
            grown[:found] = pixels[:found]
            pixels = grown
        pixels[found:found + size] = np.sort(stack[:size])
        found += size
        if pieces == ends.size:
            longer = np.empty(2 * ends.size, np.int64)
            longer[:pieces] = ends[:pieces]
            ends = longer
        ends[pieces] = found
        pieces += 1
    bounds = np.zeros(pieces + 1, np.int64)
    bounds[1:] = ends[:pieces]
    return pixels[:found], bounds
