"""Least-squares plane: centroid and the smallest-eigenvalue eigenvector of the scatter."""

from __future__ import annotations

import numpy as np

from ._common import Prepared
from .primitives import FitFailure, Plane

__all__ = ["fit_plane", "orient_normal"]

UNDETERMINED = "points are coincident or collinear: the plane is undetermined"


def orient_normal(normal: np.ndarray, d: float, scale: float = 1.0) -> tuple[np.ndarray, float]:
    """Orient ``(normal, d)`` so that ``d >= 0`` (Hesse normal form).

    The normal then points away from the origin (the sensor), and ``d`` is the distance of
    the origin from the plane. A plane through the origin (``|d|`` below 1e-12 of
    ``scale``) is oriented so that its largest normal component is positive.
    """
    from ..kernels.linalg import hesse_form

    oriented, distance = hesse_form(np.asarray(normal, dtype=np.float64), float(d), float(scale))
    return oriented, float(distance)


def fit_plane(points, *, inlier_distance: float | None = None) -> Plane | FitFailure:
    """Fit the plane ``normal . p = d`` minimising the orthogonal distances.

    The normal is the eigenvector of the smallest eigenvalue of the centred scatter
    matrix (paper Sec. 4.1 with its erratum); that eigenvalue is the residual sum of
    squares. The plane is given in Hesse normal form: unit normal, ``d >= 0``, so the
    normal points away from the origin (see :func:`orient_normal`).

    Parameters
    ----------
    points : (N, 3) array_like
        Points in metres (any unit works; ``d`` and ``rms`` come out in it).
    inlier_distance : float, optional
        Count as inliers only the points within this distance of the plane; by default
        every point is an inlier.

    Returns
    -------
    Plane or FitFailure
        The plane with the rms orthogonal distance, or a falsy FitFailure saying why
        not: fewer than 3 points, NaN/inf coordinates, coincident or collinear points.

    Raises
    ------
    ValueError
        If ``points`` is not (N, 3).
    TypeError
        If ``points`` is not numeric.

    Examples
    --------
    >>> plane = fit_plane([[0, 0, 2], [1, 0, 2], [0, 1, 2], [1, 1, 2]])
    >>> plane.normal.tolist(), round(plane.d, 6), round(plane.rms, 6)
    ([0.0, 0.0, 1.0], 2.0, 0.0)
    """
    return plane_from_prepared(Prepared(points, "plane", 3, inlier_distance))


def plane_from_prepared(prep: Prepared) -> Plane | FitFailure:
    """:func:`fit_plane` on points already checked, centred, scaled and decomposed."""
    from ._compiled import plane_of

    if prep.failure is not None:
        return prep.failure
    # rms from the distances, not the eigenvalue: the eigenvalue carries an absolute
    # rounding error of ~1e-16, i.e. a 1e-8 rms floor on exact data
    limit = np.inf if prep.inlier_distance is None else prep.inlier_distance
    ok, normal, d, rms, inliers = plane_of(prep.q, prep.points, prep.centroid, prep.scale, prep.eigvals,
                                           prep.eigvecs, limit)
    if not ok:
        return FitFailure("plane", UNDETERMINED)
    return Plane(normal=normal, d=float(d), rms=float(rms), inliers=int(inliers))
