"""Cylinder: axis start (surface normals or a moment-based direction search), circle fit,
then geometric Levenberg-Marquardt refinement of axis, axis point and radius."""

from __future__ import annotations

import functools

import numpy as np

from ._codes import INLIERS, RADIUS, RMS
from ._common import Prepared, as_points, refusal
from .primitives import Cylinder, FitFailure

__all__ = ["fit_cylinder", "axis_from_normals", "cylinder_arc"]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (M, 3) arrays (np.cross is slow on small inputs)."""
    return np.stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ],
        axis=1,
    )


def _perpendicular_bases(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors ``u, v`` (each (M, 3)) completing each unit direction to a right-handed frame."""
    helper = np.zeros_like(directions)
    use_y = np.abs(directions[:, 0]) > 0.9
    helper[~use_y, 0] = 1.0
    helper[use_y, 1] = 1.0
    u = _cross(directions, helper)
    u /= np.sqrt((u * u).sum(axis=1))[:, None]
    return u, _cross(directions, u)


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``u, v`` completing one unit ``axis`` to a right-handed frame."""
    x, y, z = axis
    if abs(x) <= 0.9:  # u = axis x e_x
        u = np.array([0.0, z, -y])
    else:  # u = axis x e_y
        u = np.array([-z, 0.0, x])
    u /= np.sqrt(u @ u)
    v = np.array([y * u[2] - z * u[1], z * u[0] - x * u[2], x * u[1] - y * u[0]])
    return u, v


@functools.lru_cache(maxsize=4)
def _hemisphere(n: int) -> np.ndarray:
    """``n`` near-uniform unit directions with z >= 0 (Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = 1.0 - i / n
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    rho = np.sqrt(1.0 - z * z)
    dirs = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    dirs.setflags(write=False)
    return dirs


@functools.lru_cache(maxsize=8)
def _cone_template(half_angle: float, rings: int = 4, per_ring: int = 12):
    """Directions on rings around +z up to ``half_angle`` (radians), +z included, with frames."""
    angles = np.repeat(np.linspace(half_angle / rings, half_angle, rings), per_ring)
    phis = (np.linspace(0.0, 2 * np.pi, per_ring, endpoint=False)[None, :] + 0.5 * np.arange(rings)[:, None]).ravel()
    dirs = np.stack([np.sin(angles) * np.cos(phis), np.sin(angles) * np.sin(phis), np.cos(angles)], axis=1)
    dirs = np.vstack([[0.0, 0.0, 1.0], dirs])
    u, v = _perpendicular_bases(dirs)
    return dirs, u, v


def _projector_coefficients(directions: np.ndarray) -> np.ndarray:
    """Coefficients of ``|P x|^2`` (P = I - w w^T) on the monomials x2 y2 z2 xy xz yz."""
    wx, wy, wz = directions[:, 0], directions[:, 1], directions[:, 2]
    return np.stack([1 - wx * wx, 1 - wy * wy, 1 - wz * wz, -2 * wx * wy, -2 * wx * wz, -2 * wy * wz], axis=1)


@functools.lru_cache(maxsize=1)
def _search_grids():
    """Hemisphere directions with frames and projector coefficients, and the two cone
    templates (8 and 2 deg), computed once."""
    # A writable copy: compiled code passes writable (empty) grids to the same kernels when it
    # refits, and numba compiles a read-only array as another type, so a read-only grid here
    # would compile the whole cylinder search twice.
    dirs = np.array(_hemisphere(300))
    u, v = _perpendicular_bases(dirs)
    cones = tuple(_cone_template(np.radians(angle)) for angle in (8.0, 2.0))
    return dirs, u, v, _projector_coefficients(dirs), cones


def axis_from_normals(normals: np.ndarray) -> np.ndarray | None:
    """Direction most perpendicular to all surface normals (smallest eigenvector of sum n n^T).

    Rows that are not finite or have zero length are ignored; None when fewer than two
    usable normals remain or they are all parallel (a plane: the axis is undetermined).
    """
    norms = np.linalg.norm(normals, axis=1)
    good = np.isfinite(norms) & (norms > 0)
    if good.sum() < 2:
        return None
    unit = normals[good] / norms[good, None]
    eigvals, eigvecs = np.linalg.eigh(unit.T @ unit)
    if eigvals[1] <= 1e-6 * eigvals[2]:
        return None
    return eigvecs[:, 0]


def cylinder_arc(points: np.ndarray, axis: np.ndarray, point: np.ndarray) -> float:
    """Arc (radians, 0 to 2*pi) of the cross-section circle that the points cover.

    2*pi minus the largest angular gap between consecutive points around the axis.
    """
    from ._compiled import arc_around_axis

    return float(arc_around_axis(np.ascontiguousarray(points, dtype=float), np.asarray(axis, float),
                                 np.asarray(point, float)))


def _oriented(axis: np.ndarray) -> np.ndarray:
    """Axis sign fixed so that its largest-magnitude component is positive."""
    # on Python floats: three numbers cost less than the numpy calls on them
    largest = max(axis.tolist(), key=abs)
    return -axis if largest < 0 else axis


def fit_cylinder(
    points,
    normals=None,
    *,
    max_iterations: int = 30,
    inlier_distance: float | None = None,
    axis_hint=None,
) -> Cylinder | FitFailure:
    """Fit an infinite cylinder minimising the orthogonal distances ``|(p - p0) x a| - r``.

    Start: with ``normals``, the axis is the direction most perpendicular to them
    (smallest eigenvector of ``sum n n^T``, as CAPE does); without, a coarse-to-fine
    search for the projection direction that makes the points most circular (moments up
    to 4th order, so its cost does not grow with N). The circle of the projection gives
    the axis point and radius; Levenberg-Marquardt then refines axis, point and radius on
    the geometric distances. Works from partial arcs (60-180 deg) and any axis direction.

    The returned ``axis`` has its largest-magnitude component positive; ``point`` is the
    point of the axis nearest the points' centroid.

    Guard against false cylinders: when the curvature over the covered arc (the
    sagitta ``r (1 - cos(arc/2))``) is not larger than the fit's rms, a plane explains
    the points as well and the fit fails.

    Parameters
    ----------
    points : (N, 3) array_like
        At least 5 points, not coplanar.
    normals : (N, 3) array_like, optional
        Surface normals (any length, any sign; NaN rows are ignored).
    max_iterations : int
        Levenberg-Marquardt iterations (4-8 are typical).
    inlier_distance : float, optional
        Count as inliers only points within this distance of the surface (default: all).
    axis_hint : (3,) array_like, optional
        A known approximate axis (e.g. from an earlier fit of the same region); used as
        the start instead of the normals or the direction search.

    Returns
    -------
    Cylinder or FitFailure
        FitFailure (falsy, with a reason) on fewer than 5 points, NaN/inf, coplanar or
        collinear points, insignificant curvature, or no convergence.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.linspace(0, np.pi, 20)
    >>> pts = np.stack([np.cos(t), np.sin(t), np.tile([0.0, 1.0], 10)], axis=1)
    >>> c = fit_cylinder(pts)
    >>> (np.round(c.axis, 6) + 0.0).tolist(), round(c.radius, 6)
    ([0.0, 0.0, 1.0], 1.0)
    """
    prep = Prepared(points, "cylinder", 5, inlier_distance)
    if normals is not None:
        normals = as_points(normals, "normals")
        if normals.shape != prep.points.shape:
            raise ValueError(f"normals must have the shape of points {prep.points.shape}; got {normals.shape}")
    return cylinder_from_prepared(prep, normals, max_iterations=max_iterations, axis_hint=axis_hint)


def cylinder_from_prepared(prep: Prepared, normals=None, *, max_iterations: int = 30,
                           axis_hint=None) -> Cylinder | FitFailure:
    """:func:`fit_cylinder` on points already checked, centred, scaled and decomposed."""
    if prep.failure is not None:
        return prep.failure
    q, scale = prep.q, prep.scale

    axis = None
    if axis_hint is not None:
        axis = np.asarray(axis_hint, float).reshape(3)
        if not np.all(np.isfinite(axis)) or not np.linalg.norm(axis) > 0:
            raise ValueError(f"axis_hint must be a finite non-zero 3-vector; got {axis_hint!r}")
        axis = axis / np.linalg.norm(axis)
    elif normals is not None:
        axis = axis_from_normals(normals)
    from ._decide import cylinder_checked

    hint = np.full(3, np.nan) if axis is None else axis
    inlier_q = np.inf if prep.inlier_distance is None else prep.inlier_distance / scale
    code, result = cylinder_checked(np.ascontiguousarray(q), prep.eigvals, hint, *_search_grids(),
                                    int(max_iterations), float(inlier_q), np.full(7, np.nan), np.inf)
    if code:
        return FitFailure("cylinder", refusal("cylinder", code, result, scale=scale, plane_rms=prep.eigen_rms,
                                              n=len(q), minimum=5, max_iterations=max_iterations))
    return cylinder_model(result, prep.centroid, scale)


def cylinder_model(result: np.ndarray, centroid: np.ndarray, scale: float) -> Cylinder:
    """The Cylinder of a checked result row (scaled frame about ``centroid``)."""
    values = result.tolist()  # Python floats: the scalar arithmetic below costs less
    return Cylinder(axis=_oriented(result[:3]), point=centroid + scale * result[3:6],
                    radius=values[RADIUS] * scale, rms=values[RMS] * scale,
                    inliers=int(values[INLIERS]))
