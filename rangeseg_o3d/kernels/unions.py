"""The merge's pair loop over planes: union-find over label-wise moments, in one compiled pass.

:func:`rangeseg_o3d.refinement.merge.merge_regions` tries its candidate pairs in order,
each union from the parts' summed moments. For pairs of planes every test it makes reads
the moments, the parts' models and (rarely) the parts' summed range noise: no point is
touched, and the loop's cost was Python's, a few tens of calls per pair. Here the same
tests run in the same order on the same values (each union's plane computed alone, as
:func:`.labelwise.planes_from_moment_rows` computes a row), the moments and noise sums
added as parts join.
"""

from __future__ import annotations

import numpy as np

from .jit import njit  # numba.njit, with this package's cache locator installed
from .labelwise import planes_from_moment_rows
from .linalg import CHI_SQUARE_SIGMAS, NOISE_CHI2_SIGMAS, noise_rms_bound

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("grid.py", "inline.py", "kinds.py", "labelwise.py", "linalg.py")

__all__ = ["merge_plane_pairs", "part_within_step", "plane_candidates", "plane_prediction_sd"]

@njit(cache=True, nogil=True)
def _find(root, k):
    while root[k] != k:
        k = root[k]
    return k


@njit(cache=True, nogil=True)
def _plane_of(row):
    # (rms, normal, d, centroid, ok) of the least-squares plane of one moments row
    centroid, normal, d, eigvals, _, ok = planes_from_moment_rows(row.reshape(1, 10))
    return np.sqrt(eigvals[0, 0]), normal[0], d[0], centroid[0], ok[0]


@njit(cache=True, nogil=True)
def _part_rms(moments, rms, k):
    # merge._Unions.part_rms of a plane root: the larger of its model's rms and that of
    # its current pixels' least-squares plane
    return max(rms[k], _plane_of(moments[k])[0])


@njit(cache=True, nogil=True)
def _mean_square_distance(row, normal, d):
    # merge._mean_square_distances of one moments row to the plane ``normal . p = d``
    count = max(row[0], 1.0)
    second = ((row[4], row[5], row[6]), (row[5], row[7], row[8]), (row[6], row[8], row[9]))
    projected = 0.0
    for a in range(3):
        for b in range(3):
            projected += normal[a] * second[a][b] * normal[b]
    along = row[1] * normal[0] + row[2] * normal[1] + row[3] * normal[2]
    return (projected - 2.0 * d * along + count * d * d) / count


@njit(cache=True, nogil=True)
def _angle_deg(u, v):
    dot = abs(u[0] * v[0] + u[1] * v[1] + u[2] * v[2])
    return np.degrees(np.arccos(min(max(dot, 0.0), 1.0)))


@njit(cache=True, nogil=True)
def part_within_step(row, noise_sum, own_rms, big_row, big_rms, normal, d, step_sigmas, min_cosine):
    """Whether a part (moments ``row``, see :func:`.labelwise.label_moments`; its summed
    range noise ``noise_sum``; its model's rms ``own_rms``) lies on the larger part's plane
    ``normal . p = d`` (moments ``big_row``, rms ``big_rms``) on the mean: its centroid's
    offset within ``step_sigmas`` times its samples' scatter (``own_rms``, at least their
    distance noise: the mean range noise times the incidence cosine at the centroid, floored
    at ``min_cosine``) and the plane's uncertainty there (:func:`plane_prediction_sd`), in
    quadrature. True for a part with no points."""
    part = row[0]
    if part <= 0.0:
        return True
    cx, cy, cz = row[1] / part, row[2] / part, row[3] / part
    offset = normal[0] * cx + normal[1] * cy + normal[2] * cz - d
    norm = np.sqrt(cx * cx + cy * cy + cz * cz)
    cosine = abs(offset + d) / norm if norm > 0.0 else 1.0
    noise = max(noise_sum / part * max(cosine, min_cosine), own_rms)
    spread = plane_prediction_sd(big_row, big_rms, normal, cx, cy, cz)
    return abs(offset) <= step_sigmas * np.sqrt(noise * noise + spread * spread)


