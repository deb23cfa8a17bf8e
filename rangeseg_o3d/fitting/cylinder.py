"""Cylinder: axis start (surface normals or a moment-based direction search), circle fit,
then geometric Levenberg-Marquardt refinement of axis, axis point and radius."""

from __future__ import annotations

import functools

import numpy as np

from ._common import (
    RADIUS_LIMIT,
    Prepared,
    as_points,
    count_within,
    curvature_failure,
    levenberg_marquardt,
    refinement_failure,
)
from .models import Cylinder, FitFailure

__all__ = ["fit_cylinder", "axis_from_normals", "search_axis", "cylinder_arc"]


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


def _cone(axis: np.ndarray, half_angle: float):
    """The cone template rotated onto ``axis``: ``(directions, u, v)``; frames rotate along."""
    u, v = _frame(axis)
    rotation = np.stack([u, v, axis])  # rows: template x, y, z go to u, v, axis
    return tuple(m @ rotation for m in _cone_template(half_angle))


class _Moments:
    """Moments up to 4th order of centred points, enough to fit a circle to their projection
    along any direction at a cost independent of the number of points (Eberly's method)."""

    def __init__(self, q: np.ndarray):
        x, y, z = q[:, 0], q[:, 1], q[:, 2]
        quad = np.stack([x * x, y * y, z * z, x * y, x * z, y * z], axis=1)
        self.n = len(q)
        self.second = q.T @ q
        self.third = q.T @ quad
        self.fourth = quad.T @ quad

    def circle_scores(self, directions: np.ndarray, u=None, v=None, s=None):
        """Kasa circle fit of the projection along each unit direction.

        Returns ``(score, center2, radius_sq, u, v)``: score is the algebraic error
        divided by ``4 r^2``, i.e. approximately the mean squared geometric distance, so
        that directions squashing the points into a small blob are not favoured.
        ``u, v, s`` (frames and projector coefficients) may be passed precomputed.
        """
        if u is None:
            u, v = _perpendicular_bases(directions)
        if s is None:
            s = _projector_coefficients(directions)
        su, sv = u @ self.second, v @ self.second
        a00, a01, a11 = (su * u).sum(axis=1), (su * v).sum(axis=1), (sv * v).sum(axis=1)
        t3 = s @ self.third.T  # (M, 3): sum |y|^2 X
        b0, b1 = (t3 * u).sum(axis=1), (t3 * v).sum(axis=1)
        sum4 = ((s @ self.fourth) * s).sum(axis=1)
        det = a00 * a11 - a01 * a01
        det = np.where(np.abs(det) > 1e-300, det, 1e-300)
        cx = 0.5 * (a11 * b0 - a01 * b1) / det
        cy = 0.5 * (a00 * b1 - a01 * b0) / det
        mu = (a00 + a11) / self.n
        algebraic = (sum4 - self.n * mu * mu - 2.0 * (b0 * cx + b1 * cy)) / self.n
        radius_sq = mu + cx * cx + cy * cy
        score = np.maximum(algebraic, 0.0) / (4.0 * radius_sq)
        return score, np.stack([cx, cy], axis=1), radius_sq, u, v


def _projector_coefficients(directions: np.ndarray) -> np.ndarray:
    """Coefficients of ``|P x|^2`` (P = I - w w^T) on the monomials x2 y2 z2 xy xz yz."""
    wx, wy, wz = directions[:, 0], directions[:, 1], directions[:, 2]
    return np.stack([1 - wx * wx, 1 - wy * wy, 1 - wz * wz, -2 * wx * wy, -2 * wx * wz, -2 * wy * wz], axis=1)


@functools.lru_cache(maxsize=4)
def _hemisphere_grid(n: int):
    """Hemisphere directions with their frames and projector coefficients, computed once."""
    dirs = _hemisphere(n)
    u, v = _perpendicular_bases(dirs)
    return dirs, u, v, _projector_coefficients(dirs)


def search_axis(q: np.ndarray, moments: "_Moments | None" = None) -> np.ndarray:
    """Axis direction of centred, scaled points ``q`` without normals.

    Coarse-to-fine search over the hemisphere for the direction along which the points
    project best onto a circle (Eberly's cylinder fit, with the Kasa error normalised to a
    geometric one); about 8 deg coarse spacing refined to about 0.5 deg.
    """
    moments = _Moments(q) if moments is None else moments
    dirs, u, v, coeffs = _hemisphere_grid(300)
    score = moments.circle_scores(dirs, u, v, coeffs)[0]
    best = dirs[int(np.argmin(score))]
    for half_angle in (np.radians(8.0), np.radians(2.0)):
        dirs, u, v = _cone(best, half_angle)
        best = dirs[int(np.argmin(moments.circle_scores(dirs, u, v)[0]))]
    return best


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


