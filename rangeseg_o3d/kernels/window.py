"""Per-pixel window planes: the moments of every k x k window and their smallest eigenpair.

The moments are one pass over the grid, each window summed about one of its own points
(its centre when valid), so the centred scatter keeps its precision however far the scan
is from the origin. The smallest eigenvalue is the smallest root of the characteristic
cubic, found by Newton's method from below in a branch-free loop that the compiler
vectorises (five steps settle nearly every window); windows with repeated or clustered
roots, where Newton crawls, take the trigonometric closed form instead.
"""

from __future__ import annotations

import math

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .inline import NO_MOMENTS, _add_moments

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("inline.py", "kinds.py")

__all__ = ["window_moments", "window_normals", "smallest_eigenvalues", "window_residuals", "eigenvectors", "crease_mask",
           "ray_steps", "blind_spacing"]


@njit(cache=True, nogil=True, inline="always")
def _reference(xyz, r0, r1, c0, c1, r, c):
    # The point the window's sums are taken about: its centre, else its first valid point.
    if xyz[r, c, 2] == xyz[r, c, 2]:
        return r, c
    for i in range(r0, r1):
        for j in range(c0, c1):
            if xyz[i, j, 2] == xyz[i, j, 2]:
                return i, j
    return r, c


@njit(cache=True, nogil=True, inline="always")
def _window_scatter(xyz, half, r, c):
    # The valid points of the window of pixel (r, c), clipped at the grid border: (count,
    # mean x, y, z, centred scatter xx, yy, zz, xy, xz, yz), summed about the window's
    # reference point; NaN mean and zero scatter when it has none.
    h, w = xyz.shape[0], xyz.shape[1]
    r0, r1 = max(r - half, 0), min(r + half + 1, h)
    c0, c1 = max(c - half, 0), min(c + half + 1, w)
    rr, cc = _reference(xyz, r0, r1, c0, c1, r, c)
    ox, oy, oz = xyz[rr, cc, 0], xyz[rr, cc, 1], xyz[rr, cc, 2]
    m = NO_MOMENTS
    for i in range(r0, r1):
        for j in range(c0, c1):
            z = xyz[i, j, 2]
            if z == z:
                m = _add_moments(m, xyz[i, j, 0] - ox, xyz[i, j, 1] - oy, z - oz)
    n, sx, sy, sz, sxx, sxy, sxz, syy, syz, szz = m
    if n == 0.0:
        return n, np.nan, np.nan, np.nan, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    mx, my, mz = sx / n, sy / n, sz / n
    return (n, mx + ox, my + oy, mz + oz, sxx - sx * mx, syy - sy * my, szz - sz * mz,
            sxy - sx * my, sxz - sx * mz, syz - sy * mz)


@njit(cache=True, nogil=True)
def window_moments(xyz, window):
    """Count ``(H, W)``, mean ``(3, H, W)`` and centred scatter ``(6, H, W)`` of every window.

    A point is valid when its z is not NaN; windows are clipped at the grid border. The
    scatter is packed ``(xx, yy, zz, xy, xz, yz)``; mean is NaN and scatter 0 where a
    window has no valid point.
    """
    h, w = xyz.shape[0], xyz.shape[1]
    half = window // 2
    count = np.zeros((h, w))
    mean = np.full((3, h, w), np.nan)
    scatter = np.zeros((6, h, w))
    for r in range(h):
        for c in range(w):
            sums = _window_scatter(xyz, half, r, c)
            if sums[0] == 0.0:
                continue
            count[r, c] = sums[0]
            for k in range(3):
                mean[k, r, c] = sums[1 + k]
            for k in range(6):
                scatter[k, r, c] = sums[4 + k]
    return count, mean, scatter


