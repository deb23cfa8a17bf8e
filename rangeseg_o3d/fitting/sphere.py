"""Sphere: algebraic least-squares start, then geometric Levenberg-Marquardt refinement."""

from __future__ import annotations

import numpy as np

from ._common import (
    Prepared,
    count_within,
    curvature_failure,
    refinement_failure,
)
from .models import FitFailure, Sphere

__all__ = ["fit_sphere", "sphere_algebraic", "sphere_cap_angle"]


def sphere_algebraic(q: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Linear least-squares sphere ``(center, radius)`` of centred, scaled points ``q``.

    Paper Sec. 4.2 with its errata: ``|p|^2 = 2 p . c - t`` with
    ``t = |c|^2 - r^2``, solved with lstsq (not the normal equations). Returns None
    when the system is rank deficient (coplanar points) or ``r^2 <= 0``.
    """
    design = np.empty((len(q), 4))
    design[:, :3] = 2.0 * q
    design[:, 3] = -1.0
    rhs = np.einsum("ij,ij->i", q, q)
    solution, _, rank, _ = np.linalg.lstsq(design, rhs, rcond=None)
    if rank < 4:
        return None
    center, t = solution[:3], solution[3]
    radius_sq = center @ center - t
    if not np.isfinite(radius_sq) or radius_sq <= 0:
        return None
    return center, float(np.sqrt(radius_sq))


def _refine(q: np.ndarray, center: np.ndarray, radius: float, max_iterations: int):
    """Levenberg-Marquardt on orthogonal distances ``|q - c| - r``; (center, radius, converged)."""
    from ._compiled import sphere_lm

    center, radius, converged = sphere_lm(np.ascontiguousarray(q), np.asarray(center, float),
                                          float(radius), int(max_iterations))
    return center, float(radius), bool(converged)


def sphere_cap_angle(points: np.ndarray, center: np.ndarray) -> float:
    """Full opening angle (radians) of the cap the points cover, seen from ``center``.

    Twice the largest angle between a point's direction and the mean direction; 2*pi
    when the mean direction vanishes (points all round the sphere).
    """
    rel = np.asarray(points, float) - center
    unit = rel / np.linalg.norm(rel, axis=1, keepdims=True)
    mean = unit.mean(axis=0)
    norm = np.linalg.norm(mean)
    if norm < 1e-9:
        return 2 * np.pi
    cosines = np.clip(unit @ (mean / norm), -1.0, 1.0)
    return float(2.0 * np.arccos(cosines.min()))


def fit_sphere(
    points,
    *,
    max_iterations: int = 30,
    inlier_distance: float | None = None,
) -> Sphere | FitFailure:
    """Fit a sphere minimising the orthogonal distances ``|p - c| - r``.

    The algebraic linear least-squares solution (paper Sec. 4.2, corrected) on
    centred and scaled coordinates starts a Levenberg-Marquardt refinement of the
    geometric distances (the algebraic fit is biased on the partial caps a scanner sees).

    Guard against false spheres: when the curvature the sphere adds over the patch
    (the sagitta ``r (1 - cos(cap/2))``) is not larger than the fit's rms, a plane
    explains the points as well and the fit fails; a noisy plane therefore never
    becomes a huge sphere.

    Parameters
    ----------
    points : (N, 3) array_like
        At least 4 points, not coplanar.
    max_iterations : int
        Levenberg-Marquardt iterations (3-8 are typical from the algebraic start).
    inlier_distance : float, optional
        Count as inliers only points within this distance of the surface (default: all).

    Returns
    -------
    Sphere or FitFailure
        FitFailure (falsy, with a reason) on fewer than 4 points, NaN/inf, coplanar or
        collinear points, insignificant curvature, or no convergence.

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.]])
    >>> s = fit_sphere(pts + 2)
    >>> np.round(s.center, 6).tolist(), round(s.radius, 6)
    ([2.0, 2.0, 2.0], 1.0)
    """
    return sphere_from_prepared(Prepared(points, "sphere", 4, inlier_distance, curved=True),
                                max_iterations)


def sphere_from_prepared(prep: Prepared, max_iterations: int = 30) -> Sphere | FitFailure:
    """:func:`fit_sphere` on points already checked, centred, scaled and decomposed."""
    if prep.failure is not None:
        return prep.failure
    q, scale = prep.q, prep.scale
    start = sphere_algebraic(q)
    if start is None:
        return FitFailure("sphere", "the algebraic sphere system is singular (coplanar points)")
    center, radius, converged = _refine(q, start[0], start[1], max_iterations)
    failure = refinement_failure("sphere", converged, max_iterations, center, radius)
    if failure is not None:
        return failure
    dist = np.linalg.norm(q - center, axis=1) - radius
    rms = float(np.sqrt(dist @ dist / len(q)))
    failure = curvature_failure(prep, "sphere", radius, sphere_cap_angle(q, center), rms)
    if failure is not None:
        return failure
    return Sphere(
        center=prep.centroid + scale * center,
        radius=float(radius * scale),
        rms=rms * scale,
        inliers=count_within(dist * scale, prep.inlier_distance),
    )