def _circle_start(moments: _Moments, axis: np.ndarray) -> tuple[np.ndarray, float]:
    """Axis point and radius from the Kasa circle of the projection along ``axis``."""
    _, center2, radius_sq, u, v = moments.circle_scores(axis[None, :])
    point = center2[0, 0] * u[0] + center2[0, 1] * v[0]
    return point, float(np.sqrt(max(radius_sq[0], 1e-300)))


def _refine(q: np.ndarray, axis: np.ndarray, point: np.ndarray, radius: float, max_iterations: int):
    """Levenberg-Marquardt on ``|(q - p0) x a| - r``; each step linearised in a frame whose
    z axis is the current axis (2 tilt angles, 2 axis-point shifts, the radius)."""

    def evaluate(state):
        a, rotation, p0, r = state
        local = (q - p0) @ rotation
        x, y, z = local[:, 0], local[:, 1], local[:, 2]
        rho = np.maximum(np.sqrt(x * x + y * y), 1e-300)
        jac = np.empty((len(q), 5))
        np.divide(-x, rho, out=jac[:, 0])
        np.divide(-y, rho, out=jac[:, 1])
        np.multiply(z, jac[:, 0], out=jac[:, 2])
        np.multiply(z, jac[:, 1], out=jac[:, 3])
        jac[:, 4] = -1.0
        return rho - r, jac

    def local_frame(a):
        # columns u, v, a: points @ rotation gives coordinates with the axis as z
        return np.column_stack([*_frame(a), a])

    def apply(state, step):
        a, rotation, p0, r = state
        new_a = rotation @ np.array([step[2], step[3], 1.0])
        new_a /= np.sqrt(new_a @ new_a)
        new_p = p0 + rotation[:, :2] @ step[:2]
        new_p = new_p - (new_p @ new_a) * new_a  # keep the point nearest the centroid (origin of q)
        return (new_a, local_frame(new_a), new_p, r + step[4])

    state = (axis, local_frame(axis), point - (point @ axis) * axis, radius)
    state, res, converged = levenberg_marquardt(
        state, evaluate, apply, max_iterations, abandon=lambda st: st[3] > RADIUS_LIMIT
    )
    return state[0], state[2], float(state[3]), res, converged


def cylinder_arc(points: np.ndarray, axis: np.ndarray, point: np.ndarray) -> float:
    """Arc (radians, 0 to 2*pi) of the cross-section circle that the points cover.

    2*pi minus the largest angular gap between consecutive points around the axis.
    """
    axis = np.asarray(axis, float)
    rel = np.asarray(points, float) - point
    u, v = _frame(axis / np.linalg.norm(axis))
    angles = np.sort(np.arctan2(rel @ v, rel @ u))
    if len(angles) < 2:
        return 0.0
    gaps = np.diff(angles, append=angles[0] + 2 * np.pi)
    return float(2 * np.pi - gaps.max())


def _oriented(axis: np.ndarray) -> np.ndarray:
    """Axis sign fixed so that its largest-magnitude component is positive."""
    return -axis if axis[np.argmax(np.abs(axis))] < 0 else axis


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
    prep = Prepared(points, "cylinder", 5, inlier_distance, curved=True)
    if normals is not None:
        normals = as_points(normals, "normals")
        if normals.shape != prep.points.shape:
            raise ValueError(f"normals must have the shape of points {prep.points.shape}; got {normals.shape}")
    if prep.failure is not None:
        return prep.failure
    q, scale = prep.q, prep.scale

    moments = _Moments(q)
    axis = None
    if axis_hint is not None:
        axis = np.asarray(axis_hint, float).reshape(3)
        if not np.all(np.isfinite(axis)) or not np.linalg.norm(axis) > 0:
            raise ValueError(f"axis_hint must be a finite non-zero 3-vector; got {axis_hint!r}")
        axis = axis / np.linalg.norm(axis)
    elif normals is not None:
        axis = axis_from_normals(normals)
    if axis is None:
        axis = search_axis(q, moments)
    point, radius = _circle_start(moments, axis)
    axis, point, radius, res, converged = _refine(q, axis, point, radius, max_iterations)
    failure = refinement_failure("cylinder", converged, max_iterations, np.append(axis, point), radius)
    if failure is not None:
        return failure
    rms = float(np.sqrt(res @ res / len(q)))
    failure = curvature_failure(prep, "cylinder", radius, cylinder_arc(q, axis, point), rms)
    if failure is not None:
        return failure
    return Cylinder(
        axis=_oriented(axis),
        point=prep.centroid + scale * point,
        radius=float(radius * scale),
        rms=rms * scale,
        inliers=count_within(res * scale, prep.inlier_distance),
    )
