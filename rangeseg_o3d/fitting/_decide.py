"""Compiled checks of the curved fits and the plane -> cylinder -> sphere decision.

Every test that refuses a model lives here, as a code of :mod:`._codes` (``ACCEPTED`` or
the reason); :func:`rangeseg_o3d.fitting._common.refusal` words a code and its numbers.
The public sphere and cylinder fits (:mod:`.sphere`, :mod:`.cylinder`) and the decision
of :func:`rangeseg_o3d.fitting.classify.fit_primitive` (:func:`primitive_decision`) call
the same checks, so a model passes or fails for the same reason on every path. The
decision runs as one call: a few hundred points cost tens of microseconds, where the
same steps as separate numpy calls cost several times that in call overhead;
:func:`decide` hands its answer back as a :class:`Decision` with named fields. Model
kinds are those of :mod:`rangeseg_o3d.kernels.kinds` (PLANE, SPHERE, CYLINDER; NONE for
no model).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from ..kernels.jit import njit  # numba.njit, with this package's cache locator installed

from ..kernels.kinds import CYLINDER, NONE, PLANE, SPHERE
from ..kernels.labelwise import height_field_shape
from ..kernels.linalg import (CHI_SQUARE_SIGMAS, DEGENERATE_RATIO, NOISE_CHI2_SIGMAS, collinear, curvature_resolved,
                              flat_by_quadric, noise_rms_bound, plane_tolerance,
                              quadric_resolved)
from ._codes import (  # noqa: F401 -- callers and tests read the codes as _decide.X too
    ACCEPTED, ARC, ARC_UNDER, COLLINEAR, CONVERGED, COPLANAR, CURVED_SIZE, DIVERGED, FLAT,
    GAIN_UNDER, INLIERS, MIN_POINTS, NON_FINITE, NOT_CONVERGED, NO_BETTER, RADIUS,
    RADIUS_LIMIT, RADIUS_OVER, RMS, RMS_OVER, RUNAWAY, SINGULAR, TOO_FEW,
)
from ._compiled import (
    cylinder_core,
    cylinder_refine,
    plane_of,
    prepare_points,
    sphere_core,
    sphere_refine,
)

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("_codes.py", "_compiled.py", "../kernels/grid.py", "../kernels/inline.py", "../kernels/kinds.py",
                 "../kernels/labelwise.py", "../kernels/linalg.py")


@njit(cache=True, nogil=True)
def flatness_code(eigvals):
    """COLLINEAR or COPLANAR from the ascending scatter eigenvalues, else ACCEPTED."""
    if collinear(eigvals):
        return COLLINEAR
    if eigvals[0] <= DEGENERATE_RATIO * DEGENERATE_RATIO * eigvals[2]:
        return COPLANAR
    return ACCEPTED


@njit(cache=True, nogil=True)
def _input_code(q, minimum, eigvals):
    # enough points, spread in three dimensions
    if q.shape[0] < minimum:
        return TOO_FEW
    return flatness_code(eigvals)


@njit(cache=True, nogil=True)
def _outcome_code(result, plane_rms):
    # After Levenberg-Marquardt: did it converge to a finite model, and does that model
    # bend away from the plane by more than its rms (the sagitta r (1 - cos(arc / 2)),
    # arc capped at pi)? All in the scaled frame; ``plane_rms`` from the smallest eigenvalue.
    radius = result[RADIUS]
    if np.isfinite(radius) and radius > RADIUS_LIMIT:
        return RUNAWAY
    if result[CONVERGED] < 0.0:  # given up far above the threshold
        return RMS_OVER
    if result[CONVERGED] == 0.0:
        return NOT_CONVERGED
    if not np.all(np.isfinite(result[:RADIUS + 1])) or radius <= 0:
        return DIVERGED
    if result[RMS] >= plane_rms:
        return NO_BETTER
    if radius * (1.0 - np.cos(min(result[ARC], np.pi) / 2.0)) > result[RMS]:
        return ACCEPTED
    return FLAT


@njit(cache=True, nogil=True)
def _eigen_rms(eigvals, n):
    return np.sqrt(max(eigvals[0], 0.0) / n)


@njit(cache=True, nogil=True)
def _statistics_code(result, radius, rms, inliers, arc, converged, eigvals, n):
    # store a fit's statistics in its row; the code of its outcome
    result[RADIUS], result[RMS], result[INLIERS], result[ARC] = radius, rms, inliers, arc
    result[CONVERGED] = converged
    return _outcome_code(result, _eigen_rms(eigvals, n))


# inline into _curved_try (see _compiled.sphere_core); the public fits' calls compile it alone
@njit(cache=True, nogil=True, inline="always")
def cylinder_checked(q, eigvals, axis_hint, hemisphere, hemi_u, hemi_v, hemi_s, cones,
                     max_iterations, inlier_distance, start, give_up_rms):
    """Cylinder on centred, scaled ``q`` with every check: ``(code, result)``.

    ``start`` is ``(axis, point, radius)`` in the scaled frame (7 values) to refine from,
    or NaN for the axis search (``axis_hint``: NaN, or an axis to start from). ``result``
    holds axis, point, radius, rms, inliers, arc and converged (slots of CURVED_SIZE).
    ``give_up_rms`` (scaled; inf for never): Levenberg-Marquardt stops creeping at an rms
    over twice it, and the code is RMS_OVER.
    """
    result = np.full(CURVED_SIZE, np.nan)
    code = _input_code(q, MIN_POINTS[CYLINDER], eigvals)
    if code != ACCEPTED:
        return code, result
    if np.isfinite(start[6]):
        axis, point, radius, converged, rms, arc, inliers = cylinder_refine(
            q, start[:3].copy(), start[3:6].copy(), start[6], max_iterations, inlier_distance, give_up_rms)
    else:
        axis, point, radius, converged, rms, arc, inliers = cylinder_core(
            q, axis_hint, hemisphere, hemi_u, hemi_v, hemi_s, cones, max_iterations, inlier_distance,
            give_up_rms)
    result[:3] = axis
    result[3:6] = point
    return _statistics_code(result, radius, rms, inliers, arc, converged, eigvals, q.shape[0]), result


# inline into _curved_try (see _compiled.sphere_core); the public fits' calls compile it alone
@njit(cache=True, nogil=True, inline="always")
def sphere_checked(q, eigvals, max_iterations, inlier_distance, start, give_up_rms):
    """Sphere on centred, scaled ``q`` with every check: ``(code, result)``.

    ``start`` is ``(center, radius)`` in the scaled frame (4 values), or NaN for the
    algebraic start. ``result`` holds the centre in slots 0-2, then as for cylinders.
    """
    result = np.full(CURVED_SIZE, np.nan)
    code = _input_code(q, MIN_POINTS[SPHERE], eigvals)
    if code != ACCEPTED:
        return code, result
    if np.isfinite(start[3]):
        ok, center, radius, converged, rms, cap, inliers = sphere_refine(
            q, start[:3].copy(), start[3], max_iterations, inlier_distance, give_up_rms)
    else:
        ok, center, radius, converged, rms, cap, inliers = sphere_core(q, max_iterations, inlier_distance,
                                                                        give_up_rms)
    if not ok:
        return SINGULAR, result
    result[:3] = center
    result[3:6] = 0.0
    return _statistics_code(result, radius, rms, inliers, cap, converged, eigvals, q.shape[0]), result


#: Plane distances, in the plane's rms, beyond which a point is left out of the bend test
#: (a pixel of a neighbouring face, or a mixed one at a jump, that a quadric bends to).
BEND_TRIM = 2.0


@njit(cache=True, nogil=True)
def incidence_rms(points, normal):
    """The rms of ``normal . ray`` over the viewing rays of ``points`` (seen from the origin,
    the sensor): a range noise ``sigma`` along the rays moves the points off their plane by
    ``sigma`` times it. A plane seen obliquely keeps most of its range noise within itself."""
    total = 0.0
    n = points.shape[0]
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        length = np.sqrt(x * x + y * y + z * z)
        if length > 0.0:
            c = (x * normal[0] + y * normal[1] + z * normal[2]) / length
            total += c * c
    return np.sqrt(total / max(n, 1))


@njit(cache=True, nogil=True)
def bend_resolved(q, normal, rms, samples=1.0):
    """Whether the quadric height field of the centred points ``q`` resolves a bend
    (:func:`quadric_resolved`, each point counting ``samples`` independent samples) once
    the points farther than ``BEND_TRIM`` times ``rms`` from their plane (``normal``,
    through their centroid; ``rms`` in ``q``'s units: the plane's own, or the noise the
    sensor gives its distances when smaller, :func:`bend_trim`) are left out and the
    plane is fitted again: a pipe's bend is in every point, a few pixels of a neighbouring
    face are not."""
    n = q.shape[0]
    keep = np.empty(n, np.bool_)
    for i in range(n):
        keep[i] = abs(q[i, 0] * normal[0] + q[i, 1] * normal[1] + q[i, 2] * normal[2]) <= BEND_TRIM * rms
    kept = q[keep]
    m = kept.shape[0]
    if m <= 6:
        return False
    centred = kept - kept.sum(axis=0) / m
    _, vectors = np.linalg.eigh(centred.T @ centred)
    gain, _ = height_field_shape(centred, vectors[:, 0].copy(), vectors[:, 1].copy(), vectors[:, 2].copy())
    return quadric_resolved(gain, m * samples)


@njit(cache=True, nogil=True)
def bend_trim(points, normal, rms, noise):
    """The distance scale of :func:`bend_resolved`'s trim for ``points`` (world, the sensor
    at the origin) about their plane (``normal``, rms ``rms``) under a range noise ``noise``
    along the rays (0: not known): the plane's rms, or what that noise gives its distances
    (``noise`` x :func:`incidence_rms`) when smaller. Mixed pixels at a jump and a
    neighbour's pixels raise the plane's own rms, and a trim at twice it keeps some of them
    (noise_20mm seed 89 scan 5: a box face seen at 60 degrees, plane rms 16 mm where its
    noise gives 10, seven mixed pixels 24-43 mm off bent its quadric into a 1 m cylinder)."""
    if noise <= 0.0:
        return rms
    return min(rms, noise * incidence_rms(points, normal))


#: The least share of its sagitta that an arc leaves as the rms of its points about their
#: plane: points spread evenly along a shallow arc leave sqrt(4 / 45) ~ 0.3 of it (the
#: spread of a parabola's height over its chord); a third of that for uneven spreads.
ARC_RMS_SHARE = 0.1


@njit(cache=True, nogil=True)
def arc_hidden(rms, spread, min_arc):
    """Whether a plane of ``rms`` is too close to points whose in-plane standard deviation
    is at least ``spread`` (both in one unit) for any arc of ``min_arc`` or more
    (radians) across them: such an arc's chord is at least ``2 spread`` wide (a width is at
    least twice the deviation along it), its sagitta at least ``spread tan(min_arc / 4)``
    (over half a circle, the radius), and its points leave about ``ARC_RMS_SHARE`` of that
    about their plane. A necessary condition of every curved model the decision accepts
    (cylinder arc and sphere cap are held to ``min_arc`` over all the points), cheap where
    the models' searches are not: a wide wall within the noise whose quadric resolves a
    bend of a few millimetres is no pipe the decision could accept."""
    return rms < ARC_RMS_SHARE * spread * np.tan(0.25 * min_arc)


@njit(cache=True, nogil=True)
def judge_code(rms, radius, arc, tolerance, max_radius, min_arc, curvature_gain, plane_rms):
    """The decision's own tests of a fitted curved model (metres, radians)."""
    if rms > tolerance:
        return RMS_OVER
    if radius > max_radius:
        return RADIUS_OVER
    if arc < min_arc:
        return ARC_UNDER
    if rms > 0 and plane_rms < curvature_gain * rms:
        return GAIN_UNDER
    return ACCEPTED