@njit(cache=True, nogil=True)
def _scatter3(xyz):
    """Count ``(H, W)`` and centred scatter ``(6, H, W)`` of every 3x3 window: the values
    :func:`window_moments` gives (``window=3``), without its means.

    A window whose nine points are all valid (inside a scan, nearly every one) is summed
    about its centre, the nine points in row order, as :func:`_window_scatter` sums it; but
    each point's term is added to every window of a row in one loop over the row (the
    same operations per window, in the same order: the same values), without the
    clipping, the reference search and the test per point. The other windows (the grid's
    border, a missing point) go through :func:`_window_scatter`.
    """
    h, w = xyz.shape[0], xyz.shape[1]
    count = np.zeros((h, w))
    scatter = np.zeros((6, h, w))
    # the coordinates as three contiguous grids: the row loops below read them in unit steps
    xs, ys, zs = np.empty((h, w)), np.empty((h, w)), np.empty((h, w))
    for r in range(h):
        for c in range(w):
            xs[r, c], ys[r, c], zs[r, c] = xyz[r, c, 0], xyz[r, c, 1], xyz[r, c, 2]
    # per window of a row (column c at c - 1): sx, sy, sz, sxx, sxy, sxz, syy, syz, szz
    s0, s1, s2, s3, s4, s5 = np.empty(w), np.empty(w), np.empty(w), np.empty(w), np.empty(w), np.empty(w)
    s6, s7, s8 = np.empty(w), np.empty(w), np.empty(w)
    full = np.empty(w, np.bool_)  # the windows of the row whose nine points are valid
    m = max(w - 2, 0)
    for r in range(h):
        interior = 0 < r < h - 1 and w > 2
        if interior:
            for c in range(w):
                full[c] = 0 < c < w - 1
            for i in range(r - 1, r + 2):
                for c in range(w):
                    if zs[i, c] != zs[i, c]:
                        for j in range(max(c - 1, 0), min(c + 2, w)):
                            full[j] = False
            cx, cy, cz = xs[r, 1:w - 1], ys[r, 1:w - 1], zs[r, 1:w - 1]
            for k in range(m):
                s0[k] = s1[k] = s2[k] = s3[k] = s4[k] = s5[k] = s6[k] = s7[k] = s8[k] = 0.0
            for i in range(r - 1, r + 2):
                for j in range(3):
                    px, py, pz = xs[i, j:j + m], ys[i, j:j + m], zs[i, j:j + m]
                    for k in range(m):
                        x = px[k] - cx[k]
                        y = py[k] - cy[k]
                        z = pz[k] - cz[k]
                        s0[k] += x
                        s1[k] += y
                        s2[k] += z
                        s3[k] += x * x
                        s4[k] += x * y
                        s5[k] += x * z
                        s6[k] += y * y
                        s7[k] += y * z
                        s8[k] += z * z
            sc0, sc1, sc2 = scatter[0, r, 1:w - 1], scatter[1, r, 1:w - 1], scatter[2, r, 1:w - 1]
            sc3, sc4, sc5 = scatter[3, r, 1:w - 1], scatter[4, r, 1:w - 1], scatter[5, r, 1:w - 1]
            row_count = count[r, 1:w - 1]
            for k in range(m):  # every window of the row (those not full are redone below)
                n = 9.0  # 0.0 + 1.0, nine times: exact
                sx, sy, sz = s0[k], s1[k], s2[k]
                mx, my, mz = sx / n, sy / n, sz / n
                row_count[k] = n
                sc0[k] = s3[k] - sx * mx
                sc1[k] = s6[k] - sy * my
                sc2[k] = s8[k] - sz * mz
                sc3[k] = s4[k] - sx * my
                sc4[k] = s5[k] - sx * mz
                sc5[k] = s7[k] - sy * mz
        for c in range(w):
            if interior and full[c]:
                continue
            window = _window_scatter(xyz, 1, r, c)
            count[r, c] = window[0]  # (0 and a zero scatter where the window has no point)
            for k in range(6):
                scatter[k, r, c] = window[4 + k]
    return count, scatter


