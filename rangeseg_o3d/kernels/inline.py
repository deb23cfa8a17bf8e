"""Inline helpers shared by the kernels: model distances and 4-neighbours on a flat grid."""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .kinds import CYLINDER, PLANE, SPHERE

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("kinds.py",)


#: The ten moment sums a point adds to, in this order: count, x, y, z, xx, xy, xz, yy, yz, zz.
NO_MOMENTS = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit(cache=True, nogil=True, inline="always")
def _add_moments(m, x, y, z):
    # The ten sums ``m`` (ordered as NO_MOMENTS) with the point (x, y, z) added: a tuple of
    # scalars, so a kernel's running sums stay in registers (an array row updated per point
    # costs several times the time); the same additions in the same order wherever it is used.
    return (m[0] + 1.0, m[1] + x, m[2] + y, m[3] + z, m[4] + x * x, m[5] + x * y, m[6] + x * z,
            m[7] + y * y, m[8] + y * z, m[9] + z * z)


@njit(cache=True, nogil=True, inline="always")
def _add_ray_terms(outer, first, wi, wq, u0, u1, u2):
    # A point's terms of the sums of a plane fitted along the rays added in place to ``outer``
    # (3 x 3, sum w u u^T) and ``first`` (3, sum w q u): its weight ``wi``, ``wq = wi q`` and
    # unit ray (u0, u1, u2), numpy's products ``(w u_a) u_b`` and ``(w q) u_a``; the same bits
    # wherever it is used (kernels.rays' sums, kernels.growth.refit_terms).
    wa = wi * u0
    outer[0, 0] += wa * u0
    outer[0, 1] += wa * u1
    outer[0, 2] += wa * u2
    wa = wi * u1
    outer[1, 0] += wa * u0
    outer[1, 1] += wa * u1
    outer[1, 2] += wa * u2
    wa = wi * u2
    outer[2, 0] += wa * u0
    outer[2, 1] += wa * u1
    outer[2, 2] += wa * u2
    first[0] += wq * u0
    first[1] += wq * u1
    first[2] += wq * u2


@njit(cache=True, nogil=True, inline="always")
def _distance(kind, prm, x, y, z):
    # Absolute orthogonal distance of (x, y, z) from the model (a row of a model table, see
    # kinds.py); inf for "no model".
    return abs(_signed_distance(kind, prm, x, y, z))


@njit(cache=True, nogil=True, inline="always")
def _signed_distance(kind, prm, x, y, z):
    # Signed orthogonal distance of (x, y, z) from the model: along a plane's normal, out of
    # a sphere or cylinder positive; inf for "no model".
    if kind == PLANE:
        return prm[0] * x + prm[1] * y + prm[2] * z - prm[3]
    if kind == SPHERE:
        dx, dy, dz = x - prm[0], y - prm[1], z - prm[2]
        return np.sqrt(dx * dx + dy * dy + dz * dz) - prm[3]
    if kind == CYLINDER:
        rx, ry, rz = x - prm[3], y - prm[4], z - prm[5]
        along = rx * prm[0] + ry * prm[1] + rz * prm[2]
        radial2 = rx * rx + ry * ry + rz * rz - along * along
        return np.sqrt(max(radial2, 0.0)) - prm[6]
    return np.inf


@njit(cache=True, nogil=True, inline="always")
def _incidence(kind, prm, x, y, z):
    # |cos| of the angle between the ray to (x, y, z) (from the sensor at the origin) and the
    # model's normal at the point's foot; 1 for "no model"
    r = np.sqrt(x * x + y * y + z * z)
    if r == 0.0:
        return 1.0
    if kind == PLANE:
        nx, ny, nz = prm[0], prm[1], prm[2]
    elif kind == SPHERE:
        nx, ny, nz = x - prm[0], y - prm[1], z - prm[2]
    elif kind == CYLINDER:
        rx, ry, rz = x - prm[3], y - prm[4], z - prm[5]
        along = rx * prm[0] + ry * prm[1] + rz * prm[2]
        nx, ny, nz = rx - along * prm[0], ry - along * prm[1], rz - along * prm[2]
    else:
        return 1.0
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    if norm == 0.0:
        return 1.0
    return abs(nx * x + ny * y + nz * z) / (norm * r)


