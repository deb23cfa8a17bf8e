"""The screen of :func:`rangeseg_o3d.bent_planes.cylinders_for_bent_planes`' bend test.

On a stereo scan a dozen plane regions a frame are asked whether their inverse ranges bend
across their main direction; about nine in ten are refused by the test before the cylinder's
fit (its width, its plane along the rays, the F-test of the bend, the bend's drop against the
squares' chi-square spread). numpy's form of that test is a few dozen small-array calls on
about 1200 points, about 1 ms a region (8-12 ms a stereo scan). Here the same quantities come
from one compiled pass: the least squares by Householder reflections instead of LAPACK's SVD,
the percentiles by a sort, so their rounding differs from numpy's. The caller keeps numpy's
answer wherever this one could differ: the screen only refuses a region whose every gate it
fails by more than ``margin`` of the quantities compared (and hands on a region whose main
direction is near degenerate, whose width is near its bound, or whose design is near
singular), so that the outcome is numpy's.
"""

from __future__ import annotations

import numpy as np

from .jit import njit  # numba.njit, with this package's cache locator installed

__all__ = ["bend_screen", "curve_screen"]


@njit(cache=True, nogil=True)
def _percentile(values, q):
    # numpy's linear percentile of the sorted ``values`` (up to rounding)
    m = values.shape[0]
    virtual = q / 100.0 * (m - 1)
    low = int(np.floor(virtual))
    high = min(low + 1, m - 1)
    frac = virtual - low
    return values[low] + (values[high] - values[low]) * frac


@njit(cache=True, nogil=True)
def _householder_squares(design, target, p_flat):
    # (flat, bent, smallest |R_jj| / largest): the least sums of squares of design[:, :p_flat]
    # @ x - target and of design @ x - target, by Householder reflections of [design | target]
    n, p = design.shape
    a = np.empty((n, p + 1))
    for i in range(n):
        for j in range(p):
            a[i, j] = design[i, j]
        a[i, p] = target[i]
    flat = 0.0
    smallest, largest = np.inf, 0.0
    for j in range(p):
        norm = 0.0
        for i in range(j, n):
            norm += a[i, j] * a[i, j]
        norm = np.sqrt(norm)
        diag = -norm if a[j, j] >= 0 else norm
        smallest, largest = min(smallest, norm), max(largest, norm)
        if norm == 0.0:
            continue
        # v = a[j:, j] - diag e_1, reflected: H = I - 2 v v^T / (v^T v)
        v0 = a[j, j] - diag
        vv = v0 * v0 + (norm * norm - a[j, j] * a[j, j])
        if vv <= 0.0:
            continue
        for c in range(j + 1, p + 1):
            dot = v0 * a[j, c]
            for i in range(j + 1, n):
                dot += a[i, j] * a[i, c]
            f = 2.0 * dot / vv
            a[j, c] -= f * v0
            for i in range(j + 1, n):
                a[i, c] -= f * a[i, j]
        a[j, j] = diag
        if j == p_flat - 1:
            for i in range(p_flat, n):
                flat += a[i, p] * a[i, p]
    bent = 0.0
    for i in range(p, n):
        bent += a[i, p] * a[i, p]
    return flat, bent, smallest / largest if largest > 0 else 0.0


