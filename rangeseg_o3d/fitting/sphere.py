"""Sphere: algebraic least-squares start, then geometric Levenberg-Marquardt refinement."""

from __future__ import annotations

import numpy as np

from ._codes import INLIERS, RADIUS, RMS
from ._common import Prepared, refusal
from .primitives import FitFailure, Sphere

__all__ = ["fit_sphere", "sphere_cap_angle"]


def sphere_cap_angle(points: np.ndarray, center: np.ndarray) -> float:
    """Full opening angle (radians) of the cap the points cover, seen from ``center``.

    Twice the largest angle between a point's direction and the mean direction; 2*pi
    when the mean direction vanishes (points all round the sphere).
    """
    from ._compiled import cap_angle

    return float(cap_angle(np.ascontiguousarray(points, dtype=float), np.asarray(center, float)))


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
    return sphere_from_prepared(Prepared(points, "sphere", 4, inlier_distance), max_iterations)


def sphere_from_prepared(prep: Prepared, max_iterations: int = 30) -> Sphere | FitFailure:
    """:func:`fit_sphere` on points already checked, centred, scaled and decomposed."""
    from ._decide import sphere_checked

    if prep.failure is not None:
        return prep.failure
    scale = prep.scale
    inlier_q = np.inf if prep.inlier_distance is None else prep.inlier_distance / scale
    code, result = sphere_checked(np.ascontiguousarray(prep.q), prep.eigvals, int(max_iterations),
                                  float(inlier_q), np.full(7, np.nan), np.inf)
    if code:
        return FitFailure("sphere", refusal("sphere", code, result, scale=scale, plane_rms=prep.eigen_rms,
                                            n=len(prep.q), minimum=4, max_iterations=max_iterations))
    return sphere_model(result, prep.centroid, scale)


def sphere_model(result: np.ndarray, centroid: np.ndarray, scale: float) -> Sphere:
    """The Sphere of a checked result row (scaled frame about ``centroid``)."""
    values = result.tolist()  # Python floats: the scalar arithmetic below costs less
    return Sphere(center=centroid + scale * result[:3], radius=values[RADIUS] * scale,
                  rms=values[RMS] * scale, inliers=int(values[INLIERS]))
