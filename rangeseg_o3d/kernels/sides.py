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
from .kinds import CYLINDER, SPHERE
from .linalg import curvature_resolved, noise_rms_bound
from .window import eigenvectors, smallest_eigenvalues

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("inline.py", "kinds.py", "linalg.py", "window.py")

__all__ = ["crease_sides", "crease_cut", "cap_band_most", "curved_may_split"]


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


@njit(cache=True, nogil=True)
def cap_band_most(xyz, sigma, idx, axis, point, sigmas, slack):
    """The most pixels of a cylinder region (``idx``, flat pixels of ``xyz`` (N, 3) with range
    noise ``sigma``; the cylinder's unit ``axis`` through ``point``) that one plane across the
    axis, at any axial coordinate, holds within ``sigmas`` times each pixel's noise along the
    axis: an upper bound on the band of ``refinement.facets.cap_split`` at whatever offset its
    histogram picks.

    A pixel's axial coordinate ``(x - point) . axis`` and its noise along the axis ``sigma
    |ray . axis|`` (the ray from the origin, that noise at least 1e-12, as the cap split takes
    them) make the closed interval of the offsets whose band holds it; the answer is the most
    intervals one offset meets (a sweep over their sorted ends). Each interval is widened by
    ``slack`` (relative, and times the points' coordinate scale) over what numpy's rounding of the
    same terms could move: the bound is never under the band numpy counts. A pixel whose
    coordinate or noise is NaN is in no band (numpy's comparison is false)."""
    n = idx.size
    low = np.empty(n)
    high = np.empty(n)
    m = 0
    origin_scale = abs(point[0]) + abs(point[1]) + abs(point[2])
    for j in range(n):
        i = idx[j]
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        along = (x - point[0]) * axis[0] + (y - point[1]) * axis[1] + (z - point[2]) * axis[2]
        norm = math.sqrt(x * x + y * y + z * z)
        noise = sigma[i] * abs(x * axis[0] + y * axis[1] + z * axis[2]) / max(norm, 1e-12)
        if noise != noise or along != along:
            continue
        reach = sigmas * max(noise, 1e-12) * (1.0 + slack) + slack * (abs(x) + abs(y) + abs(z) + origin_scale + 1.0)
        low[m] = along - reach
        high[m] = along + reach
        m += 1
    low = np.sort(low[:m])
    high = np.sort(high[:m])
    most, ended = 0, 0
    for k in range(m):  # an offset at the k-th lowest start meets every interval begun and not ended before it
        while high[ended] < low[k]:
            ended += 1
        most = max(most, k + 1 - ended)
    return most


@njit(cache=True, nogil=True)
def _region_may_split(xyz, sigma, pixels, kind, prm, min_size, inlier_factor, sigmas, bins, cuts, cover, extra, slack):
    # Whether planes_for_curved may split one sphere or cylinder region (``pixels``): see
    # curved_may_split. Each distance is bounded by |d| +- slack times the coordinates' scale,
    # the sums by (1 +- slack): far over the rounding by which these operations can differ
    # from numpy's (its matrix products, pairwise sums and norms).
    n = pixels.size
    upper = np.empty(n)
    values = np.empty(n)
    squares_high, squares_low = 0.0, 0.0
    scale = abs(prm[0]) + abs(prm[1]) + abs(prm[2]) + abs(prm[3]) + 1.0
    if kind == CYLINDER:
        scale += abs(prm[4]) + abs(prm[5]) + abs(prm[6])
    for j in range(n):
        i = pixels[j]
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        if not np.isfinite(sigma[i]):
            return True  # (numpy's medians and bounds decide)
        if kind == CYLINDER:
            rx, ry, rz = x - prm[3], y - prm[4], z - prm[5]
            t = rx * prm[0] + ry * prm[1] + rz * prm[2]
            nx, ny, nz = rx - t * prm[0], ry - t * prm[1], rz - t * prm[2]
            d = math.sqrt(nx * nx + ny * ny + nz * nz) - prm[6]
        else:
            cx, cy, cz = x - prm[0], y - prm[1], z - prm[2]
            d = math.sqrt(cx * cx + cy * cy + cz * cz) - prm[3]
        if not np.isfinite(d):
            return True
        error = slack * (abs(x) + abs(y) + abs(z) + scale)
        high = abs(d) + error
        low = max(abs(d) - error, 0.0)
        upper[j] = high
        squares_high += high * high
        squares_low += low * low
        values[j] = sigma[i]
    rms_high = math.sqrt(squares_high / n) * (1.0 + slack)
    rms_low = math.sqrt(squares_low / n) * (1.0 - slack)
    # beyond the range noise at the region's median (fitting.robust.beyond_noise): the splits run
    lowest, highest = values.min(), values.max()
    if lowest == highest:  # (a laser's range noise, one value: no sort)
        median = lowest
    else:
        values = np.sort(values)
        half = n // 2
        median = values[half] if n % 2 else (values[half - 1] + values[half]) / 2.0
    if rms_high > noise_rms_bound(median, float(n), sigmas) * (1.0 - slack):
        return True
    # a region's worth of the model's outliers (facets._holds_another's first test)
    outliers = 0
    for j in range(n):
        if upper[j] > inlier_factor * rms_low:
            outliers += 1
    if outliers >= min_size:
        return True
    if kind != CYLINDER:
        return False  # (a sphere has no crease cut and no end cap)
    # the crease cut's gate (crease_sides over every pixel, _misfits_across: the rms beyond the
    # noise of the distances, then the chi-square of the mean distances in bins of angle, the
    # bins and their noise by the same compiled steps, the distances bounded)
    if n >= 2 * bins and n >= 2 * min_size and _may_misfit_across(xyz, sigma, pixels, prm, rms_high, upper, min_size,
                                                                 bins, cuts, cover, extra, sigmas, slack):
        return True
    # an end cap's band of the size floor (facets.cap_split)
    if n >= 2 * min_size:
        return cap_band_most(xyz, sigma, pixels, prm[0:3], prm[3:6], sigmas, slack) >= min_size
    return False