@njit(cache=True, nogil=True)
def window_normals(xyz, window, wanted):
    """Unit normals ``(H, W, 3)`` of the windows of the pixels ``wanted`` ((H, W) bool), NaN
    elsewhere (and where undefined): the values :func:`window_moments`,
    :func:`smallest_eigenvalues` and :func:`eigenvectors` give those pixels over the whole
    grid (each window's sums and eigenpair are its own), at the cost of those pixels only."""
    h, w = xyz.shape[0], xyz.shape[1]
    half = window // 2
    rows = np.empty(h * w, np.int64)
    m = 0
    for r in range(h):
        for c in range(w):
            if wanted[r, c]:
                rows[m] = r * w + c
                m += 1
    scatter = np.zeros((6, m))
    for k in range(m):
        sums = _window_scatter(xyz, half, rows[k] // w, rows[k] % w)
        for i in range(6):
            scatter[i, k] = sums[4 + i]
    vectors = eigenvectors(scatter, smallest_eigenvalues(scatter))
    out = np.full((h, w, 3), np.nan)
    for k in range(m):
        r, c = rows[k] // w, rows[k] % w
        out[r, c, 0], out[r, c, 1], out[r, c, 2] = vectors[k, 0], vectors[k, 1], vectors[k, 2]
    return out


@njit(cache=True, nogil=True, inline="always")
def _invariants(a11, a22, a33, a12, a13, a23):
    # Trace, sum of principal 2x2 minors and determinant: the cubic's coefficients.
    trace = a11 + a22 + a33
    minors = a11 * a22 + a11 * a33 + a22 * a33 - a12 * a12 - a13 * a13 - a23 * a23
    det = a11 * (a22 * a33 - a23 * a23) - a12 * (a12 * a33 - a23 * a13) + a13 * (a12 * a23 - a22 * a13)
    return trace, minors, det


@njit(cache=True, nogil=True, inline="always")
def _newton_step(lam, trace, minors, det):
    # One Newton step on lam^3 - trace lam^2 + minors lam - det. Left of the smallest root
    # the cubic is increasing and concave, so the steps climb to that root without passing it.
    f = ((lam - trace) * lam + minors) * lam - det
    slope = (3.0 * lam - 2.0 * trace) * lam + minors
    return -f / slope if slope > 0.0 else 0.0


@njit(cache=True, nogil=True, inline="always")
def _closed_form(a11, a22, a33, a12, a13, a23):
    # Trigonometric solution of the cubic: exact for repeated roots, where Newton is slow.
    q = (a11 + a22 + a33) / 3.0
    b11, b22, b33 = a11 - q, a22 - q, a33 - q
    p = math.sqrt((b11 * b11 + b22 * b22 + b33 * b33 + 2.0 * (a12 * a12 + a13 * a13 + a23 * a23)) / 6.0)
    if not p > 0.0:
        return max(q, 0.0)
    det = b11 * (b22 * b33 - a23 * a23) - a12 * (a12 * b33 - a23 * a13) + a13 * (a12 * a23 - b22 * a13)
    phi = math.acos(min(max(det / (2.0 * p * p * p), -1.0), 1.0)) / 3.0
    return max(q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0), 0.0)


@njit(cache=True, nogil=True)
def smallest_eigenvalues(scatter):
    """Smallest eigenvalue of each packed symmetric positive semi-definite 3x3 matrix.

    ``scatter`` is (6, N) ordered ``(a11, a22, a33, a12, a13, a23)``; returns (N,), clipped at 0
    and NaN where a matrix has a NaN. Accurate to about 1e-10 of the trace.
    """
    n = scatter.shape[1]
    a11, a22, a33, a12, a13, a23 = scatter[0], scatter[1], scatter[2], scatter[3], scatter[4], scatter[5]
    values = np.empty(n)
    last_step = np.empty(n)
    margin = np.empty(n)
    # Kept free of branches (selects and float stores only), so that it vectorises.
    for i in range(n):
        trace, minors, det = _invariants(a11[i], a22[i], a33[i], a12[i], a13[i], a23[i])
        # Newton's first step from 0: a lower bound, as det >= 0 and minors >= 0.
        lam = det / minors if minors > 0.0 else 0.0
        step = 0.0
        for _ in range(5):
            step = _newton_step(lam, trace, minors, det)
            lam += step
        values[i] = max(lam, 0.0) if trace == trace else np.nan
        last_step[i] = abs(step) - 1e-10 * trace
        # minors ~ 0: the two smaller roots are both ~0 and det / minors is rounding noise
        margin[i] = minors - 1e-10 * trace * trace
    for i in range(n):  # not settled (repeated or clustered roots, where Newton crawls)
        if values[i] == values[i] and (last_step[i] > 0.0 or not margin[i] > 0.0):
            values[i] = _closed_form(a11[i], a22[i], a33[i], a12[i], a13[i], a23[i])
    return values


