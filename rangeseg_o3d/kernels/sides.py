"""A cylinder region seen as the two sides of a crease: whether the cylinder misfits it in a
pattern across its axis, and the cut by angle about the axis into two least-squares planes.

One compiled call per cylinder region (the refinement's facets step asks it of every
cylinder within the range noise): in numpy the same test was some 25 small-array calls.
"""

from __future__ import annotations

import math

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .inline import _distance_noise
from .kinds import CYLINDER
from .linalg import curvature_resolved, noise_rms_bound
from .window import eigenvectors, smallest_eigenvalues

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("inline.py", "kinds.py", "linalg.py", "window.py")

__all__ = ["crease_sides", "crease_cut"]


@njit(cache=True, nogil=True)
def _normals_and_noise(xyz, sigma, pixels, axis, point, radius):
    # Per pixel: the cylinder's unit radial normal at its foot (zero on the axis) and the
    # variance of its distance to the cylinder from range noise along its ray
    # (fitting.robust.distance_noise squared: the incidence cosine and, in quadrature, the
    # sagitta of the cylinder's bend along the ray, most of the noise there is at a far
    # pillar's flanks under a depth camera's centimetres)
    m = pixels.size
    normals = np.zeros((m, 3))
    variance = np.empty(m)
    model = np.array([axis[0], axis[1], axis[2], point[0], point[1], point[2], radius])
    for j in range(m):
        i = pixels[j]
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        rx, ry, rz = x - point[0], y - point[1], z - point[2]
        along = rx * axis[0] + ry * axis[1] + rz * axis[2]
        nx, ny, nz = rx - along * axis[0], ry - along * axis[1], rz - along * axis[2]
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        if norm > 0.0:
            normals[j, 0], normals[j, 1], normals[j, 2] = nx / norm, ny / norm, nz / norm
        variance[j] = _distance_noise(CYLINDER, model, x, y, z, sigma[i]) ** 2
    return normals, variance


@njit(cache=True, nogil=True)
def _angle_order(normals, axis):
    # The pixels' order by angle about the axis (stable), the angle measured from the mean
    # of their normals: an arc short of a full turn does not straddle the branch cut.
    m = normals.shape[0]
    first = np.zeros(3)
    for j in range(m):
        for k in range(3):
            first[k] += normals[j, k]
    first /= max(m, 1)
    second = np.array([axis[1] * first[2] - axis[2] * first[1], axis[2] * first[0] - axis[0] * first[2],
                       axis[0] * first[1] - axis[1] * first[0]])
    angles = np.empty(m)
    for j in range(m):
        angles[j] = math.atan2(normals[j, 0] * second[0] + normals[j, 1] * second[1] + normals[j, 2] * second[2],
                               normals[j, 0] * first[0] + normals[j, 1] * first[1] + normals[j, 2] * first[2])
    return np.argsort(angles, kind="mergesort")