@njit(cache=True, nogil=True)
def _curved_try(kind, q, eigvals, scale, axis_hint, hemisphere, hemi_u, hemi_v, hemi_s, cones,
                max_iterations, inlier_distance, start, tolerance, max_radius, min_arc,
                curvature_gain, plane_rms):
    # kind CYLINDER or SPHERE; the check then, for a model, the decision's judgement
    if kind == CYLINDER:
        code, result = cylinder_checked(q, eigvals, axis_hint, hemisphere, hemi_u, hemi_v, hemi_s,
                                        cones, max_iterations, inlier_distance / scale, start,
                                        tolerance / scale)
    else:
        code, result = sphere_checked(q, eigvals, max_iterations, inlier_distance / scale, start,
                                      tolerance / scale)
    if code == ACCEPTED:
        code = judge_code(result[RMS] * scale, result[RADIUS] * scale, result[ARC], tolerance,
                          max_radius, min_arc, curvature_gain, plane_rms)
    return code, result


@njit(cache=True, nogil=True, inline="always")
def _other_curved(kind):
    return SPHERE if kind == CYLINDER else CYLINDER


@njit(cache=True, nogil=True)
def primitive_decision(points, axis_hint, hemisphere, hemi_u, hemi_v, hemi_s, cones, plane_rms,
                       cylinder_rms, sphere_rms, rms_per_range2, max_radius, min_arc,
                       curvature_gain, inlier_factor, roundness_cylinder, roundness_sphere,
                       max_iterations, noise_floor=0.0, bends=0.0):
    """The decision rule of ``classify.fit_primitive`` on (N >= 3, 3) points (``bends``:
    its ``resolve_bends``, the independent samples each point carries; 0: not asked).

    Returns the fields of :class:`Decision` in order (call it through :func:`decide`).
    """
    n_bad, centroid, scale, q, eigvals, eigvecs = prepare_points(points)
    n = q.shape[0]
    extra = rms_per_range2 * (centroid @ centroid)
    plane_tol = plane_tolerance(plane_rms, noise_floor, n) + extra
    codes = np.full(4, -1, np.int64)
    curved = np.full((4, CURVED_SIZE), np.nan)
    if n_bad:
        return (NONE, NON_FINITE, NONE, centroid, scale, np.full(3, np.nan), np.nan, np.nan, plane_tol,
                np.nan, 0, codes, curved)
    eigen_rms = _eigen_rms(eigvals, n) * scale
    ok, normal, d, rms, inliers = plane_of(q, points, centroid, scale, eigvals, eigvecs,
                                           inlier_factor * plane_tol)
    if not ok:
        return NONE, COLLINEAR, NONE, centroid, scale, normal, d, rms, plane_tol, eigen_rms, inliers, codes, curved
    plane_ok = rms <= plane_tol
    # A plane over the noise itself, accepted only within its chi-square spread, is no
    # better explained than a curved model that stays within the noise: the curved ones are
    # tried too and need only to beat it (a far cylinder whose curvature the noise hides).
    marginal = plane_ok and rms > max(plane_rms, noise_floor) + extra
    # A plane accepted only by a threshold above the noise (a preset's plane_rms over a
    # quiet sensor's noise), yet beyond what that noise gives n points, is no better
    # explained either: a curved model within that bound needs only to beat it (a column
    # piece whose curvature the plane threshold hides).
    bound = np.inf  # the curved models' own thresholds
    if plane_ok and not marginal and noise_floor > 0.0:
        noise_bound = noise_rms_bound(noise_floor + extra, n - 3.0, NOISE_CHI2_SIGMAS)
        if rms > noise_bound:
            marginal, bound = True, noise_bound
    # The floor keeps rounding-level residuals of exact planes from looking "curved".
    gain, roundness = 1.0, 0.5
    if rms > 0.1 * plane_tol:
        gain, roundness = height_field_shape(q, normal, eigvecs[:, 1].copy(), eigvecs[:, 2].copy())
    # the quadric's gain is uncertain only where the plane's rms is the noise's
    within = rms <= noise_floor + extra
    flat = plane_ok and flat_by_quadric(gain, curvature_gain, n if within else np.inf) and not marginal
    # A plane within the noise whose quadric resolves a bend all the same (a pipe seen on a
    # narrow arc): its gain cannot reach curvature_gain, so a curved model needs only to
    # beat the plane and resolve its own curvature; failing that it stays a plane. (Over
    # the noise the quadric also bends to a few pixels of a neighbouring face.)
    # (the search for curved models is costly: first whether any could be accepted)
    samples = n * bends  # the independent samples among the points (correlated noise: fewer)
    # the trim of the bend test at the noise the sensor gives the plane's distances, where
    # each point is a sample of that noise of its own (correlated means scatter by more)
    trim_noise = noise_floor + extra if bends >= 1.0 else 0.0
    # Where the points' noise errs together (under one independent sample each: a stereo
    # camera's tile means) within the noise is also an rms that noise gives the n points up
    # its chi-square, the bound over which the plane is marginal above: between the noise and
    # that bound the quadric's gain is as uncertain, and the F-test over the samples decides
    # (stereo seed 37 scan 0: a 17 cm pipe at 4.6 m, its plane 0.8 mm over the noise, was
    # settled flat). Single returns keep the noise itself: over it a laser's plane holds a
    # neighbour's or mixed pixels its quadric bends to (spinning_64x1024 seed 11 scan 1: a
    # 140 px wall, 17.3 mm rms over 15 mm noise, became a 0.35 m cylinder).
    noisy = within or (0.0 < bends < 1.0 and noise_floor > 0.0
                       and rms <= noise_rms_bound(noise_floor + extra, n - 3.0, NOISE_CHI2_SIGMAS))
    bent = (flat and bends > 0.0 and noisy and quadric_resolved(gain, samples)
            and not arc_hidden(rms, np.sqrt(max(eigvals[1], 0.0) / n) * scale, min_arc)
            and bend_resolved(q, normal, bend_trim(points, normal, rms, trim_noise) / scale, bends))
    if flat and not bent:
        return PLANE, ACCEPTED, NONE, centroid, scale, normal, d, rms, plane_tol, eigen_rms, inliers, codes, curved
    needed_gain = 1.0 if marginal or bent else curvature_gain
    # Principal curvatures pick the likely model: tried first, the other only if it fails.
    first, decisive = CYLINDER, False
    if roundness <= roundness_cylinder:
        decisive = True
    elif roundness >= roundness_sphere:
        first, decisive = SPHERE, True
    no_start = np.full(7, np.nan)
    best, best_rms = NONE, np.inf
    for kind in (first, _other_curved(first)):
        tolerance = min((cylinder_rms if kind == CYLINDER else sphere_rms) + extra, bound)
        codes[kind], curved[kind] = _curved_try(
            kind, q, eigvals, scale, axis_hint, hemisphere, hemi_u, hemi_v, hemi_s, cones,
            max_iterations, inlier_factor * tolerance, no_start, tolerance, max_radius, min_arc,
            needed_gain, rms)
        if codes[kind] == ACCEPTED and (np.isfinite(bound) or bent):
            # over a plane beyond the noise, a curvature the points resolve (not the
            # bend of two more parameters over noise or a sliver of another face)
            curved_rms = curved[kind, RMS] * scale
            m = samples if bent else n
            if not curvature_resolved(m * rms * rms, m * curved_rms * curved_rms, m,
                                      2 if kind == CYLINDER else 1, CHI_SQUARE_SIGMAS):
                codes[kind] = GAIN_UNDER
        if codes[kind] == ACCEPTED:
            if curved[kind, RMS] < best_rms:
                best, best_rms = kind, curved[kind, RMS]
            if decisive:
                break
    if best == NONE and plane_ok:
        best = PLANE
    return best, ACCEPTED, first, centroid, scale, normal, d, rms, plane_tol, eigen_rms, inliers, codes, curved