@njit(cache=True, nogil=True)
def window_residuals(xyz, window, min_valid, ranges, sigma0, quadratic):
    """The noise-normalised residual image: ``(H, W)``, ``inf`` where invalid.

    Per pixel: the smallest eigenvalue of its window's scatter (:func:`window_moments`,
    :func:`smallest_eigenvalues`) over ``max(count - 3, 1) sigma^2``, ``sigma = sigma0 +
    quadratic r^2`` (``quadratic`` per pixel, ``ranges`` r); ``inf`` where the pixel is
    invalid, the window has under ``min_valid`` points or the ratio is not finite. The same
    values as those steps in numpy (``segmentation.residual.residual_image``'s), without
    their whole-grid temporaries.
    """
    h, w = xyz.shape[0], xyz.shape[1]
    if window == 3:
        count, scatter = _scatter3(xyz)
    else:
        count, _, scatter = window_moments(xyz, window)
    values = smallest_eigenvalues(scatter.reshape(6, h * w)).reshape(h, w)
    out = np.full((h, w), np.inf)
    for r in range(h):
        for c in range(w):
            n = count[r, c]
            if xyz[r, c, 2] != xyz[r, c, 2] or not n >= min_valid:
                continue
            sigma = sigma0 + quadratic[r, c] * (ranges[r, c] * ranges[r, c])
            scale = max(n - 3.0, 1.0) * sigma * sigma
            if scale > 0.0:  # else (0 or NaN) the ratio is not finite
                residual = values[r, c] / scale
                if residual - residual == 0.0:  # finite
                    out[r, c] = residual
    return out


@njit(cache=True, nogil=True)
def eigenvectors(scatter, values):
    """Unit eigenvector (N, 3) of each packed matrix (6, N) for its eigenvalue ``values[i]``.

    The longest cross product of two rows of ``A - lambda I``; NaN where all three vanish
    (the eigenvalue is not simple, e.g. the zero matrix) or the input is NaN.
    """
    n = scatter.shape[1]
    out = np.full((n, 3), np.nan)
    cross = np.empty((3, 3))
    for i in range(n):
        a11, a22, a33 = scatter[0, i] - values[i], scatter[1, i] - values[i], scatter[2, i] - values[i]
        a12, a13, a23 = scatter[3, i], scatter[4, i], scatter[5, i]
        cross[0, 0], cross[0, 1], cross[0, 2] = a12 * a23 - a13 * a22, a13 * a12 - a11 * a23, a11 * a22 - a12 * a12
        cross[1, 0], cross[1, 1], cross[1, 2] = a12 * a33 - a13 * a23, a13 * a13 - a11 * a33, a11 * a23 - a12 * a13
        cross[2, 0], cross[2, 1], cross[2, 2] = a22 * a33 - a23 * a23, a23 * a13 - a12 * a33, a12 * a23 - a22 * a13
        best, pick = 0.0, -1
        for k in range(3):
            norm2 = cross[k, 0] ** 2 + cross[k, 1] ** 2 + cross[k, 2] ** 2
            if norm2 > best:
                best, pick = norm2, k
        if pick >= 0:
            scale = 1.0 / math.sqrt(best)
            for k in range(3):
                out[i, k] = cross[pick, k] * scale
    return out


@njit(cache=True, nogil=True, inline="always")
def _tilt(normals, tolerance, ra, ca, rb, cb):
    # sine of the angle between the normals at two pixels (sign-free); -1 where either
    # lies outside the grid or has no test (NaN tolerance) or no normal
    h, w = normals.shape[0], normals.shape[1]
    if ra < 0 or ca < 0 or rb < 0 or cb < 0 or ra >= h or rb >= h or ca >= w or cb >= w:
        return -1.0
    if not (tolerance[ra, ca] == tolerance[ra, ca] and tolerance[rb, cb] == tolerance[rb, cb]):
        return -1.0
    ax, ay, az = normals[ra, ca, 0], normals[ra, ca, 1], normals[ra, ca, 2]
    bx, by, bz = normals[rb, cb, 0], normals[rb, cb, 1], normals[rb, cb, 2]
    # |a x b| = sin(angle), sign-free (normals have arbitrary signs)
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    sine = math.sqrt(cx * cx + cy * cy + cz * cz)
    return sine if sine == sine else -1.0