@njit(cache=True, nogil=True)
def plane_prediction_sd(row, rms, normal, x, y, z):
    """The standard deviation of a least-squares plane's offset at the point ``(x, y, z)``:
    the plane of the points whose moments are ``row`` (see :func:`.labelwise.label_moments`),
    ``normal`` its normal and ``rms`` its rms distance, ``rms sqrt(1/n + h)`` with ``h`` the
    point's leverage across the plane (its offset from the centroid within the plane, in the
    points' spread), at most ``rms``: a plane carried past the points it was fitted to tilts
    with the noise, the more the farther."""
    n = row[0]
    if n < 3.0 or not rms > 0.0:
        return 0.0
    c = np.empty(3)
    c[0], c[1], c[2] = row[1] / n, row[2] / n, row[3] / n
    delta = np.empty(3)
    delta[0], delta[1], delta[2] = x - c[0], y - c[1], z - c[2]
    along = delta[0] * normal[0] + delta[1] * normal[1] + delta[2] * normal[2]
    for a in range(3):
        delta[a] -= along * normal[a]
    scatter = np.empty((3, 3))
    scatter[0, 0] = row[4] - n * c[0] * c[0]
    scatter[0, 1] = scatter[1, 0] = row[5] - n * c[0] * c[1]
    scatter[0, 2] = scatter[2, 0] = row[6] - n * c[0] * c[2]
    scatter[1, 1] = row[7] - n * c[1] * c[1]
    scatter[1, 2] = scatter[2, 1] = row[8] - n * c[1] * c[2]
    scatter[2, 2] = row[9] - n * c[2] * c[2]
    # the plane's own direction filled so the solve sees the in-plane spread alone
    trace = scatter[0, 0] + scatter[1, 1] + scatter[2, 2]
    if not trace > 0.0:
        return rms
    for a in range(3):
        for b in range(3):
            scatter[a, b] += trace * normal[a] * normal[b]
        scatter[a, a] += 1e-12 * trace
    leverage = delta @ np.linalg.solve(scatter, delta)
    return min(rms * np.sqrt(1.0 / n + max(leverage, 0.0)), rms)


@njit(cache=True, nogil=True)
def _noise_by_root(labels, sigma, root, n):
    # each root's summed finite range noise, its pixels added in raster order (as
    # label_noise_sums over the labels mapped to their roots)
    out = np.zeros(n)
    for i in range(labels.shape[0]):
        k = labels[i]
        if k < 0 or k >= n:
            continue
        k = _find(root, k)
        value = sigma[i]
        out[k] += value if value - value == 0.0 else 0.0
    return out


@njit(cache=True, nogil=True)
def merge_plane_pairs(first, second, held, apart, moments, normal, d, rms, count, root, labels, sigma,
                      rms_factor, max_angle_deg, part_sigmas, plane_rms, rms_per_range2, min_points, noise_floor,
                      step_sigmas, min_cosine):
    """merge_regions' loop over its candidate pairs of planes ``(first[i], second[i])``, in
    that order; ``held[i]``: the pair is held (its smaller part must lie on the union's
    plane on the mean; ``part_sigmas``: merge.PART_SIGMAS). Per label (row): ``moments`` (K, 10), the model's ``normal``, ``d``,
    ``rms`` and ``count`` (inliers), ``root`` (union-find parents, labels their own at the
    start); ``labels`` and ``sigma`` the flat label image and range noise (each root's noise
    summed when a union first needs it). The fitter's plane refit from moments takes
    ``plane_rms``, ``rms_per_range2``, ``min_points`` and ``noise_floor``. ``apart[i]``: the
    pair's regions do not touch, and its smaller part must lie on the larger's plane within
    ``step_sigmas`` of its scatter and the larger plane's own spread there
    (merge._Unions.no_step, ``min_cosine`` its floor of the incidence cosine;
    ``step_sigmas <= 0``: no such test).

    Changes the arrays in place: a union's model goes to its root (``rb`` joins ``ra``,
    the pair's roots in its order). Returns a bool per label: its model is a union's.
    """
    n = moments.shape[0]
    joined = np.zeros(n, np.bool_)
    noise = np.zeros(0)
    have_noise = False
    minimum = max(min_points, 3)
    # each root's _part_rms, computed once per root and moments row (the same function of
    # the same row: the same value as computing it at every use)
    part_rms = np.zeros(n)
    known = np.zeros(n, np.bool_)
    for i in range(first.shape[0]):
        ra, rb = _find(root, first[i]), _find(root, second[i])
        if ra == rb:
            continue
        for k in (ra, rb):
            if not known[k]:
                part_rms[k] = _part_rms(moments, rms, k)
                known[k] = True
        row = moments[ra] + moments[rb]
        union_rms, union_normal, union_d, centroid, ok = _plane_of(row)
        # the union's least-squares plane against the merge limit (no refit when over it)
        if union_rms > rms_factor * max(part_rms[ra], part_rms[rb]):
            continue
        # the fitter's refit from the moments (refit_planes_from_moments)
        tolerance = plane_rms
        if noise_floor > 0.0:
            tolerance = max(tolerance, noise_rms_bound(noise_floor, row[0] - 3.0, NOISE_CHI2_SIGMAS))
        tolerance += rms_per_range2 * (centroid[0] * centroid[0] + centroid[1] * centroid[1]
                                       + centroid[2] * centroid[2])
        if row[0] < minimum or not ok or union_rms > tolerance:
            # refused: the least-squares plane when within the larger part's rms and the
            # smaller part lies on it within its own noise (_Unions.plane_within_larger)
            larger, smaller = (ra, rb) if moments[ra, 0] >= moments[rb, 0] else (rb, ra)
            if not ok or union_rms > part_rms[larger]:
                continue
            if not have_noise:
                noise = _noise_by_root(labels, sigma, root, n)
                have_noise = True
            part = moments[smaller, 0]
            bound = noise_rms_bound(noise[smaller] / max(part, 1.0), part - 3.0, NOISE_CHI2_SIGMAS)
            if _mean_square_distance(moments[smaller], union_normal, union_d) > bound * bound:
                continue
        limit = rms_factor * max(rms[ra], rms[rb])
        if not union_rms <= rms_factor * max(part_rms[ra], part_rms[rb]):
            continue
        small = ra if moments[ra, 0] <= moments[rb, 0] else rb
        # the smaller part, turned from the union, on its plane (_Unions.parts_on)
        if not _angle_deg(normal[small], union_normal) <= max_angle_deg:
            reach = part_sigmas * limit
            if not _mean_square_distance(moments[small], union_normal, union_d) <= reach * reach:
                continue
        if held[i]:  # on the union's plane on the mean (_Unions.part_centred)
            part = moments[small, 0]
            if part > 0:
                mean = (moments[small, 1] * union_normal[0] + moments[small, 2] * union_normal[1]
                        + moments[small, 3] * union_normal[2]) / part - union_d
                if not abs(mean) <= CHI_SQUARE_SIGMAS * rms[small] / np.sqrt(part):
                    continue
        if apart[i] and step_sigmas > 0.0:  # no step between the parts apart (_Unions.no_step)
            if not have_noise:
                noise = _noise_by_root(labels, sigma, root, n)
                have_noise = True
            big = rb if small == ra else ra
            if not part_within_step(moments[small], noise[small], rms[small], moments[big], rms[big], normal[big], d[big],
                                step_sigmas, min_cosine):
                continue
        root[rb] = ra
        normal[ra] = union_normal
        d[ra] = union_d
        rms[ra] = union_rms
        count[ra] = row[0]
        joined[ra] = True
        moments[ra] += moments[rb]
        known[ra] = False  # its model and moments changed: its _part_rms is computed anew
        if have_noise:
            noise[ra] += noise[rb]
    return joined


