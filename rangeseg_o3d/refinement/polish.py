"""Step 8, ``polish``: spheres and cylinders are refitted once on their final pixels.

Planes are refitted from moments whenever they change, which costs nothing; the other
kinds keep the parameters of the points they were fitted to until here. A curved model
must also still earn its curvature on its final pixels: a cylinder fitted over a crease
keeps its region once the settle step has handed the crease's far face back to its own
plane, and on the face alone it is two parameters of noise (:func:`_still_flat`).
"""

from __future__ import annotations

import numpy as np

from ..fitting.primitives import Plane
from ..fitting.region_fitter import label_sizes, model_table, region_indices
from ..fitting.robust import curvature_resolved
from .context import Context

__all__ = ["polish_models"]

#: Parameters of each curved kind beyond a plane's three (what the curvature test weighs).
EXTRA_PARAMETERS = {"cylinder": 2, "sphere": 1}


def polish_models(ctx: Context, labels: np.ndarray, fits: dict) -> dict:
    """``fits`` with the models moments cannot refit (spheres, cylinders) refitted on the
    pixels of ``labels``, and those that no longer resolve a curvature there replaced by
    the plane the fitter's decision gives their pixels.

    Refitted only where the region outgrew the points the model was fitted to by more than
    20 % (a model's ``inliers`` counts those): a few more pixels move nothing.
    """
    fits = dict(fits)
    sizes = label_sizes(labels, minlength=max(fits, default=0) + 1)
    curved = [k for k, m in fits.items() if m and not isinstance(m, Plane)]
    grown = [k for k in curved if sizes[k] > 1.2 * max(fits[k].inliers, 1)]
    for k, refit in ctx.fitter.refit_regions(ctx.xyz, labels, fits, grown, from_moments=False).items():
        if refit and refit.kind == fits[k].kind:
            fits[k] = refit
    if curved:
        flat = _still_flat(ctx, labels, fits, curved)
        for k, idx in (region_indices(labels, only=flat) if flat else {}).items():
            decided = ctx.fitter.fit(ctx.fitter.points(ctx.xyz, idx))
            if isinstance(decided, Plane):
                fits[k] = decided
    return fits


def _still_flat(ctx: Context, labels: np.ndarray, fits: dict, curved: list) -> list:
    """The curved regions among ``curved`` whose model does not lower their pixels' least-
    squares plane's sum of squared distances by more than noise would (the F-test of
    :func:`rangeseg_o3d.fitting.robust.curvature_resolved`): two passes over the grid,
    the label-wise moments and the curved models' distances."""
    from ..kernels import distance_stats, label_moments, planes_from_moment_rows

    n = max(curved) + 1
    flat_labels = np.ascontiguousarray(labels.ravel(), dtype=np.int32)
    kinds, params, rms = model_table({k: fits[k] for k in curved}, n)
    _, curved_squares, counts = distance_stats(ctx.xyz, flat_labels, kinds, params, rms,
                                               np.ascontiguousarray(ctx.sigma, dtype=np.float64), 3.0)
    eigvals = planes_from_moment_rows(label_moments(ctx.xyz, flat_labels, n)[curved])[3]
    return [k for k, plane_variance in zip(curved, eigvals[:, 0]) if counts[k] > 3 and not curvature_resolved(
        plane_variance * counts[k], curved_squares[k], int(counts[k]), EXTRA_PARAMETERS[fits[k].kind])]
