"""Immutable fitted models and the failure value returned instead of NaN parameters."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar, Union

import numpy as np

__all__ = ["Plane", "Sphere", "Cylinder", "FitFailure", "Model", "front_along_rays", "squared_distances",
           "with_statistics"]


def _vec(value, name: str) -> np.ndarray:
    # a model's 3-vector field, read-only; ValueError naming the field for anything else
    if (type(value) is np.ndarray and value.shape == (3,) and value.dtype == np.float64
            and not value.flags.writeable):
        return value  # already a model's vector (dataclasses.replace passes it again)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be 3 numbers; got {type(value).__name__} {value!r:.60}") from None
    if arr.size != 3:
        raise ValueError(f"{name} must be 3 numbers; got shape {arr.shape}")
    arr = arr.reshape(3)
    arr.setflags(write=False)
    return arr


def _unit_rows(vectors: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(vectors, axis=1, keepdims=True)
    return np.divide(vectors, norms, out=np.zeros_like(vectors), where=norms > 0)


@dataclass(frozen=True, eq=False)
class Plane:
    """Plane ``normal . p = d`` (unit normal); rms of orthogonal distances; inlier count."""

    normal: np.ndarray
    d: float
    rms: float
    inliers: int
    kind: ClassVar[str] = "plane"

    def __post_init__(self):
        object.__setattr__(self, "normal", _vec(self.normal, "normal"))

    def distances(self, points: np.ndarray) -> np.ndarray:
        """Signed orthogonal distances of ``(N, 3)`` points."""
        return np.asarray(points, dtype=float) @ self.normal - self.d

    def normals(self, points: np.ndarray) -> np.ndarray:
        """Unit surface normals at the feet of ``(N, 3)`` points (the plane's, repeated)."""
        return np.broadcast_to(self.normal, (len(points), 3))

    def params(self) -> dict:
        return {"normal": self.normal.tolist(), "d": float(self.d)}


@dataclass(frozen=True, eq=False)
class Sphere:
    """Sphere with ``center`` and ``radius``."""

    center: np.ndarray
    radius: float
    rms: float
    inliers: int
    kind: ClassVar[str] = "sphere"

    def __post_init__(self):
        object.__setattr__(self, "center", _vec(self.center, "center"))

    def distances(self, points: np.ndarray) -> np.ndarray:
        return np.linalg.norm(np.asarray(points, dtype=float) - self.center, axis=1) - self.radius

    def normals(self, points: np.ndarray) -> np.ndarray:
        """Unit surface normals at the feet of ``(N, 3)`` points (from the centre out; a
        point at the centre gets a zero vector)."""
        return _unit_rows(np.asarray(points, dtype=float) - self.center)

    def params(self) -> dict:
        return {"center": self.center.tolist(), "radius": float(self.radius)}


@dataclass(frozen=True, eq=False)
class Cylinder:
    """Infinite cylinder: unit ``axis`` through ``point`` (the point nearest the inliers' centroid)."""

    axis: np.ndarray
    point: np.ndarray
    radius: float
    rms: float
    inliers: int
    kind: ClassVar[str] = "cylinder"

    def __post_init__(self):
        object.__setattr__(self, "axis", _vec(self.axis, "axis"))
        object.__setattr__(self, "point", _vec(self.point, "point"))

    def distances(self, points: np.ndarray) -> np.ndarray:
        rel = np.asarray(points, dtype=float) - self.point
        radial = rel - np.outer(rel @ self.axis, self.axis)
        return np.linalg.norm(radial, axis=1) - self.radius

    def normals(self, points: np.ndarray) -> np.ndarray:
        """Unit surface normals at the feet of ``(N, 3)`` points (radial, away from the axis;
        a point on the axis gets a zero vector)."""
        rel = np.asarray(points, dtype=float) - self.point
        return _unit_rows(rel - np.outer(rel @ self.axis, self.axis))

    def params(self) -> dict:
        return {
            "axis": self.axis.tolist(),
            "point": self.point.tolist(),
            "radius": float(self.radius),
        }


@dataclass(frozen=True)
class FitFailure:
    """A fit that could not be made; falsy, with the reason."""

    kind: str
    reason: str
    inliers: int = 0
    rms: float = field(default=float("nan"))

    def __bool__(self) -> bool:
        return False


Model = Union[Plane, Sphere, Cylinder]


def squared_distances(model, points: np.ndarray) -> float:
    """The sum of the squared distances of ``points`` (N, 3) from ``model``'s surface (any
    model with ``distances``): what the steps that weigh two models on the same points compare."""
    return float(np.sum(model.distances(points) ** 2))


#: The fields :func:`with_statistics` sets without the dataclass machinery: scalars no check reads.
_STATISTICS = frozenset({"rms", "inliers"})


def with_statistics(model, **changes):
    """``dataclasses.replace(model, **changes)`` where only the fit statistics change.

    A Plane, Sphere or Cylinder whose ``rms`` or ``inliers`` alone change is copied field
    by field (its vectors were checked when it was made and are shared, as ``replace``
    shares them): the same model without ``replace``'s field introspection and
    ``__post_init__``, a quarter of its time (the pipeline sets the statistics of every
    region of a frame). Any other model or change goes through ``replace``.
    """
    if type(model) in (Plane, Sphere, Cylinder) and changes.keys() <= _STATISTICS:
        copy = object.__new__(type(model))
        copy.__dict__.update(model.__dict__)
        copy.__dict__.update(changes)
        return copy
    return replace(model, **changes)


def front_along_rays(model, points: np.ndarray, starts: np.ndarray | None = None) -> tuple:
    """``(rays, ranges, front, hit)`` of the returns ``points`` (N, 3) against the cylinder
    (unbounded along its axis) or sphere ``model``: their unit rays and ranges from where the
    rays start (``starts``, (N, 3); the origin when None), the range at which each ray first
    meets the model (the nearer crossing; where the ray passes it by, the range of its closest
    approach), and whether it meets it in front of its start."""
    if not isinstance(model, (Cylinder, Sphere)):
        raise ValueError(f"model must be a Cylinder or a Sphere; got {type(model).__name__}")
    points = np.asarray(points, dtype=np.float64)
    start = np.zeros_like(points) if starts is None else np.asarray(starts, dtype=np.float64)
    seen = points - start
    ranges = np.linalg.norm(seen, axis=1)
    rays = seen / np.maximum(ranges, 1e-12)[:, None]
    if isinstance(model, Cylinder):
        axis = model.axis
        d = rays - np.outer(rays @ axis, axis)
        rel = start - model.point
        e = rel - np.outer(rel @ axis, axis)
        a = np.maximum(np.einsum("ij,ij->i", d, d), 1e-24)
        b = np.einsum("ij,ij->i", d, e)
        c = np.einsum("ij,ij->i", e, e) - model.radius ** 2
    else:
        rel = start - model.center
        a = np.ones(len(points))
        b = np.einsum("ij,ij->i", rays, rel)
        c = np.einsum("ij,ij->i", rel, rel) - model.radius ** 2
    disc = b * b - a * c
    front = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
    return rays, ranges, front, (disc >= 0.0) & (front > 0.0)  # (a start inside: front < 0)
