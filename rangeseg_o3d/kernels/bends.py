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

Where the depth comes in steps (a Kinect's disparity), the bend is judged over blocks of the
matching window along the region (``bent_planes._bend_over_blocks``): about 5 regions a
kinect_real scan, ~1.7 ms each in numpy, of which ~98 % are refused. ``stepped_bend_screen``
answers the same gates in one pass and bounds each quantity numpy's form compares from the
errors of its inputs (the region's axis within the rounding of its scatter over the
eigenvalue gap, each residual within the rounding of the target over the design's
condition): it hands on any region where a test pixel lies within that error of a block's end,
a block's spread or conditioning within it of numpy's bound, or the bound on the bend's
t-value reaches the threshold, for either way numpy's eigenvector may order the blocks.
"""

from __future__ import annotations

import numpy as np

from .jit import njit  # numba.njit, with this package's cache locator installed

__all__ = ["bend_screen", "curve_screen", "stepped_bend_screen"]


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
def _householder(design, target, p_flat):
    # [design | target] reduced by Householder reflections: (the reduced array, each reflection's
    # first entry and v^T v (0 where none was applied; its tail stays below the diagonal), the
    # squares left after the first p_flat reflections, smallest |R_jj| / largest)
    n, p = design.shape
    a = np.empty((n, p + 1))
    for i in range(n):
        for j in range(p):
            a[i, j] = design[i, j]
        a[i, p] = target[i]
    heads, norms = np.zeros(p), np.zeros(p)
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
        heads[j], norms[j] = v0, vv
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
    return a, heads, norms, flat, smallest / largest if largest > 0 else 0.0


@njit(cache=True, nogil=True)
def _householder_squares(design, target, p_flat):
    # (flat, bent, smallest |R_jj| / largest): the least sums of squares of design[:, :p_flat]
    # @ x - target and of design @ x - target, by Householder reflections of [design | target]
    a, _, _, flat, conditioned = _householder(design, target, p_flat)
    p = design.shape[1]
    bent = 0.0
    for i in range(p, design.shape[0]):
        bent += a[i, p] * a[i, p]
    return flat, bent, conditioned


@njit(cache=True, nogil=True)
def _kept(points, noise):
    # numpy's keep of bent_planes._pipe_of: finite points with a finite positive noise
    keep = np.zeros(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        x, y, z, s = points[i, 0], points[i, 1], points[i, 2], noise[i]
        keep[i] = np.isfinite(x) and np.isfinite(y) and np.isfinite(z) and np.isfinite(s) and s > 0
    return keep


@njit(cache=True, nogil=True)
def _across_main_direction(pts):
    # (offsets from the centre, the view's direction, each point's offset across the longest
    # extent seen from the camera, the eigenvalues of the extent across the view): the region
    # frame of bent_planes._pipe_of
    m = pts.shape[0]
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
    axis = vectors[:, 2].copy()
    across = np.array([axis[1] * view[2] - axis[2] * view[1], axis[2] * view[0] - axis[0] * view[2],
                       axis[0] * view[1] - axis[1] * view[0]])
    across /= np.sqrt(across[0] ** 2 + across[1] ** 2 + across[2] ** 2)
    return offsets, view, offsets @ across, values


@njit(cache=True, nogil=True)
def _width_answer(lateral, max_radius, margin):
    # (width, answer) of bent_planes._pipe_of's width gate (half the 3rd-97th percentile extent
    # of ``lateral`` within (0, max_radius]): answer 1 numpy's form refuses, 0 it may answer
    # either way (within ``margin`` of a bound), -1 it passes
    ordered = np.sort(lateral)
    width = _percentile(ordered, 97.0) - _percentile(ordered, 3.0)
    half = 0.5 * width
    if half > max_radius * (1.0 + margin):
        return width, 1
    if not (half > margin * max_radius and half < max_radius * (1.0 - margin)):
        return width, 0
    return width, -1


@njit(cache=True, nogil=True)
def _within_noise_answer(squares, m, n, sigmas, margin):
    # the gate of a model along the rays (its squares ``squares`` over ``m`` points within
    # ``sigmas`` sqrt(2 / n) of their count), answered as _width_answer's
    tol = margin * squares
    bound = m * (1.0 + sigmas * np.sqrt(2.0 / n))
    if squares - tol > bound:
        return 1  # the model does not explain it along the rays
    if squares + tol >= bound:
        return 0
    return -1


@njit(cache=True, nogil=True)
def _ray_design(pts, sig, lateral, width):
    # bent_planes._pipe_of's least squares along the rays in their noise: (design, target) with
    # the inverse ranges as target, the rays and the bend (lateral / width)^2 as columns
    m = pts.shape[0]
    design = np.empty((m, 4))
    target = np.empty(m)
    for i in range(m):
        x, y, z = pts[i, 0], pts[i, 1], pts[i, 2]
        r = np.sqrt(x * x + y * y + z * z)
        scale = r * r / sig[i]
        design[i, 0], design[i, 1], design[i, 2] = x / r * scale, y / r * scale, z / r * scale
        design[i, 3] = (lateral[i] / width) ** 2 * scale
        target[i] = scale / r
    return design, target


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
    keep = _kept(points, noise)
    pts, sig = points[keep], noise[keep]
    m = pts.shape[0]
    if m < 10:
        return True, nan, nan, nan  # numpy's form: None below 10 points, an exact count
    n = min(samples, float(m))
    unit = n / m
    _, _, lateral, values = _across_main_direction(pts)
    if values[2] - values[1] <= 1e-6 * abs(values[2]):
        return False, nan, nan, nan  # the main direction near degenerate: numpy's may differ
    width, answer = _width_answer(lateral, max_radius, margin)
    if answer >= 0:
        return answer == 1, nan, nan, width
    design, target = _ray_design(pts, sig, lateral, width)
    flat, bent, conditioned = _householder_squares(design, target, 3)
    if conditioned < 1e-8:
        return False, flat, bent, width  # near singular: numpy's lstsq cuts small singular values
    answer = _within_noise_answer(bent, m, n, sigmas, margin)  # the plane with its bend
    if answer >= 0:
        return answer == 1, flat, bent, width
    tol = margin * flat
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
def _plane_residuals(design, target):
    # (residuals, squares, smallest |R_jj| / largest) of the least squares design @ x ~ target
    # by Householder reflections: the residual vector Q [0; Q^T target's tail], each point's
    # residual to within rounding of the target's size whatever the design's condition
    n, p = design.shape
    a, heads, norms, squares, conditioned = _householder(design, target, p)
    residuals = np.zeros(n)
    for i in range(p, n):
        residuals[i] = a[i, p]
    for j in range(p - 1, -1, -1):  # Q = H_0 H_1 ... H_(p-1) applied to [0; tail]
        if norms[j] == 0.0:
            continue
        dot = heads[j] * residuals[j]
        for i in range(j + 1, n):
            dot += a[i, j] * residuals[i]
        f = 2.0 * dot / norms[j]
        residuals[j] -= f * heads[j]
        for i in range(j + 1, n):
            residuals[i] -= f * a[i, j]
    return residuals, squares, conditioned


@njit(cache=True, nogil=True)
def _blocks_refuse(residuals, share, along, along_error, window, share_error, residual_error, sigmas):
    """True where bent_planes._bend_over_blocks' bend over blocks ``window`` long in ``along``
    (each point's position along the region's main direction in the image, within
    ``along_error`` of numpy's) certainly stays under ``sigmas`` standard errors: every block's
    membership, use and conditioning as numpy decides them, and the mean bend with its error
    bound from the errors of the inputs (``share``: each point's position across the region
    over its width, within ``share_error`` of numpy's; ``residual_error``: each residual's).
    False where numpy's form must answer."""
    m = residuals.shape[0]
    w = float(max(window, 1))
    low = np.inf
    for i in range(m):
        low = min(low, along[i])
    high = -np.inf
    block = np.empty(m, np.int64)
    for i in range(m):
        position = (along[i] - low) / w
        b = int(np.floor(position))
        rest = (position - b) * w
        if (b >= 1 and rest <= 2.0 * along_error) or w - rest <= 2.0 * along_error:
            return False  # a point at a block's end: numpy's may fall in the next block
        block[i] = b
        high = max(high, position)
    count = int(np.floor(high)) + 1
    powers = np.zeros((count, 5))  # per block: sums of share^0..4
    absolute = np.zeros((count, 5))  # ... of |share|^0..4
    moments = np.zeros((count, 3))  # ... of residual share^0..2
    scatter = np.zeros(count)  # ... of |residual| (1 + |share| + share^2)
    largest_share = 0.0
    for i in range(m):
        largest_share = max(largest_share, abs(share[i]))
    # the error of share^p (p <= 4) given share's: p max(1, |share|)^(p - 1) share_error
    power_error = 4.0 * max(1.0, largest_share + share_error) ** 3 * share_error
    for i in range(m):
        b, u, r = block[i], share[i], residuals[i]
        term = 1.0
        for p in range(5):
            powers[b, p] += term
            absolute[b, p] += abs(term)
            if p < 3:
                moments[b, p] += r * term
            term *= u
        scatter[b] += abs(r) * (1.0 + abs(u) + u * u)
    least = 0.5 / np.sqrt(12.0)  # numpy's least spread of a usable block
    terms = np.empty(count)
    errors = np.empty(count)
    used = 0
    usable = 0
    for b in range(count):
        c = powers[b, 0]
        if c < 6:
            continue  # an exact count
        mean_u, mean_uu = powers[b, 1] / c, powers[b, 2] / c
        variance = mean_uu - mean_u * mean_u
        # the variance's error from share's and from rounding (sums of at most m terms)
        variance_error = (1.0 + 2.0 * abs(mean_u)) * power_error + 1e-12 * absolute[b, 2] / c
        if abs(variance - least * least) <= variance_error + 1e-12 * least * least:
            return False
        if variance < least * least:
            continue
        usable += 1
        # the normal equations of residual ~ x0 + x1 share + x2 share^2 and their solution
        a00, a01, a02 = powers[b, 0], powers[b, 1], powers[b, 2]
        a11, a12, a22 = powers[b, 2], powers[b, 3], powers[b, 4]
        c00, c01, c02 = a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11
        det = a00 * c00 + a01 * c01 + a02 * c02
        trace = a00 + a11 + a22
        # each entry is within c power_error (+ rounding) of numpy's: bounds on the determinant
        # and the trace numpy's conditioning compares
        entry_error = c * power_error + 1e-12 * absolute[b, 4] + 1e-12 * c
        trace_error = 3.0 * entry_error
        # (a cofactor is at most 2 trace^2: every entry of the positive normal matrix is within the trace)
        det_error = 18.0 * (trace + trace_error) ** 2 * entry_error + 1e-13 * trace ** 3
        if abs(det) - det_error > 1e-12 * (trace + trace_error) ** 3:
            pass  # conditioned in numpy's form too
        elif abs(det) + det_error < 1e-12 * max(trace - trace_error, 0.0) ** 3:
            continue  # ill-conditioned there too: left out
        else:
            return False
        c11, c12 = a00 * a22 - a02 * a02, a02 * a01 - a00 * a12
        c22 = a00 * a11 - a01 * a01
        b0, b1, b2 = moments[b, 0], moments[b, 1], moments[b, 2]
        x0 = (c00 * b0 + c01 * b1 + c02 * b2) / det
        x1 = (c01 * b0 + c11 * b1 + c12 * b2) / det
        x2 = (c02 * b0 + c12 * b1 + c22 * b2) / det
        # |error of x| <= ||A^-1|| (||dA|| |x| + |db|) / (1 - ||A^-1|| ||dA||), ||A^-1|| <= trace^2 / det
        # for the symmetric positive normal matrix; plus both solves' rounding
        inverse = trace * trace / (abs(det) - det_error)
        matrix_error = 3.0 * entry_error
        size = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        right_error = np.sqrt(3.0) * (residual_error * absolute[b, 0] * 3.0 * max(1.0, largest_share) ** 2
                                      + power_error * scatter[b] + 1e-12 * scatter[b])
        if inverse * matrix_error >= 0.5:
            return False
        errors[used] = (2.0 * inverse * (matrix_error * size + right_error)
                        + 1e-12 * inverse * trace * size)
        terms[used] = -x2  # the inverse range falls towards the sides: convex
        used += 1
    if usable < 3 or used < 3:
        return True  # numpy's form: (False, 0)
    mean = 0.0
    largest_error = 0.0
    for b in range(used):
        mean += terms[b]
        largest_error = max(largest_error, errors[b])
    mean /= used
    spread = 0.0
    for b in range(used):
        spread += (terms[b] - mean) ** 2
    spread = np.sqrt(spread / (used - 1))
    # every term within largest_error of numpy's: its mean within that, its spread within sqrt(2) of it
    mean_high = mean + largest_error
    if mean_high <= 0.0:
        return True  # not convex (or no spread): numpy's form refuses
    spread_low = spread - np.sqrt(2.0) * largest_error
    if spread_low <= 0.0:
        return False
    return mean_high / (spread_low / np.sqrt(used)) * (1.0 + 1e-9) < sigmas


@njit(cache=True, nogil=True)
def stepped_bend_screen(points, noise, sample, columns, samples, max_radius, window, sigmas, margin):
    """True where numpy's form of the bend test where the depth comes in steps
    (:func:`rangeseg_o3d.bent_planes._pipe_of` with pixels, up to the cylinder's fit) refuses a
    plane region: its width, its plane along the rays, or its bend over blocks ``window``
    pixels long (:func:`rangeseg_o3d.bent_planes._bend_over_blocks`) under ``sigmas`` standard
    errors whichever way numpy's form orders the blocks; False where numpy's form must
    answer. ``points`` (N, 3), ``noise`` (N,): the region's test pixels and their range noise;
    ``sample``: their flat indices in a grid ``columns`` wide; ``samples``: the region's
    independent returns; ``max_radius``: the fitter's; ``margin``: as bend_screen's.
    Each quantity numpy's form compares is bounded from the errors of its inputs (eigenvectors
    within the rounding of their scatter over its eigenvalue gap): the screen refuses only where
    the bound falls on numpy's refusing side."""
    keep = _kept(points, noise)
    pts, sig = points[keep], noise[keep]
    m = pts.shape[0]
    if m < 10:
        return True  # numpy's form: None below 10 points
    n = min(samples, float(m))
    offsets, _, lateral, values = _across_main_direction(pts)
    gap = values[2] - values[1]
    if gap <= 1e-6 * abs(values[2]):
        return False
    width, answer = _width_answer(lateral, max_radius, margin)
    if answer >= 0:
        return answer == 1
    design, target = _ray_design(pts, sig, lateral, width)
    residuals, flat, conditioned = _plane_residuals(design[:, :3], target)
    if conditioned < 1e-8:
        return False
    answer = _within_noise_answer(flat, m, n, sigmas, margin)
    if answer >= 0:
        return answer == 1
    # the errors of the inputs of the block test against numpy's: the axis turns by at most the
    # scatter's rounding over the eigenvalue gap, moving each point's share by that angle times
    # its distance over the width; each residual errs by the rounding of the target's size over
    # the design's condition
    extent, largest_target = 0.0, 0.0
    for i in range(m):
        extent = max(extent, np.sqrt(offsets[i, 0] ** 2 + offsets[i, 1] ** 2 + offsets[i, 2] ** 2))
        largest_target = max(largest_target, abs(target[i]))
    turn = 1e-12 * (1.0 + abs(values[2]) / gap)
    share = lateral / width
    largest_share = np.max(np.abs(share))
    share_error = (turn * extent / width + 1e-13) * (2.0 + 2.0 * largest_share)
    residual_error = 1e-11 * largest_target / conditioned
    # each point's (row, column) and the main direction of the pixels (bent_planes._bend_over_blocks)
    pixels = np.empty((m, 2))
    t = 0
    for i in range(points.shape[0]):
        if keep[i]:
            pixels[t, 0], pixels[t, 1] = sample[i] // columns, sample[i] % columns
            t += 1
    centre = np.zeros(2)
    for i in range(m):
        centre += pixels[i]
    centre /= m
    spread = np.zeros((2, 2))
    reach = 0.0
    for i in range(m):
        dr, dc = pixels[i, 0] - centre[0], pixels[i, 1] - centre[1]
        spread[0, 0] += dr * dr
        spread[0, 1] += dr * dc
        spread[1, 1] += dc * dc
        reach = max(reach, np.sqrt(dr * dr + dc * dc))
    spread[1, 0] = spread[0, 1]
    image_values, image_vectors = np.linalg.eigh(spread)
    image_gap = image_values[1] - image_values[0]
    if image_gap <= 1e-6 * abs(image_values[1]):
        return False
    along_error = 1e-12 * (2.0 + abs(image_values[1]) / image_gap) * (reach + 1.0)
    along = np.empty(m)
    for i in range(m):
        along[i] = ((pixels[i, 0] - centre[0]) * image_vectors[0, 1]
                    + (pixels[i, 1] - centre[1]) * image_vectors[1, 1])
    # numpy's eigenvector may point either way, which changes where the blocks start: refuse only
    # where both orders refuse
    if not _blocks_refuse(residuals, share, along, along_error, window, share_error, residual_error, sigmas):
        return False
    return _blocks_refuse(residuals, share, -along, along_error, window, share_error, residual_error, sigmas)


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