@njit(cache=True, nogil=True)
def _misfits_across(xyz, sigma, idx, distances, axis, point, radius, bins, sample, sigmas):
    # The gate: on an even sample of at most ``sample`` pixels, the rms is beyond the noise
    # of the distances, and so is the mean distance in each of ``bins`` equal-count bins of
    # angle (a chi-square over the bins, ``sigmas`` deviations up its law). Returns whether,
    # and the sample's normals and angle order (empty when the rms is within the noise).
    n = idx.size
    picks = np.arange(0, n, max(1, n // sample))
    m = picks.size
    normals, variance = _normals_and_noise(xyz, sigma, idx[picks], axis, point, radius)
    squares, noise = 0.0, 0.0
    for j in range(m):
        squares += distances[picks[j]] ** 2
        noise += variance[j]
    if not math.sqrt(squares / m) > noise_rms_bound(math.sqrt(noise / m), float(m), sigmas):
        return False, normals, np.zeros(0, np.int64)
    order = _angle_order(normals, axis)
    counts, means, spread = np.zeros(bins), np.zeros(bins), np.zeros(bins)
    for j in range(m):
        b = j * bins // m
        counts[b] += 1.0
        means[b] += distances[picks[order[j]]]
        spread[b] += variance[order[j]]
    chi_square = 0.0
    for b in range(bins):
        mean = means[b] / counts[b]
        chi_square += counts[b] * mean * mean / max(spread[b] / counts[b], 1e-24)
    return chi_square > bins + sigmas * math.sqrt(2.0 * bins), normals, order


@njit(cache=True, nogil=True)
def _cut_positions(n, min_size, cuts):
    # ``cuts`` equal-count cut positions leaving each side ``min_size`` (np.linspace's values
    # truncated, without repeats)
    start, stop = float(min_size), float(n - min_size)
    step = (stop - start) / (cuts - 1)
    values = np.empty(cuts, np.int64)
    for c in range(cuts):
        values[c] = int(c * step + start) if c < cuts - 1 else int(stop)
    return np.unique(values)


@njit(cache=True, nogil=True)
def _best_cut(points, order, positions):
    # The cut position whose two sides' least-squares planes leave the fewest squared
    # distances, and those squared distances: per side the smallest eigenvalue of its
    # scatter, from running sums of the centred points taken in angle order.
    n = order.size
    centre = np.zeros(3)
    for j in range(n):
        for k in range(3):
            centre[k] += points[j, k]
    centre /= n
    sums, products = np.zeros((positions.size + 1, 3)), np.zeros((positions.size + 1, 6))
    s, p = np.zeros(3), np.zeros(6)
    c = 0
    for j in range(n):
        x, y, z = points[order[j], 0] - centre[0], points[order[j], 1] - centre[1], points[order[j], 2] - centre[2]
        s[0] += x
        s[1] += y
        s[2] += z
        p[0] += x * x
        p[1] += y * y
        p[2] += z * z
        p[3] += x * y
        p[4] += x * z
        p[5] += y * z
        while c < positions.size and positions[c] == j + 1:
            sums[c], products[c] = s, p
            c += 1
    sums[positions.size], products[positions.size] = s, p  # the whole region
    scatter = np.empty((6, 2 * positions.size))
    pairs = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
    for c in range(positions.size):
        left = float(positions[c])
        right = n - left
        for e in range(6):
            a, b = pairs[e]
            tail_a, tail_b = sums[positions.size, a] - sums[c, a], sums[positions.size, b] - sums[c, b]
            scatter[e, 2 * c] = products[c, e] - sums[c, a] * sums[c, b] / left
            scatter[e, 2 * c + 1] = products[positions.size, e] - products[c, e] - tail_a * tail_b / right
    values = smallest_eigenvalues(scatter)
    best, best_squares = 0, np.inf
    for c in range(positions.size):
        squares = values[2 * c] + values[2 * c + 1]
        if squares < best_squares:
            best, best_squares = c, squares
    return positions[best], best_squares


@njit(cache=True, nogil=True)
def _sides_cannot_explain(points, order, cut, distances, cover, extra, sigmas):
    # The sides' least-squares planes cannot replace the cylinder, whatever pixels a later
    # step moves between them or drops: any ``cover`` share of the pixels (``least`` or more)
    # keeps squared distances no smaller than each pixel's to the nearer plane, and the
    # cylinder's over them are at most its sum over the region; when even the smallest
    # ``least`` of the former beat the latter by the curvature test's margin (``extra``
    # parameters), neither two planes nor one left of them pass it.
    n = order.size
    least = int(math.ceil(cover * n))
    if least <= 6 + extra:
        return False
    means = np.zeros((2, 3))
    for j in range(n):
        side = 0 if j < cut else 1
        for k in range(3):
            means[side, k] += points[order[j], k]
    means[0] /= cut
    means[1] /= n - cut
    scatter = np.zeros((6, 2))
    for j in range(n):
        side = 0 if j < cut else 1
        x = points[order[j], 0] - means[side, 0]
        y = points[order[j], 1] - means[side, 1]
        z = points[order[j], 2] - means[side, 2]
        scatter[0, side] += x * x
        scatter[1, side] += y * y
        scatter[2, side] += z * z
        scatter[3, side] += x * y
        scatter[4, side] += x * z
        scatter[5, side] += y * z
    normals = eigenvectors(scatter, smallest_eigenvalues(scatter))
    if not (np.isfinite(normals[0, 0]) and np.isfinite(normals[1, 0])):
        return False
    nearer = np.empty(n)
    total = 0.0
    for j in range(n):
        near = np.inf
        for side in range(2):
            off = 0.0
            for k in range(3):
                off += (points[j, k] - means[side, k]) * normals[side, k]
            near = min(near, off * off)
        nearer[j] = near
        total += distances[j] * distances[j]
    floor = np.sum(np.sort(nearer)[:least])
    return curvature_resolved(floor, total, least, extra, sigmas)


@njit(cache=True, nogil=True)
def crease_sides(xyz, sigma, idx, distances, axis, point, radius, min_size, bins, sample, cuts, sigmas, cover, extra):
    """The first side of a cylinder region cut in two by angle about its axis, when the
    cylinder misfits it in a pattern across the axis; an empty mask otherwise.

    ``xyz`` (N, 3) and ``sigma`` (N,) are the scan's points and range noise, ``idx`` the
    region's flat pixels, ``distances`` the cylinder's signed distances to them, ``axis``
    (unit), ``point`` and ``radius`` the cylinder's. The gate, on an even sample of at most ``sample``
    pixels: their rms is beyond the noise of their distances (range noise along each ray
    times the incidence cosine and the sagitta of the bend in quadrature, as
    ``fitting.robust.distance_noise``; :func:`.linalg.noise_rms_bound` with ``sigmas``), and so
    is their mean distance in each of ``bins`` equal-count bins of angle about the axis
    (a chi-square over the bins beyond ``bins + sigmas sqrt(2 bins)``). Then among ``cuts``
    equal-count cuts of all the pixels ordered by angle (each side at least ``min_size``),
    the one whose sides' least-squares planes leave the fewest squared distances. Returns
    a boolean mask over ``idx`` (True: the first side), of length 0 when the gate fails,
    the region has under ``2 min_size`` pixels, or no ``cover`` share of the pixels could
    be explained by those planes (the curvature test of :func:`.linalg.curvature_resolved`
    with ``extra`` parameters, a bound: see ``_sides_cannot_explain``).
    """
    n = idx.size
    none = np.zeros(0, np.bool_)
    if n < 2 * bins:
        return none
    misfits, normals, order = _misfits_across(xyz, sigma, idx, distances, axis, point, radius, bins, sample, sigmas)
    if not misfits or n < 2 * min_size:
        return none
    if normals.shape[0] < n:  # the gate saw a sample: the cut orders every pixel
        normals, _ = _normals_and_noise(xyz, sigma, idx, axis, point, radius)
        order = _angle_order(normals, axis)
    points = np.empty((n, 3))
    for j in range(n):
        points[j] = xyz[idx[j]]
    cut, _ = _best_cut(points, order, _cut_positions(n, min_size, cuts))
    if _sides_cannot_explain(points, order, cut, distances, cover, extra, sigmas):
        return none
    first = np.zeros(n, np.bool_)
    for j in range(cut):
        first[order[j]] = True
    return first


@njit(cache=True, nogil=True)
def crease_cut(points, axis, point, radius, side, cuts):
    """:func:`rangeseg_o3d.crease_planes._crease_cut`'s sums in one pass over ``points`` (N, 3)
    about the cylinder ``(axis, point, radius)``: ``(status, angle, reference, planes_squares,
    cylinder_squares)``. ``reference``: the unit mean offset from the axis (status 1 when it
    is zero or not finite: no cut); the points are ordered by angle about the axis from it,
    the best of ``cuts`` equal-count cuts leaving ``side`` points a side (:func:`_best_cut`)
    gives ``planes_squares``, its two sides' least-squares planes' squared distances (at
    least 0), and ``angle``, midway between the angles either side of it;
    ``cylinder_squares`` is the cylinder's. numpy's form rounds differently: its mean and
    sums are pairwise, its products BLAS's, its eigenvalues LAPACK's, its sort not stable
    (here: added point after point, Newton's smallest eigenvalues, a stable sort)."""
    n = points.shape[0]
    radial = np.empty((n, 3))
    mean = np.zeros(3)
    for i in range(n):
        x, y, z = points[i, 0] - point[0], points[i, 1] - point[1], points[i, 2] - point[2]
        t = x * axis[0] + y * axis[1] + z * axis[2]
        radial[i, 0], radial[i, 1], radial[i, 2] = x - t * axis[0], y - t * axis[1], z - t * axis[2]
        for k in range(3):
            mean[k] += radial[i, k]
    reference = mean / n
    norm = np.sqrt(reference[0] * reference[0] + reference[1] * reference[1] + reference[2] * reference[2])
    if not (norm > 0.0 and np.isfinite(norm)):
        return 1, 0.0, reference, 0.0, 0.0
    reference /= norm
    across = np.array([axis[1] * reference[2] - axis[2] * reference[1], axis[2] * reference[0] - axis[0] * reference[2],
                       axis[0] * reference[1] - axis[1] * reference[0]])
    angles = np.empty(n)
    cylinder_squares = 0.0
    for i in range(n):
        x, y, z = radial[i, 0], radial[i, 1], radial[i, 2]
        angles[i] = math.atan2(x * across[0] + y * across[1] + z * across[2],
                               x * reference[0] + y * reference[1] + z * reference[2])
        off = np.sqrt(x * x + y * y + z * z) - radius
        cylinder_squares += off * off
    order = np.argsort(angles, kind="mergesort")
    size, squares = _best_cut(points, order, _cut_positions(n, side, cuts))
    angle = 0.5 * (angles[order[size - 1]] + angles[order[size]])
    return 0, angle, reference, max(squares, 0.0), cylinder_squares