@njit(cache=True, nogil=True)
def _may_misfit_across(xyz, sigma, pixels, prm, rms_high, upper, min_size, bins, cuts, cover, extra, sigmas, slack):
    # Whether crease_sides may cut the cylinder ``prm``'s region (its gate, _misfits_across with
    # every pixel its sample, and then _sides_cannot_explain), with
    # the region's rms at most ``rms_high`` and each distance within +-``upper``: the distance
    # noise, the angle order and the bins are its own steps on the same pixels; each bin's
    # |mean distance| is bounded by the mean of those bounds about the mean of the distances
    # here, which lie within ``upper - |d|`` of numpy's.
    axis, point, radius = prm[0:3], prm[3:6], prm[6]
    n = pixels.size
    normals, variance = _normals_and_noise(xyz, sigma, pixels, axis, point, radius)
    noise = 0.0
    for j in range(n):
        noise += variance[j]
    if not np.isfinite(noise):
        return True
    if not rms_high > noise_rms_bound(math.sqrt(noise / n), float(n), sigmas) * (1.0 - slack):
        return False
    order = _angle_order(normals, axis)
    counts, sums, errors, spread = np.zeros(bins), np.zeros(bins), np.zeros(bins), np.zeros(bins)
    for j in range(n):
        b = j * bins // n
        i = pixels[order[j]]
        x, y, z = xyz[i, 0] - point[0], xyz[i, 1] - point[1], xyz[i, 2] - point[2]
        t = x * axis[0] + y * axis[1] + z * axis[2]
        nx, ny, nz = x - t * axis[0], y - t * axis[1], z - t * axis[2]
        d = math.sqrt(nx * nx + ny * ny + nz * nz) - radius
        counts[b] += 1.0
        sums[b] += d
        errors[b] += upper[order[j]] - abs(d)
        spread[b] += variance[order[j]]
    chi_square = 0.0
    for b in range(bins):
        mean = (abs(sums[b]) + errors[b]) / counts[b]
        chi_square += counts[b] * mean * mean / max(spread[b] / counts[b], 1e-24)
    if not chi_square * (1.0 + slack) > (bins + sigmas * math.sqrt(2.0 * bins)) * (1.0 - slack):
        return False
    # crease_sides' last refusal: even the best cut's planes cannot explain the region, with
    # the cylinder's squared distances at their bound (the refusal holds for any smaller sum)
    points = np.empty((n, 3))
    for j in range(n):
        points[j] = xyz[pixels[j]]
    cut, _ = _best_cut(points, order, _cut_positions(n, min_size, cuts))
    return not _sides_cannot_explain(points, order, cut, upper * (1.0 + slack), cover, extra, sigmas)


@njit(cache=True, nogil=True)
def curved_may_split(labels, xyz, sigma, kinds, params, min_size, inlier_factor, sigmas, bins, cuts, cover, extra,
                     slack):
    """Per label (a boolean array as long as ``kinds``): whether ``refinement.facets.planes_for_curved``
    may change the region of a sphere or cylinder; False only where every test that lets its
    splits run surely refuses, so that the step leaves the region as it is.

    ``labels`` are the flat labels, ``xyz`` (N, 3) and ``sigma`` (N,) the points and range noise,
    ``kinds`` and ``params`` the model table (:mod:`.kinds`; labels of other kinds are not asked).
    In one pass the pixels of the sphere and cylinder labels are grouped; then per region, with
    the model's distances computed here and bounded either side by ``slack`` (relative, and
    times the coordinates' scale) over numpy's rounding:

    - its rms is within the chi-square bound (``sigmas``) of the median range noise (else
      the split into planes runs);
    - fewer than ``min_size`` distances can be beyond ``inlier_factor`` times its rms (else
      the test for another surface inside it goes on);
    - a cylinder of ``2 bins`` and ``2 min_size`` pixels: its rms is within the bound of the
      noise of its distances, or the chi-square of its mean distances in ``bins`` bins of angle
      about the axis is within its bound (``crease_sides``' gate, over every pixel), or the
      planes of the best of ``cuts`` cuts by angle cannot explain a ``cover`` share of it with
      ``extra`` parameters fewer (its last refusal);
    - a cylinder of ``2 min_size`` pixels: no plane across its axis holds ``min_size`` of them
      within their noise along it (:func:`cap_band_most`).

    A non-finite range noise or distance in a region answers True (numpy decides)."""
    count = kinds.size
    counts = np.zeros(count, np.int64)
    for i in range(labels.size):
        k = labels[i]
        if 0 < k < count and (kinds[k] == SPHERE or kinds[k] == CYLINDER):
            counts[k] += 1
    starts = np.zeros(count + 1, np.int64)
    for k in range(count):
        starts[k + 1] = starts[k] + counts[k]
    order = np.empty(starts[count], np.int64)
    fill = starts[:count].copy()
    for i in range(labels.size):
        k = labels[i]
        if 0 < k < count and counts[k] > 0:
            order[fill[k]] = i
            fill[k] += 1
    may = np.zeros(count, np.bool_)
    for k in range(count):
        if counts[k] > 0:
            may[k] = _region_may_split(xyz, sigma, order[starts[k]:starts[k + 1]], kinds[k], params[k], min_size,
                                       inlier_factor, sigmas, bins, cuts, cover, extra, slack)
    return may