@njit(cache=True, nogil=True, inline="always")
def _distance_noise(kind, prm, x, y, z, sigma):
    # fitting.robust.distance_noise of one point: the range noise ``sigma`` times the
    # incidence cosine, and on a sphere or cylinder the sagitta of its bend along the ray
    # (sqrt(3) sigma**2 c**2 / (2 r), c the ray's part across the normal and a cylinder's
    # axis) in quadrature; ``sigma`` for "no model"
    cosine = _incidence(kind, prm, x, y, z)
    first = sigma * cosine
    if kind != SPHERE and kind != CYLINDER:
        return first
    curved = 1.0 - cosine * cosine
    radius = prm[3]
    if kind == CYLINDER:
        r = np.sqrt(x * x + y * y + z * z)
        along = (x * prm[0] + y * prm[1] + z * prm[2]) / r if r > 0.0 else 0.0
        curved -= along * along
        radius = prm[6]
    if not radius > 0.0:
        return first
    sagitta = sigma * sigma * max(curved, 0.0) / (2.0 * radius)
    return np.sqrt(first * first + 3.0 * sagitta * sagitta)


@njit(cache=True, nogil=True, inline="always")
def _neighbour(i, step, h, w):
    # Flat index of the 4-neighbour ``step`` (up, down, left, right) of pixel i; -1 off the grid.
    return _grid_neighbour(i, i // w, i % w, step, h, w, False)


@njit(cache=True, nogil=True, inline="always")
def _grid_neighbour(i, r, c, step, h, w, wrap):
    # :func:`_neighbour` of pixel i at (r, c), given them (no division: settle_borders' first
    # pass asks it of every pixel of a frame); with ``wrap`` (a 360-degree grid) across the
    # seam of a full turn
    if step == 0:
        return i - w if r > 0 else -1
    if step == 1:
        return i + w if r < h - 1 else -1
    if step == 2:
        return i - 1 if c > 0 else (i + w - 1 if wrap else -1)
    return i + 1 if c < w - 1 else (i - w + 1 if wrap else -1)


@njit(cache=True, nogil=True, inline="always")
def _plane_step_agrees(prm, xyz, i, j, ri, rj, limit):
    # Whether the range step ri - rj between pixels i and j is the plane's own step between
    # their rays within ``limit``: a plane seen at a grazing angle steps by far more than the
    # sensor's jump threshold from one ray to the next (r = d / (n . u) along the unit ray u),
    # with no discontinuity between them. False when a ray runs (nearly) parallel to the plane.
    ci = prm[0] * xyz[i, 0] + prm[1] * xyz[i, 1] + prm[2] * xyz[i, 2]  # = (n . u_i) r_i
    cj = prm[0] * xyz[j, 0] + prm[1] * xyz[j, 1] + prm[2] * xyz[j, 2]
    if ci == 0.0 or cj == 0.0:
        return False
    plane_i, plane_j = prm[3] * ri / ci, prm[3] * rj / cj  # the plane's range along each ray
    return abs((ri - rj) - (plane_i - plane_j)) <= limit


@njit(cache=True, nogil=True, inline="always")
def _jump_limit(a, b, jump_ratio, jump_min):
    # the largest step between neighbours' ranges ``a`` and ``b`` that is no jump: a share of
    # the nearer range, at least ``jump_min``. Callers compare ``abs(a - b)`` with it: ``>`` counts
    # a NaN range as no jump, ``<=`` as one (each states which)
    return max(jump_min, jump_ratio * min(a, b))


@njit(cache=True, nogil=True, inline="always")
def _nearest_neighbour_model(i, flat, h, w, xyz, kinds, params, rms, sigma, ranges, k_sigma, jump_ratio,
                             jump_min, plane_steps=False):
    # Growth's test for free pixel i: among its 4-neighbours' regions with a model and no
    # range jump to them (step <= max(jump_min, jump_ratio * r); with ``plane_steps`` also
    # no jump when a plane's own step between the two rays accounts for it, see
    # _plane_step_agrees), the one whose model is nearest in units of max(sigma, rms),
    # within k_sigma (the first of equals); returns (label, distance), label 0 when none.
    n = kinds.shape[0]
    best, best_score, best_dist = 0, k_sigma, 0.0
    for step in range(4):
        j = _neighbour(i, step, h, w)
        if j < 0:
            continue
        k = flat[j]
        if k <= 0 or k >= n or kinds[k] == 0:
            continue
        ri, rj = ranges[i], ranges[j]
        limit = _jump_limit(ri, rj, jump_ratio, jump_min)
        if not (abs(ri - rj) <= limit):
            if not (plane_steps and kinds[k] == PLANE and _plane_step_agrees(params[k], xyz, i, j, ri, rj, limit)):
                continue
        dist = _distance(kinds[k], params[k], xyz[i, 0], xyz[i, 1], xyz[i, 2])
        score = dist / max(sigma[i], rms[k])
        if score <= best_score and (best == 0 or score < best_score):
            best, best_score, best_dist = k, score, dist
    return best, best_dist
