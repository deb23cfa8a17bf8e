"""Step 2, ``grow``: edge-band pixels go back to the neighbouring region whose surface explains them.

The paper's own future work (Sec. 6, "re-add points left out by the edge band"). Closing
and the 3x3 window leave a band of edge pixels around every region; small objects lose
most of their pixels to it. Regions are grown back into that band, a ring of pixels at a
time, wherever the region's fitted surface explains the pixel within the local noise.

Step 6, ``settle`` (:func:`settle_regions`), lives here too: after the merge, border pixels
move to the neighbouring region whose surface explains them clearly better.
"""

from __future__ import annotations

import numpy as np

from .. import kernels  # the package: its names load on first use (no compiler at import)
from ..fitting.primitives import Plane
from ..fitting.region_fitter import label_sizes, model_table, pixel_rms
from .context import Context

__all__ = ["grow_into_edges", "grow_regions", "grows_any", "refit_grown", "settle_regions"]


def _growth_inputs(xyz, labels, models, sigma, ranges) -> tuple:
    # the compiled growth's grids and model table: flat float64 points, noise and ranges
    # around the caller's C-contiguous int32 ``labels``
    kinds, params, rms = model_table(models, int(labels.max(initial=0)) + 1)
    return (np.ascontiguousarray(xyz.reshape(-1, 3), dtype=np.float64), labels, kinds, params, rms,
            np.ascontiguousarray(sigma, dtype=np.float64).ravel(),
            np.ascontiguousarray(ranges, dtype=np.float64).ravel())


def grows_any(xyz: np.ndarray, labels: np.ndarray, models: dict, sigma: np.ndarray, ranges: np.ndarray, *,
              k_sigma: float = 3.0, jump_ratio: float = 0.08, jump_min: float = 0.05) -> bool:
    """Whether :func:`grow_into_edges` with these arguments adds any pixel: its first ring
    does (:func:`rangeseg_o3d.kernels.first_ring_grows`, growth's own test in one
    pass that stops at the first pixel taken), as growth stops at the first ring adding none.
    Cheaper than the growth's copies and, after it, the callers' refits where nothing grows."""
    labels = np.ascontiguousarray(labels, dtype=np.int32)
    return bool(kernels.first_ring_grows(*_growth_inputs(xyz, labels, models, sigma, ranges),
                                         float(k_sigma), float(jump_ratio), float(jump_min)))


def grow_into_edges(
    xyz: np.ndarray,
    labels: np.ndarray,
    models: dict,
    sigma: np.ndarray,
    ranges: np.ndarray,
    *,
    iterations: int = 3,
    k_sigma: float = 3.0,
    jump_ratio: float = 0.08,
    jump_min: float = 0.05,
    box=None,
) -> np.ndarray:
    """Hand unlabelled valid pixels to the adjacent region whose model fits them best.

    Parameters
    ----------
    xyz : (H, W, 3) points, NaN where invalid.
    labels : (H, W) int labels, 0 = no region.
    models : label -> fitted model (regions without a model do not grow).
    sigma : (H, W) range noise per pixel, metres.
    ranges : (H, W) ranges, for the no-jump test between a pixel and its neighbour.
    iterations : rings of pixels to add at most.
    k_sigma : accept a pixel within ``k_sigma * max(sigma, model.rms)`` of the surface.
    box : optional ``(row0, row1, col0, col1)`` (half-open) holding every pixel of the
        regions in ``models`` grown by ``iterations`` pixels: the growth is looked for there
        only (the same answer, no pass over the whole grid); or a ``(K, 4)`` array of such
        boxes that hold them together (looked for in each).

    Returns
    -------
    New (H, W) int32 labels.
    """
    labels = np.array(labels, dtype=np.int32, order="C", copy=True)
    arguments = (*_growth_inputs(xyz, labels, models, sigma, ranges),
                 int(iterations), float(k_sigma), float(jump_ratio), float(jump_min))
    if box is not None and np.ndim(box) == 2:
        kernels.grow_rings_in_boxes(*arguments, np.ascontiguousarray(box, dtype=np.int64))
    else:
        kernels.grow_rings(*arguments, *((0, -1, 0, -1) if box is None else (int(b) for b in box)))
    return labels


def refit_grown(ctx: Context, labels: np.ndarray, grown: np.ndarray, fits: dict) -> dict:
    """The models of ``fits`` after the regions of ``labels`` grew to ``grown``.

    Regions that grew by more than 5 % are refitted where moments suffice (planes); a
    refit must keep the kind. Other models keep their parameters until the ``polish``
    step and take the rms of their grown pixels, which later steps compare.
    """
    fits = dict(fits)
    before = label_sizes(labels, minlength=grown.max(initial=0) + 1)
    after = label_sizes(grown, minlength=before.size)
    changed = [int(k) for k in np.flatnonzero(after > 1.05 * np.maximum(before, 1)) if k > 0]
    refits = ctx.fitter.refit_regions(ctx.xyz, grown, fits, changed, from_points=False)
    for k, refit in refits.items():
        if refit and refit.kind == fits[k].kind:
            fits[k] = refit
    stale = {k: fits[k] for k in changed if k not in refits and fits.get(k)}
    fits.update(pixel_rms(ctx.xyz, grown, stale, ctx.sigma))
    return fits


