"""Drawable extents of fitted models: plane outlines, cylinder spans, rotations.

Models are infinite (a plane, an infinite cylinder); to draw them we bound them by the
region's points that the model explains (its inliers).
"""

from __future__ import annotations

import logging

import numpy as np

__all__ = [
    "region_points",
    "model_inliers",
    "plane_outline",
    "cylinder_span",
    "quaternion_from_z",
]

log = logging.getLogger(__name__)

#: A point is an inlier when its distance to the model is within this many model rms.
INLIER_RMS_FACTOR = 3.0
#: Inlier tolerance floor (metres) so that a perfect fit (rms 0) keeps its points.
INLIER_FLOOR = 1e-6


def region_points(xyz: np.ndarray, labels: np.ndarray, label: int) -> np.ndarray:
    """The valid points of region ``label``.

    Parameters
    ----------
    xyz : (H, W, 3) float array, NaN where invalid.
    labels : (H, W) int array.
    label : int

    Returns
    -------
    (N, 3) float array, possibly empty.
    """
    mask = (labels == label) & ~np.isnan(xyz[..., 2])
    return xyz[mask]


def model_inliers(points: np.ndarray, model) -> np.ndarray:
    """Points within ``INLIER_RMS_FACTOR * model.rms`` of the model.

    Fewer than three such points (a model whose rms understates its scatter) means we
    cannot trust the selection, so all ``points`` are returned instead.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    tol = max(INLIER_RMS_FACTOR * float(model.rms), INLIER_FLOOR)
    keep = np.abs(model.distances(points)) <= tol
    return points[keep] if keep.sum() >= 3 else points


def _plane_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # Any helper axis not parallel to the normal gives an orthonormal in-plane basis.
    helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


def plane_outline(points: np.ndarray, plane) -> np.ndarray:
    """Closed outline of ``points`` projected onto ``plane``: their convex hull.

    Parameters
    ----------
    points : (N, 3) float array
        The plane's inlier points.
    plane : rangeseg_o3d.Plane

    Returns
    -------
    (K + 1, 3) float array
        Hull vertices in counter-clockwise order (about the normal), the first repeated
        at the end. Collinear points give their two extreme points (K = 2); an empty
        input gives a (0, 3) array.
    """
    from scipy.spatial import ConvexHull, QhullError

    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) == 0:
        return np.empty((0, 3))
    normal = plane.normal
    u, v = _plane_basis(normal)
    coords = np.stack([points @ u, points @ v], axis=1)
    try:
        order = ConvexHull(coords).vertices  # counter-clockwise in 2-D
    except (QhullError, ValueError):
        # Fewer than 3 points or all collinear: draw the segment they span.
        direction = coords - coords.mean(axis=0)
        axis_2d = np.linalg.svd(direction, full_matrices=False)[2][0]
        proj = direction @ axis_2d
        order = np.array([int(np.argmin(proj)), int(np.argmax(proj))])
    hull = coords[order]
    outline = plane.d * normal + hull[:, :1] * u + hull[:, 1:] * v
    return np.vstack([outline, outline[:1]])


def cylinder_span(points: np.ndarray, cylinder) -> tuple[np.ndarray, float]:
    """Centre and length of the part of ``cylinder``'s axis spanned by ``points``.

    Parameters
    ----------
    points : (N, 3) float array, N >= 1
        The cylinder's inlier points.
    cylinder : rangeseg_o3d.Cylinder

    Returns
    -------
    center : (3,) float array
        Point of the axis midway between the extreme axial positions of ``points``.
    length : float
        Axial extent of ``points`` (0 for a single point).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) == 0:
        raise ValueError("cylinder_span needs at least one point; got 0")
    axial = (points - cylinder.point) @ cylinder.axis
    low, high = float(axial.min()), float(axial.max())
    center = cylinder.point + 0.5 * (low + high) * cylinder.axis
    return center, high - low


def quaternion_from_z(axis) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` rotating +z onto ``axis``.

    Examples
    --------
    >>> quaternion_from_z([0.0, 0.0, 1.0]).tolist()
    [0.0, 0.0, 0.0, 1.0]
    """
    a = np.asarray(axis, dtype=float).reshape(3)
    norm = np.linalg.norm(a)
    if not np.isfinite(norm) or norm == 0:
        raise ValueError(f"axis must be a finite non-zero 3-vector; got {a.tolist()}")
    a = a / norm
    z = np.array([0.0, 0.0, 1.0])
    cos = float(z @ a)
    if cos < -1.0 + 1e-12:
        # Opposite vectors: half a turn about any perpendicular, here x.
        return np.array([1.0, 0.0, 0.0, 0.0])
    q = np.append(np.cross(z, a), 1.0 + cos)
    return q / np.linalg.norm(q)
