"""Step 8, ``polish``: spheres and cylinders are refitted once on their final pixels.

Planes are refitted from moments whenever they change, which costs nothing; the other
kinds keep the parameters of the points they were fitted to until here. A curved model
must also still earn its curvature on its final pixels: a cylinder fitted over a crease
keeps its region once the settle step has handed the crease's far face back to its own
plane, and on the face alone it is two parameters of noise (:func:`_still_flat`). A plane
must still be one on its final pixels: its kind was decided on the pixels it had then (a
pipe's flat middle piece, before growth gave it the flanks), :func:`_curved_planes`.
"""

from __future__ import annotations

import numpy as np

from .. import kernels  # the package: its names load on first use (no compiler at import)
from ..fitting.primitives import Plane
from ..fitting.region_fitter import label_sizes, model_table, region_indices
from ..fitting.robust import curvature_resolved
from .context import Context

__all__ = ["polish_models"]

#: Parameters of each curved kind beyond a plane's three (what the curvature test weighs).
EXTRA_PARAMETERS = {"cylinder": 2, "sphere": 1}


def polish_models(ctx: Context, labels: np.ndarray, fits: dict, *, decide_planes: bool = True,
                  resolve_bends: float = 0.0) -> dict:
    """``fits`` with the models moments cannot refit (spheres, cylinders) refitted on the
    pixels of ``labels``, and those that no longer resolve a curvature there replaced by
    the plane the fitter's decision gives their pixels; planes whose pixels the fitter now
    calls curved replaced by that model (:func:`_curved_planes`; with ``decide_planes``;
    ``resolve_bends``, the independent samples each pixel carries, 0 for not asked: also
    the planes whose quadric resolves a bend under the noise over those samples, and curved
    models only a neighbour's pixels bend are planes, :func:`_unbent`).

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
    unbent = (_unbent(ctx, labels, [k for k in curved if not isinstance(fits[k], Plane)], resolve_bends)
              if resolve_bends else {})
    fits.update(unbent)
    if decide_planes:  # (not the planes just found: the decision's marginal path would bend them again)
        fits.update(_curved_planes(ctx, labels, {k: m for k, m in fits.items() if k not in unbent}, resolve_bends))
    return fits


def _unbent(ctx: Context, labels: np.ndarray, curved: list, samples: float = 1.0) -> dict:
    """The planes of the regions among ``curved`` whose pixels' plane is within the
    fitter's plane threshold and whose bend does not outlive the pixels beyond 2 plane rms
    (:func:`rangeseg_o3d.fitting._decide.bend_resolved`): a curved model a plane just over
    the noise took only for a few pixels of a neighbouring face (noise_20mm seed 37 scan
    7: a 4-column wall strip with 26 px of its neighbours, rms 20.4 mm over 20 mm noise,
    a 0.53 m cylinder). Asked with ``resolve_bends``; ``samples`` per pixel as there."""
    from ..fitting import fit_plane
    from ..fitting._decide import bend_resolved
    from ..fitting.classify import INLIER_FACTOR, plane_threshold

    p = ctx.fitter.params
    if not curved or not {"plane_rms", "noise_floor", "rms_per_range2"} <= set(p):  # another plugin
        return {}
    out = {}
    for k, idx in region_indices(labels, only=curved).items():
        pts = ctx.fitter.points(ctx.xyz, idx)
        centroid = pts.mean(axis=0)
        tolerance = plane_threshold(len(pts), centroid, plane_rms=p["plane_rms"], noise_floor=p["noise_floor"],
                                    rms_per_range2=p["rms_per_range2"])
        plane = fit_plane(pts, inlier_distance=INLIER_FACTOR * tolerance)
        if plane and plane.rms <= tolerance and not bend_resolved(
                np.ascontiguousarray(pts - centroid), np.ascontiguousarray(plane.normal), plane.rms, float(samples)):
            out[k] = plane
    return out


def _curved_planes(ctx: Context, labels: np.ndarray, fits: dict, resolve_bends: float = 0.0) -> dict:
    """The curved models the fitter's decision gives the plane regions of ``labels`` whose
    final pixels it no longer settles as a plane.

    A region's kind is decided once, on the pixels it had then (a split's trimmed piece, a
    region before growth, the larger of two pieces a join put together); planes are refitted
    from moments as their regions change, keeping their kind. On the final pixels the
    batch plane test (:meth:`RegionFitter.fit_batch`: the fitter's own plane tolerance and
    quadric curvature test, one pass) settles almost every plane again; only the others
    are decided anew, and a curved answer replaces the plane (a pipe whose first piece was
    flat within the noise, grown to its whole width). With ``resolve_bends`` (the
    independent samples each pixel carries) a plane within the noise is also decided anew
    where its quadric resolves a bend over them all the same (a pipe seen on a narrow arc,
    its bend under the noise over hundreds of pixels), and so is one beyond what the noise
    gives its pixels (the decision's marginal plane: a pipe's plane over a camera's noise
    but under the preset's plane_rms); earlier decisions, on pieces and unsettled
    regions, do not ask it."""
    planes = [k for k, m in fits.items() if isinstance(m, Plane)]
    if not planes or ctx.fitter.plugin.fit_batch is None:  # a plugin without the batch test: as decided
        return {}
    bends = {"resolve_bends": float(resolve_bends)} if resolve_bends else {}  # a keyword of the primitives fitter
    settled = ctx.fitter.fit_batch(ctx.xyz, labels, **bends)
    unsettled = [k for k in planes if k not in settled]
    out = {}
    for k, idx in (region_indices(labels, only=unsettled) if unsettled else {}).items():
        decided = ctx.fitter.fit(ctx.fitter.points(ctx.xyz, idx), **bends)
        if decided and not isinstance(decided, Plane):
            out[k] = decided
    return out


def _still_flat(ctx: Context, labels: np.ndarray, fits: dict, curved: list) -> list:
    """The curved regions among ``curved`` whose model does not lower their pixels' least-
    squares plane's sum of squared distances by more than noise would (the F-test of
    :func:`rangeseg_o3d.fitting.robust.curvature_resolved`): two passes over the grid,
    the label-wise moments and the curved models' distances."""
    n = max(curved) + 1
    flat_labels = np.ascontiguousarray(labels.ravel(), dtype=np.int32)
    kinds, params, rms = model_table({k: fits[k] for k in curved}, n)
    _, curved_squares, counts = kernels.distance_stats(ctx.xyz, flat_labels, kinds, params, rms,
                                                       np.ascontiguousarray(ctx.sigma, dtype=np.float64), 3.0)
    eigvals = kernels.planes_from_moment_rows(kernels.label_moments(ctx.xyz, flat_labels, n)[curved])[3]
    return [k for k, plane_variance in zip(curved, eigvals[:, 0]) if counts[k] > 3 and not curvature_resolved(
        plane_variance * counts[k], curved_squares[k], int(counts[k]), EXTRA_PARAMETERS[fits[k].kind])]