def grow_regions(ctx: Context, labels: np.ndarray, fits: dict, *, xyz: np.ndarray, ranges: np.ndarray,
                 sigma: np.ndarray, iterations: int, k_sigma: float, jump_ratio: float, jump_min: float,
                 only=None):
    """Grow every fitted region (or those of ``only``) by up to ``iterations`` rings and
    refit; returns new ``(labels, fits)``.

    ``xyz``, ``ranges`` and ``sigma`` are the (H, W) grids; see :func:`grow_into_edges`
    for the acceptance test.
    """
    good = {k: m for k, m in fits.items() if m and (only is None or k in only)}
    if not (iterations and good):
        return labels, fits
    grown = grow_into_edges(xyz, labels, good, sigma, ranges, iterations=iterations,
                            k_sigma=k_sigma, jump_ratio=jump_ratio, jump_min=jump_min)
    return grown, refit_grown(ctx, labels, grown, fits)


#: A border pixel changes region only when the neighbour's model is nearer than its own by
#: more than this many noise sigmas: where two surfaces meet both explain it, and noise
#: alone must not move the border.
SETTLE_MARGIN = 1.0
#: From a curved region to a plane, nearer is enough: a cylinder or sphere fitted over the
#: rim of a neighbouring face (a pipe's end cap, the floor around a column) is pulled towards
#: that rim, so its own distances there are biased low; the simpler model takes the ties.
PLANE_MARGIN = 0.0
#: Rounds of settling and refitting while a curved model was refitted (it moves the border
#: it settles): a cylinder pulled over its end cap's rim gives the cap more of it each round
#: (spinning_128x2048 study seed 1183 scan 0: 189 cap pixels after the split, 147 after one
#: round, 70 after three).
SETTLE_ROUNDS = 3


def settle_regions(ctx: Context, labels: np.ndarray, fits: dict, *, xyz: np.ndarray, ranges: np.ndarray,
                   sigma: np.ndarray, iterations: int, k_sigma: float, jump_ratio: float,
                   jump_min: float, wrap_columns: bool = False):
    """Border pixels go to the neighbouring region whose surface explains them clearly
    better, up to ``iterations`` rings deep; returns new ``(labels, fits)``.

    Growth hands a free pixel to any neighbour that explains it within ``k_sigma`` noise
    sigmas; where a surface meets another at a crease, the one that grew first takes a
    band of the other (a column the bottom of a box face beside it, the floor a box's
    lowest rows, a pipe its end cap: within a few sigmas of the rim the cap is near the
    cylinder too). Once every region has its model, a border pixel whose own model is
    more than ``SETTLE_MARGIN`` sigmas farther than a 4-neighbouring region's (within
    ``k_sigma``, no jump between them) moves there (:func:`rangeseg_o3d.kernels.settle_borders`);
    from a curved region to a plane, ``PLANE_MARGIN`` (nearer is enough). With
    ``wrap_columns`` (a 360-degree grid) the first and last columns are neighbours. The
    regions that changed are refitted, keeping their kind; while that refits a curved
    model, the borders settle again with the new models (at most ``SETTLE_ROUNDS`` rounds).
    """
    good = {k: m for k, m in fits.items() if m}
    if not (iterations and len(good) > 1):
        return labels, fits
    settled = np.array(labels, dtype=np.int32, order="C", copy=True)
    n = int(settled.max(initial=0)) + 1
    fits = dict(fits)
    # (the kernel's flat float64 inputs once, not per round)
    points = np.ascontiguousarray(xyz.reshape(-1, 3), dtype=np.float64)
    noise = np.ascontiguousarray(sigma, dtype=np.float64).ravel()
    flat_ranges = np.ascontiguousarray(ranges, dtype=np.float64).ravel()
    for _ in range(SETTLE_ROUNDS):
        before = settled.copy()
        kinds, params, rms = model_table({k: m for k, m in fits.items() if m}, n)
        moved = kernels.settle_borders(points, settled, kinds, params, rms, noise, flat_ranges, int(iterations),
                                       float(k_sigma), SETTLE_MARGIN, float(jump_ratio), float(jump_min),
                                       PLANE_MARGIN, bool(wrap_columns))
        if not moved:
            break
        if not _refit_settled(ctx, before, settled, fits, n):
            break  # no curved model moved: its border stands where the models put it
    if not (settled != labels).any():
        return labels, fits
    return settled, fits


def _refit_settled(ctx: Context, before: np.ndarray, settled: np.ndarray, fits: dict, n: int) -> bool:
    """Refit, keeping their kind, the regions of ``fits`` (changed in place) whose pixels
    moved between ``before`` and ``settled``; whether a curved model was refitted (a
    cylinder or sphere fitted over the rim of its neighbour's face: with the rim gone the
    refit lies nearer its own surface, and more of the rim leaves it)."""
    moved_mask = settled != before
    touched = np.bincount(np.concatenate([before[moved_mask], settled[moved_mask]]), minlength=n)
    # planes refit from moments (nothing to gather); a curved model only where its region
    # changed by more than 5 % (a few border pixels move nothing; LM refits cost)
    changed = np.flatnonzero(touched).tolist()
    planes = [k for k in changed if isinstance(fits.get(k), Plane)]
    curved = [k for k in changed if fits.get(k) and not isinstance(fits[k], Plane)]
    if curved:  # (the regions' sizes are counted only for a curved one to weigh)
        sizes = label_sizes(settled, minlength=n)
        curved = [k for k in curved if touched[k] > 0.05 * max(sizes[k], 1)]
    refits = ctx.fitter.refit_regions(ctx.xyz, settled, fits, planes, from_points=False)
    refits.update(ctx.fitter.refit_regions(ctx.xyz, settled, fits, curved, from_moments=False))
    refitted_curved = False
    for k, refit in refits.items():
        if refit and refit.kind == fits[k].kind:
            refitted_curved |= k in curved
            fits[k] = refit
    return refitted_curved