@njit(cache=True, nogil=True)
def crease_mask(normals, tolerance, offset):
    """Pixels where the surface's orientation changes at once: ``(H, W)`` bool.

    Pixel (r, c) is marked when the unit normals of the windows centred ``offset`` pixels
    to its left and right (or above and below) make an angle whose sine exceeds, by more
    than the larger of the two windows' ``tolerance`` (a sine per pixel; NaN = no normal,
    no test there), the tilt between one of them and the next window ``2 offset`` further
    out on its side. Planes on either side of a crease tilt the flanking windows apart,
    whatever the noise of single points, once the windows are wide enough for their
    normals to be well determined, while the windows further out lie on the same planes
    and do not tilt; on a curved surface (a column, a ball) every pair of windows the
    same distance apart tilts alike: its orientation changes steadily, which is no crease.
    Where neither outer window exists (the grid's border) the tilt alone decides.
    """
    h, w = normals.shape[0], normals.shape[1]
    out = np.zeros((h, w), np.bool_)
    far = 3 * offset
    for r in range(h):
        for c in range(w):
            for axis in range(2):
                dr, dc = (0, 1) if axis == 0 else (1, 0)
                ra, ca, rb, cb = r - offset * dr, c - offset * dc, r + offset * dr, c + offset * dc
                sine = _tilt(normals, tolerance, ra, ca, rb, cb)
                if sine < 0:
                    continue
                limit = max(tolerance[ra, ca], tolerance[rb, cb])
                if sine <= limit:
                    continue
                # the steady tilt of a curved surface: the smaller of the two outer pairs'
                left = _tilt(normals, tolerance, r - far * dr, c - far * dc, ra, ca)
                right = _tilt(normals, tolerance, rb, cb, r + far * dr, c + far * dc)
                steady = min(left, right) if left >= 0 and right >= 0 else max(left, right, 0.0)
                if sine - steady > limit:
                    out[r, c] = True
                    break
    return out


@njit(cache=True, nogil=True, inline="always")
def _chord_angle(ux, uy, uz, r0, c0, r1, c1):
    # angle between two unit viewing directions (NaN components: NaN)
    dx, dy, dz = ux[r0, c0] - ux[r1, c1], uy[r0, c0] - uy[r1, c1], uz[r0, c0] - uz[r1, c1]
    # the chord between unit vectors is 2 sin(angle / 2): exact for tiny angles too
    return 2.0 * math.asin(min(math.sqrt(dx * dx + dy * dy + dz * dz) / 2.0, 1.0))


@njit(cache=True, nogil=True)
def _directions(xyz):
    # each pixel's unit viewing direction (NaN for an invalid or zero point), as three grids
    h, w = xyz.shape[0], xyz.shape[1]
    ux, uy, uz = np.empty((h, w)), np.empty((h, w)), np.empty((h, w))
    for r in range(h):
        for c in range(w):
            x, y, z = xyz[r, c, 0], xyz[r, c, 1], xyz[r, c, 2]
            norm = math.sqrt(x * x + y * y + z * z)
            if norm > 0.0:
                ux[r, c], uy[r, c], uz[r, c] = x / norm, y / norm, z / norm
            else:
                ux[r, c], uy[r, c], uz[r, c] = np.nan, np.nan, np.nan
    return ux, uy, uz


@njit(cache=True, nogil=True)
def ray_steps(xyz):
    """Angle (radians) between each pixel's viewing direction and the next row's and the
    next column's, ``(2, H, W)`` (the last row / column repeats the one before; NaN where
    either pixel is invalid)."""
    h, w = xyz.shape[0], xyz.shape[1]
    ux, uy, uz = _directions(xyz)
    out = np.full((2, h, w), np.nan)
    for r in range(h):
        for c in range(w):
            if h > 1:
                ra = min(r, h - 2)
                out[0, r, c] = _chord_angle(ux, uy, uz, ra, c, ra + 1, c)
            if w > 1:
                ca = min(c, w - 2)
                out[1, r, c] = _chord_angle(ux, uy, uz, r, ca, r, ca + 1)
    return out


@njit(cache=True, nogil=True, inline="always")
def _unit(xyz, r, c):
    # the pixel's unit viewing direction, as _directions computes it (NaN: none)
    x, y, z = xyz[r, c, 0], xyz[r, c, 1], xyz[r, c, 2]
    norm = math.sqrt(x * x + y * y + z * z)
    if norm > 0.0:
        return x / norm, y / norm, z / norm
    return np.nan, np.nan, np.nan


