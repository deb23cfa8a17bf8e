"""Small compiled linear-algebra helpers shared by the kernels and the fits.

Kept in ``kernels`` so that the kernels depend on nothing else in the package; the
compiled fits (:mod:`rangeseg_o3d.fitting._compiled`, :mod:`rangeseg_o3d.fitting._decide`)
import them from here.
"""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

__all__ = ["DEGENERATE_RATIO", "solve", "hesse_form", "collinear", "noise_rms_bound", "plane_tolerance"]

# Relative size below which a spread is treated as exactly zero. Centred float64 data
# keeps ~1e-16 relative precision and float32 input ~1e-7 of the coordinates, so a
# thickness below 1e-6 of the extent is numerical noise, never a real dimension.
DEGENERATE_RATIO = 1e-6


@njit(cache=True, nogil=True)
def solve(a, b, rel_tol=0.0):
    """Solve ``a x = b`` (small, square) by Gaussian elimination with partial pivoting.

    Returns ``(x, ok)``; ``ok`` is False when a pivot is 0 (exactly singular, as LAPACK's
    gesv says) or at most ``rel_tol`` times the largest pivot met (numerically singular).
    """
    x = b.copy()
    return x, solve_in_place(a.copy(), x, rel_tol)


@njit(cache=True, nogil=True)
def solve_in_place(m, x, rel_tol=0.0):
    """:func:`solve` in the arrays given: ``m`` (``a``) is overwritten by the elimination,
    ``x`` (``b``) by the solution; returns ``ok`` (``x`` is not the solution when False).
    For loops that solve a small system each step without new arrays."""
    n = x.shape[0]
    largest = 0.0
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(m[row, col]) > abs(m[pivot, col]):
                pivot = row
        largest = max(largest, abs(m[pivot, col]))
        if m[pivot, col] == 0.0 or abs(m[pivot, col]) <= rel_tol * largest:
            return False
        if pivot != col:
            for k in range(n):
                m[col, k], m[pivot, k] = m[pivot, k], m[col, k]
            x[col], x[pivot] = x[pivot], x[col]
        for row in range(col + 1, n):
            f = m[row, col] / m[col, col]
            for k in range(col, n):
                m[row, k] -= f * m[col, k]
            x[row] -= f * x[col]
    for col in range(n - 1, -1, -1):
        s = x[col]
        for k in range(col + 1, n):
            s -= m[col, k] * x[k]
        x[col] = s / m[col, col]
    return True


@njit(cache=True, nogil=True)
def hesse_form(normal, d, scale):
    """``(normal, d)`` with ``d >= 0`` (see ``plane.orient_normal``); a plane through the
    origin (``|d|`` under 1e-12 of ``scale``) gets its largest normal component positive."""
    if abs(d) <= 1e-12 * scale:
        if normal[np.argmax(np.abs(normal))] < 0:
            return -normal, 0.0
        return normal.copy(), 0.0
    if d < 0:
        return -normal, -d
    return normal.copy(), d


@njit(cache=True, nogil=True)
def collinear(eigvals):
    """The ascending scatter eigenvalues of coincident or collinear points (no plane, no curve)."""
    return eigvals[2] <= 0.0 or eigvals[1] <= DEGENERATE_RATIO * DEGENERATE_RATIO * eigvals[2]


#: A plane's mean squared distance is refused beyond this many standard deviations of the
#: chi-square spread the sensor's noise alone gives it.
NOISE_CHI2_SIGMAS = 3.0

#: Standard deviations of the chi-square law above which a fit's mean square residual is
#: not the noise (4: a right model of any size exceeds it with probability < 1e-4).
CHI_SQUARE_SIGMAS = 4.0


@njit(cache=True, nogil=True)
def noise_rms_bound(sigma, dof, sigmas):
    """The largest rms that noise of rms ``sigma`` alone gives a fit with ``dof`` degrees of
    freedom, ``sigmas`` standard deviations up the chi-square law (the mean square over
    ``sigma**2`` has mean 1 and deviation ``sqrt(2 / dof)``):
    ``sigma sqrt(1 + sigmas sqrt(2 / dof))``, ``dof`` taken as at least 1. Its ``py_func``
    takes an array of ``dof`` too (one bound per region)."""
    return sigma * np.sqrt(1.0 + sigmas * np.sqrt(2.0 / np.maximum(dof, 1.0)))


@njit(cache=True, nogil=True)
def curvature_resolved(plane_squares, curved_squares, n, extra, sigmas):
    """Whether a curved model with ``extra`` parameters more than a plane lowers the sum
    of squared distances of ``n`` points from ``plane_squares`` to ``curved_squares`` by
    more than noise alone would (an F-test): were the points a plane, the drop would be
    the noise variance, estimated from the curved model's own residuals, times a
    chi-square of ``extra`` degrees of freedom; it must exceed that law's mean by
    ``sigmas`` of its deviations. With no degree of freedom left it counts as resolved."""
    dof = n - 3 - extra
    if dof <= 0:
        return True
    variance = curved_squares / dof
    return plane_squares - curved_squares > (extra + sigmas * np.sqrt(2.0 * extra)) * variance


@njit(cache=True, nogil=True)
def flat_by_quadric(gain, curvature_gain, n):
    """Whether a quadric height field's ``gain`` over a plane (plane rms / quadric rms,
    from ``n`` points) settles the plane without a curved fit: the gain is only an
    estimate of a cylinder's or sphere's (a ratio of two rms, each with relative spread
    about ``1 / sqrt(2 n)``), so it must stay one standard error of that ratio,
    ``1 / sqrt(n)``, below ``curvature_gain``. A large region is judged as before; a sliver
    of a few rows (a pipe's top at the grid's border: 71 points, gain 1.46 against a
    cylinder's 1.51) gets the curved fit that decides it. The callers pass ``n = inf`` (no
    margin) for a plane whose rms is over the sensor's noise model at its range: there the
    residuals are the surface's shape, not noise, and the gain is no sampling estimate."""
    return gain * (1.0 + 1.0 / np.sqrt(max(n, 1.0))) < curvature_gain


@njit(cache=True, nogil=True)
def quadric_resolved(gain, n):
    """Whether a quadric height field whose rms is the plane's over ``gain`` resolves a
    curvature over ``n`` points (:func:`curvature_resolved`, three parameters more than
    the plane: the noise is the quadric's own residual). Where the plane's rms is the
    sensor's noise its gain is small however many points there are: a pipe seen on a
    narrow arc bends by less than the noise, yet over hundreds of points that bend is no
    noise (spinning_64: 159 px, gain 1.25, 1.5 cm noise). No degree of freedom left (``n``
    up to 6) or ``n`` not finite: False (no evidence of a bend)."""
    if not (np.isfinite(n) and n > 6.0):
        return False
    if not gain > 1.0:
        return False
    return curvature_resolved(gain * gain, 1.0, n, 3, CHI_SQUARE_SIGMAS)


@njit(cache=True, nogil=True)
def plane_tolerance(plane_rms, noise_floor, n):
    """A plane's rms threshold over ``n`` points: ``plane_rms``, or what range noise of
    ``noise_floor`` (m) alone gives the fit when larger, ``NOISE_CHI2_SIGMAS`` standard
    deviations up its chi-square over ``n - 3`` degrees of freedom
    (:func:`noise_rms_bound`). The bound tightens as the points grow (a thousand-pixel
    wall: 1.07 noise sigmas, a hundred points 1.20, twenty 1.42)."""
    if noise_floor <= 0.0:
        return plane_rms
    return max(plane_rms, noise_rms_bound(noise_floor, n - 3.0, NOISE_CHI2_SIGMAS))