class Decision(NamedTuple):
    """The answer of :func:`decide`, by name (lengths in metres unless said)."""

    kind: int
    """The model chosen: PLANE, CYLINDER or SPHERE; NONE when no model is acceptable."""
    status: int
    """ACCEPTED when a decision was made; NON_FINITE (a point is NaN or infinite, nothing
    else computed) or COLLINEAR (the points determine no plane, nothing decided)."""
    first: int
    """The curved kind tried first (NONE when no curved model was needed)."""
    centroid: np.ndarray
    """Origin of the scaled frame of the curved results."""
    scale: float
    """Scale of that frame (its lengths times ``scale`` are metres)."""
    normal: np.ndarray
    """The least-squares plane's unit normal (Hesse form, ``d >= 0``)."""
    d: float
    plane_rms: float
    """The plane's rms orthogonal distance."""
    plane_tolerance: float
    """The plane's rms threshold, grown for the patch's range."""
    eigen_rms: float
    """The best plane's rms from the smallest scatter eigenvalue (the curved fits' own tests use it)."""
    plane_inliers: int
    codes: np.ndarray
    """Per kind (index CYLINDER or SPHERE): the outcome code of the curved model tried; -1 not tried."""
    curved: np.ndarray
    """Per kind: the curved model's result row (:data:`CURVED_SIZE` slots, scaled frame)."""

    def other_curved(self) -> int:
        """The curved kind tried second."""
        return SPHERE if self.first == CYLINDER else CYLINDER