@njit(cache=True, nogil=True)
def bend_screen(points, noise, samples, max_radius, sigmas, margin):
    """``(refused, flat, bent, width)`` of the bend test of a plane region's test pixels
    ``points`` (N, 3) with range noise ``noise`` (N,), the region holding ``samples``
    independent returns: ``refused`` True where numpy's form
    (:func:`rangeseg_o3d.bent_planes._pipe_of` up to the cylinder's fit) refuses the region
    at a gate by more than ``margin`` (relative) of the quantities compared; False where
    numpy's form must answer. ``flat`` / ``bent``: the least
    sums of squares of the inverse ranges along the rays in their noise, without and with the
    bend across the main direction; ``width``: the region's 3rd-97th percentile extent across
    that direction (NaN where not reached). ``max_radius``: the fitter's; ``sigmas``: the
    chi-square deviations the bend's F-test and drop are held to (``CHI_SQUARE_SIGMAS``)."""
    nan = np.nan
    m = 0
    keep = np.zeros(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        x, y, z, s = points[i, 0], points[i, 1], points[i, 2], noise[i]
        if np.isfinite(x) and np.isfinite(y) and np.isfinite(z) and np.isfinite(s) and s > 0:
            keep[i] = True
            m += 1
    if m < 10:
        return True, nan, nan, nan  # numpy's form: None below 10 points, an exact count
    pts = np.empty((m, 3))
    sig = np.empty(m)
    t = 0
    for i in range(points.shape[0]):
        if keep[i]:
            pts[t], sig[t] = points[i], noise[i]
            t += 1
    n = min(samples, float(m))
    unit = n / m
    centre = np.zeros(3)
    for i in range(m):
        centre += pts[i]
    centre /= m
    view = centre / np.sqrt(centre[0] ** 2 + centre[1] ** 2 + centre[2] ** 2)
    offsets = pts - centre
    scatter = np.zeros((3, 3))
    for i in range(m):
        along = offsets[i, 0] * view[0] + offsets[i, 1] * view[1] + offsets[i, 2] * view[2]
        u = offsets[i] - along * view
        for r in range(3):
            for c in range(3):
                scatter[r, c] += u[r] * u[c]
    values, vectors = np.linalg.eigh(scatter)
    if values[2] - values[1] <= 1e-6 * abs(values[2]):
        return False, nan, nan, nan  # the main direction near degenerate: numpy's may differ
    axis = vectors[:, 2].copy()
    across = np.array([axis[1] * view[2] - axis[2] * view[1], axis[2] * view[0] - axis[0] * view[2],
                       axis[0] * view[1] - axis[1] * view[0]])
    across /= np.sqrt(across[0] ** 2 + across[1] ** 2 + across[2] ** 2)
    lateral = offsets @ across
    ordered = np.sort(lateral)
    width = _percentile(ordered, 97.0) - _percentile(ordered, 3.0)
    half = 0.5 * width
    if half > max_radius * (1.0 + margin):
        return True, nan, nan, width
    if not (half > margin * max_radius and half < max_radius * (1.0 - margin)):
        return False, nan, nan, width
    design = np.empty((m, 4))
    target = np.empty(m)
    for i in range(m):
        x, y, z = pts[i, 0], pts[i, 1], pts[i, 2]
        r = np.sqrt(x * x + y * y + z * z)
        scale = r * r / sig[i]
        design[i, 0], design[i, 1], design[i, 2] = x / r * scale, y / r * scale, z / r * scale
        design[i, 3] = (lateral[i] / width) ** 2 * scale
        target[i] = scale / r
    flat, bent, conditioned = _householder_squares(design, target, 3)
    if conditioned < 1e-8:
        return False, flat, bent, width  # near singular: numpy's lstsq cuts small singular values
    tol = margin * flat
    bound = m * (1.0 + sigmas * np.sqrt(2.0 / n))
    if flat - tol > bound:
        return True, flat, bent, width  # its plane does not explain it along the rays
    if flat + tol >= bound:
        return False, flat, bent, width
    # the F-test (linalg.curvature_resolved with one extra parameter) over max(int(n), 2) returns
    dof = max(int(n), 2) - 4
    if dof <= 0:
        return False, flat, bent, width
    factor = 1.0 + sigmas * np.sqrt(2.0)
    drop, drop_error = (flat - bent) * unit, 2.0 * tol * unit
    if drop + drop_error < factor * (bent - tol) * unit / dof:
        return True, flat, bent, width
    # the drop against the squares' chi-square spread: (flat - bent) unit / (bent / m) >= sqrt(2 n)
    if drop + drop_error < np.sqrt(2.0 * n) * (bent - tol) / m:
        return True, flat, bent, width
    return False, flat, bent, width


@njit(cache=True, nogil=True)
def curve_screen(xyz, noise, kept, own, test_pixels, near_bound, correlation_px, extra, sigmas, margin):
    """``(answer, plane_squares, curved_squares)`` of ``ray_claims._left_curved``'s question
    on the region's kept pixels (flat indices ``kept`` into ``xyz`` (N, 3) and ``noise``;
    its plane ``own``, ``a . p = 1``): whether a quadric along the rays (``extra`` parameters
    beyond the plane's) explains the inverse ranges of an even sample (``test_pixels`` of them)
    within ``near_bound`` range sigmas of that plane better than the plane by more than their
    noise would (the F-test of ``sigmas`` deviations over their independent returns).
    ``answer``: 1 curved, 0 not, -1 where numpy's form must answer (a sample pixel within
    ``margin`` of the near bound, a near-singular design, an F-test within ``margin`` of the
    squares of its bound). The squares are NaN where not reached."""
    nan = np.nan
    size = kept.shape[0]
    step = max(1, size // test_pixels)
    count = (size + step - 1) // step
    near = np.zeros(count, np.bool_)
    m_near = 0
    for t in range(count):
        i = kept[t * step]
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        off = np.sqrt(x * x + y * y + z * z) * abs(1.0 - (own[0] * x + own[1] * y + own[2] * z))
        bound = near_bound * noise[i]
        if np.isnan(off) or np.isnan(bound):
            continue  # never near in numpy's form
        if np.isfinite(off) and np.isfinite(bound) and abs(off - bound) <= margin * max(abs(bound), abs(off)):
            return -1, nan, nan
        if off <= bound:
            near[t] = True
            m_near += 1
    pixels = size * m_near / max(count, 1)
    # curved_along_rays on the near sample (under 2 test_pixels: its own subsample is all of them)
    m = 0
    for t in range(count):
        if near[t]:
            i = kept[t * step]
            x, y, z, s = xyz[i, 0], xyz[i, 1], xyz[i, 2], noise[i]
            if np.isfinite(x) and np.isfinite(y) and np.isfinite(z) and np.isfinite(s) and s > 0:
                m += 1
            else:
                near[t] = False
    if m < 4 + extra:
        return 0, nan, nan
    rx, ry, root_w, inverse = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    rz = np.empty(m)
    j = 0
    for t in range(count):
        if near[t]:
            i = kept[t * step]
            x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            r = max(np.sqrt(x * x + y * y + z * z), 1e-12)
            if not z / r > 0:
                return 0, nan, nan  # rays at or beyond 90 degrees off the axis
            sig = max(noise[i], 1e-12) / (r * r)
            rx[j], ry[j], rz[j] = x / r, y / r, z / r
            root_w[j], inverse[j] = 1.0 / sig, 1.0 / r
            j += 1
    u, v = rx / rz, ry / rz
    u -= u.mean()
    v -= v.mean()
    scale = max(u.std(), v.std(), 1e-12)
    u /= scale
    v /= scale
    design = np.empty((m, 6))
    target = np.empty(m)
    for t in range(m):
        column = root_w[t] * rz[t]
        design[t, 0], design[t, 1], design[t, 2] = column, column * u[t], column * v[t]
        design[t, 3], design[t, 4], design[t, 5] = column * u[t] * u[t], column * u[t] * v[t], column * v[t] * v[t]
        target[t] = root_w[t] * inverse[t]
    plane, curved, conditioned = _householder_squares(design, target, 3)
    if conditioned < 1e-8:
        return -1, plane, curved
    independent = min(float(m), pixels * m / max(m_near, 1) / float(correlation_px) ** 2)
    share = independent / m
    n = int(independent)
    dof = n - 3 - extra
    if dof <= 0:
        return 1, plane, curved  # no degree of freedom left: resolved (nothing to test)
    tol = margin * plane
    drop, error = (plane - curved) * share, 2.0 * tol * share
    factor = extra + sigmas * np.sqrt(2.0 * extra)
    if drop + error < factor * (curved - tol) * share / dof:
        return 0, plane, curved
    if drop - error > factor * (curved + tol) * share / dof:
        return 1, plane, curved
    return -1, plane, curved