@njit(cache=True, nogil=True)
def _maximum(a, b):
    # np.maximum of two floats (NaN when either is)
    if a != a or b != b:
        return np.nan
    return a if a >= b else b


@njit(cache=True, nogil=True)
def plane_candidates(normals, offsets, rms, rows, noise, adjacent_first, adjacent_second, min_cosine, tolerance,
                     disjoint, with_moments, with_noise, rms_factor):
    """merge_candidates' pairs of planes: ``(first, second)`` row indices (``first < second``,
    in row-major order) of the P planes (``normals`` (P, 3), ``offsets``, ``rms``) that are
    adjacent (``adjacent_first/second``, rows) or, with ``disjoint``, whose parameters agree
    (normals within ``min_cosine``, offsets within ``tolerance``) or, ``with_moments``
    (``rows`` (P, 10), and ``with_noise`` each row's mean range ``noise``), whose smaller
    region's points lie on the other's plane (merge.pieces_on_planes' test)."""
    p = normals.shape[0]
    wanted = np.zeros((p, p), np.bool_)
    if disjoint:
        for i in range(p):
            for j in range(p):
                dot = normals[i, 0] * normals[j, 0] + normals[i, 1] * normals[j, 1] + normals[i, 2] * normals[j, 2]
                sign = 1.0 if dot >= 0 else -1.0
                wanted[i, j] = abs(dot) >= min_cosine and abs(offsets[i] - sign * offsets[j]) <= tolerance
        if with_moments:
            for i in range(p):  # row i: the points of region i against plane j
                count_i = max(rows[i, 0], 1.0)
                floor = 0.0
                if with_noise:
                    floor = noise_rms_bound(noise[i], count_i - 3.0, NOISE_CHI2_SIGMAS)
                for j in range(p):
                    if not count_i <= max(rows[j, 0], 1.0):
                        continue  # only the smaller region's points are weighed
                    limit = rms_factor * max(rms[i], rms[j])
                    limit = limit * limit
                    if with_noise:
                        limit = _maximum(limit, floor * floor)
                    if _mean_square_distance(rows[i], normals[j], offsets[j]) <= limit:
                        wanted[i, j] = True
                        wanted[j, i] = True
    for k in range(adjacent_first.shape[0]):
        wanted[adjacent_first[k], adjacent_second[k]] = True
    count = 0
    for i in range(p):
        for j in range(i + 1, p):
            count += wanted[i, j]
    first = np.empty(count, np.int64)
    second = np.empty(count, np.int64)
    count = 0
    for i in range(p):
        for j in range(i + 1, p):
            if wanted[i, j]:
                first[count], second[count] = i, j
                count += 1
    return first, second
