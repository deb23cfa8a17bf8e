"""Exact analytic ray casting against a :class:`~rangeseg_o3d.synthetic.scene.Scene`.

Each surface type has a closed-form intersection computed for all rays at once;
:func:`cast` loops over surfaces only and keeps the nearest hit beyond ``t_min``.
"""

from __future__ import annotations

import numpy as np

from .scene import CylinderSide, Disk, Rectangle, Scene, SphereSurface

__all__ = ["cast", "intersect"]

# Hits closer than this are ignored so that a ray starting on a surface does not hit it again.
T_MIN = 1e-9
_PARALLEL = 1e-12


def _plane_t(origins, directions, center, normal):
    denom = directions @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((center - origins) @ normal) / denom
    t[np.abs(denom) < _PARALLEL] = np.inf
    return t


def _rectangle(surface: Rectangle, origins, directions):
    t = _plane_t(origins, directions, surface.center, surface.normal)
    finite = np.isfinite(t)
    rel = origins + directions * np.where(finite, t, 0.0)[:, None] - surface.center
    inside = (np.abs(rel @ surface.u) <= surface.half_u) & (np.abs(rel @ surface.v) <= surface.half_v)
    return np.where(finite & inside, t, np.inf)


def _disk(surface: Disk, origins, directions):
    t = _plane_t(origins, directions, surface.center, surface.normal)
    finite = np.isfinite(t)
    rel = origins + directions * np.where(finite, t, 0.0)[:, None] - surface.center
    inside = np.einsum("ij,ij->i", rel, rel) <= surface.radius**2
    return np.where(finite & inside, t, np.inf)


def _nearest_root(a, half_b, c, accept):
    """Smallest root t > T_MIN of ``a t^2 + 2 half_b t + c = 0`` passing ``accept(t)``; inf if none."""
    disc = half_b * half_b - a * c
    ok = (disc >= 0) & (a > _PARALLEL)
    root = np.sqrt(np.where(ok, disc, 0.0))
    safe_a = np.where(ok, a, 1.0)
    near = (-half_b - root) / safe_a
    far = (-half_b + root) / safe_a
    near_ok = ok & (near > T_MIN) & accept(near)
    far_ok = ok & (far > T_MIN) & accept(far)
    return np.where(near_ok, near, np.where(far_ok, far, np.inf))


def _sphere(surface: SphereSurface, origins, directions):
    w = origins - surface.center
    a = np.einsum("ij,ij->i", directions, directions)
    half_b = np.einsum("ij,ij->i", w, directions)
    c = np.einsum("ij,ij->i", w, w) - surface.radius**2
    return _nearest_root(a, half_b, c, lambda t: np.ones(t.shape, dtype=bool))


def _cylinder_side(surface: CylinderSide, origins, directions):
    axis = surface.axis
    w = origins - surface.base
    w_axial = w @ axis
    d_axial = directions @ axis
    w_perp = w - np.outer(w_axial, axis)
    d_perp = directions - np.outer(d_axial, axis)
    a = np.einsum("ij,ij->i", d_perp, d_perp)
    half_b = np.einsum("ij,ij->i", w_perp, d_perp)
    c = np.einsum("ij,ij->i", w_perp, w_perp) - surface.radius**2

    def within_length(t):
        s = w_axial + t * d_axial
        return (s >= 0.0) & (s <= surface.length)

    return _nearest_root(a, half_b, c, within_length)


_INTERSECTORS = {
    Rectangle: _rectangle,
    Disk: _disk,
    SphereSurface: _sphere,
    CylinderSide: _cylinder_side,
}


def intersect(surface, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Ray parameter of the nearest hit ``t > T_MIN`` with one surface, ``inf`` on a miss.

    Parameters
    ----------
    surface : Rectangle, Disk, CylinderSide or SphereSurface
    origins, directions : (N, 3) float arrays (already validated by :func:`cast`).

    Returns
    -------
    (N,) float array.
    """
    try:
        func = _INTERSECTORS[type(surface)]
    except KeyError:
        raise TypeError(f"cannot intersect a {type(surface).__name__}") from None
    t = func(surface, origins, directions)
    return np.where(t > T_MIN, t, np.inf)


def _check_rays(origins, directions) -> tuple[np.ndarray, np.ndarray]:
    o = np.asarray(origins, dtype=float)
    d = np.asarray(directions, dtype=float)
    if o.ndim != 2 or o.shape[1] != 3:
        raise ValueError(f"origins must have shape (N, 3); got {o.shape}")
    if d.shape != o.shape:
        raise ValueError(f"directions must have the shape of origins {o.shape}; got {d.shape}")
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(d))):
        raise ValueError("origins and directions must be finite")
    norms = np.linalg.norm(d, axis=1)
    if d.shape[0] and np.max(np.abs(norms - 1.0)) > 1e-6:
        bad = int(np.argmax(np.abs(norms - 1.0)))
        raise ValueError(f"directions must be unit vectors; row {bad} has norm {norms[bad]:.6g}")
    return o, d


def cast(scene: Scene, origins, directions) -> tuple[np.ndarray, np.ndarray]:
    """Cast rays into a scene and return the nearest hit of each.

    Parameters
    ----------
    scene : Scene
    origins : (N, 3) array of ray origins, metres.
    directions : (N, 3) array of unit directions.

    Returns
    -------
    ranges : (N,) float array
        Distance to the nearest surface hit beyond 1e-9 m; ``inf`` on a miss.
    ids : (N,) int32 array
        Id of the surface hit; 0 on a miss. On an exact tie (a shared edge) the surface
        listed first in the scene wins.

    Raises
    ------
    TypeError
        If ``scene`` is not a Scene.
    ValueError
        On shapes other than (N, 3), non-finite values or non-unit directions.

    Examples
    --------
    >>> from rangeseg_o3d.synthetic.scene import Scene, sphere
    >>> r, ids = cast(Scene(sphere((5, 0, 0), 1.0, first_id=3)), [[0, 0, 0]], [[1, 0, 0]])
    >>> float(r[0]), int(ids[0])
    (4.0, 3)
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a Scene; got {type(scene).__name__}")
    o, d = _check_rays(origins, directions)
    ranges = np.full(o.shape[0], np.inf)
    ids = np.zeros(o.shape[0], dtype=np.int32)
    for surface in scene.surfaces:
        t = intersect(surface, o, d)
        nearer = t < ranges
        ranges[nearer] = t[nearer]
        ids[nearer] = surface.id
    return ranges, ids