def decide(*args) -> Decision:
    """:func:`primitive_decision` (same arguments) with its answer as a :class:`Decision`."""
    return Decision._make(primitive_decision(*args))


@njit(cache=True, nogil=True)
def curved_refit(kind, points, start, base_tolerance, rms_per_range2, max_radius, min_arc,
                 curvature_gain, inlier_factor, max_iterations):
    """``refit_primitive`` for a CYLINDER or SPHERE ``kind`` from ``start``
    (world coordinates: cylinder axis, point, radius; sphere centre, radius).

    Returns ``(code, centroid, scale, result, tolerance, plane_rms)``: the threshold
    grown for the patch's range, and the plane rms from the smallest scatter eigenvalue
    (metres), which the curvature-gain test compares with; ``code`` is NON_FINITE, and
    nothing else computed, when a point is NaN or infinite.
    """
    n_bad, centroid, scale, q, eigvals, _ = prepare_points(points)
    plane_rms = _eigen_rms(eigvals, q.shape[0]) * scale
    tolerance = base_tolerance + rms_per_range2 * (centroid @ centroid)
    if n_bad:
        return NON_FINITE, centroid, scale, np.full(CURVED_SIZE, np.nan), tolerance, plane_rms
    local = np.full(7, np.nan)
    if kind == CYLINDER:
        local[:3] = start[:3]
        local[3:6] = (start[3:6] - centroid) / scale
        local[6] = start[6] / scale
    else:
        local[:3] = (start[:3] - centroid) / scale
        local[3] = start[3] / scale
    empty = np.empty((0, 3))
    code, result = _curved_try(kind, q, eigvals, scale, np.full(3, np.nan), empty, empty, empty,
                               np.empty((0, 6)), ((empty, empty, empty), (empty, empty, empty)),
                               max_iterations, inlier_factor * tolerance, local, tolerance,
                               max_radius, min_arc, curvature_gain, plane_rms)
    return code, centroid, scale, result, tolerance, plane_rms
