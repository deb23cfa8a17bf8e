"""Refit a region with a model of the kind it already has.

After the pipeline grows a region into the edge band or merges two regions, the kind is
settled; only the parameters need updating. Going straight to that kind's least-squares fit
skips the classifier's trials of the other models, which dominate its cost.
"""

from __future__ import annotations

from .cylinder import fit_cylinder
from .models import Cylinder, FitFailure, Plane, Sphere
from .plane import fit_plane
from .sphere import fit_sphere

__all__ = ["refit_same_kind"]


def refit_same_kind(points, model, *, inlier_distance: float | None = None):
    """Fit ``points`` with a model of ``model``'s kind.

    Parameters
    ----------
    points : (N, 3) array_like
    model : Plane, Cylinder or Sphere
        The region's current model; its kind is kept.
    inlier_distance : float, optional
        Points within this distance count as inliers (all points if None).

    Returns
    -------
    A model of the same kind, or FitFailure.
    """
    if isinstance(model, Plane):
        return fit_plane(points, inlier_distance=inlier_distance)
    if isinstance(model, Cylinder):
        return fit_cylinder(points, inlier_distance=inlier_distance)
    if isinstance(model, Sphere):
        return fit_sphere(points, inlier_distance=inlier_distance)
    if isinstance(model, FitFailure):
        raise ValueError(f"cannot refit a failed fit ({model.reason})")
    raise TypeError(f"model must be a Plane, Cylinder or Sphere; got {type(model).__name__}")