@njit(cache=True, nogil=True, inline="always")
def _pixel_chord_angle(xyz, r0, c0, r1, c1):
    # _chord_angle of two pixels, their directions computed on the spot (the same values)
    ax, ay, az = _unit(xyz, r0, c0)
    bx, by, bz = _unit(xyz, r1, c1)
    dx, dy, dz = ax - bx, ay - by, az - bz
    return 2.0 * math.asin(min(math.sqrt(dx * dx + dy * dy + dz * dz) / 2.0, 1.0))


#: The sine bound below is trusted where the angle's square is at least this (rad^2): far
#: above the rounding of the chord and of the cross product, which grows as the angle shrinks.
_SINE_FLOOR2 = 1e-12


@njit(cache=True, nogil=True, inline="always")
def _step_clears(xyz, r0, c0, r1, c1, reach2, limit2):
    # Whether the angle between two pixels' viewing directions is NaN (-1: a point without
    # direction), certainly puts ``reach x angle`` at or over the limit (1), or may not (0).
    # The angle is at least its sine, |a x b| / (|a| |b|): compared squared and multiplied
    # out, without a square root or a division per pixel; the factor covers the roundings.
    ax, ay, az = xyz[r0, c0, 0], xyz[r0, c0, 1], xyz[r0, c0, 2]
    bx, by, bz = xyz[r1, c1, 0], xyz[r1, c1, 1], xyz[r1, c1, 2]
    a2, b2 = ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz
    if not (a2 > 0.0 and b2 > 0.0):  # zero or NaN: no direction (the square root keeps both)
        return -1
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    norms = a2 * b2
    sine2 = (cx * cx + cy * cy + cz * cz) * (1.0 - 1e-6)
    if not (0.0 < norms < np.inf and sine2 >= _SINE_FLOOR2 * norms):  # no bound trusted
        return 0
    over = reach2 * sine2
    return 1 if over >= limit2 * norms and over < np.inf else 0


@njit(cache=True, nogil=True, inline="always")
def _fmin(a, b):
    # np.fmin of two floats: the smaller, a NaN only when both are
    if a != a:
        return b
    if b != b:
        return a
    return a if a < b else b


@njit(cache=True, nogil=True)
def blind_spacing(xyz, ranges, sigma, visible_ratio):
    """The grid's spacing where it is under ``visible_ratio`` noise sigmas: ``(spacing, count)``.

    The spacing of a pixel is its range times the smaller of its angular steps to the next
    row and column (:func:`ray_steps`, NaN ones skipped as ``np.fmin`` does); ``spacing``
    holds it where it is finite, positive and under ``visible_ratio * sigma`` (the crease
    test's blind pixels), NaN elsewhere; ``count`` is the number of those pixels. The same
    values as ``ranges * np.fmin(*ray_steps(xyz))`` there, without its square roots and
    arc sines where a lower bound of the steps (their sines, squared) already puts the
    spacing over the limit: a laser scanner's every pixel.
    """
    h, w = xyz.shape[0], xyz.shape[1]
    spacing = np.full((h, w), np.nan)
    count = 0
    for r in range(h):
        ra = min(r, h - 2)
        for c in range(w):
            reach = ranges[r, c]
            if not (reach > 0.0 and reach < np.inf):  # a spacing 0, negative or not finite
                continue
            limit = visible_ratio * sigma[r, c]
            if not limit > 0.0:  # no spacing is under it (NaN: no test)
                continue
            ca = min(c, w - 2)
            reach2, limit2 = reach * reach, limit * limit
            if reach2 < np.inf and limit2 < np.inf:
                # skipped where each step is over the limit by the bound, or has no direction
                by_row = _step_clears(xyz, ra, c, ra + 1, c, reach2, limit2) if h > 1 else -1
                by_col = _step_clears(xyz, r, ca, r, ca + 1, reach2, limit2) if w > 1 else -1
                if by_row != 0 and by_col != 0:
                    continue
            row = _pixel_chord_angle(xyz, ra, c, ra + 1, c) if h > 1 else np.nan
            col = _pixel_chord_angle(xyz, r, ca, r, ca + 1) if w > 1 else np.nan
            value = reach * _fmin(row, col)
            if value > 0.0 and value < limit and value < np.inf:
                spacing[r, c] = value
                count += 1
    return spacing, count
