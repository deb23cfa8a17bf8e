"""A laser's mixed returns: one return between two surfaces, its region released.

A laser's beam has a footprint: where it straddles an occlusion (the limb of a column, the
edge of a box before a wall), the return is a range between the two surfaces, on neither.
Along a limb such returns form a line one pixel wide with a few of the surface's own
pixels beside it, which the recovery of thin strips takes for a plane and the settling
then feeds with the limb's pixels its plane explains better than the column's cylinder:
a region no surface stands for, and the surface it holds pixels of counts as split
(noise_2mm study seed 1187 scan 5: a column's 335 px and a 35-px plane of 27 mixed returns
beside its limb holding 8 of its pixels). Only a laser's single returns straddle so: a
camera's tile mean at an occlusion is a depth between the surfaces as well, but so is any
tile's on a slope (the segmenter's jump test tells them apart instead).
"""

from __future__ import annotations

import numpy as np

from .. import kernels  # the package: its names load on first use
from ..fitting.primitives import Plane
from ..fitting.region_fitter import label_sizes, region_indices
from ..fullres import resolved_refit
from .context import Context, returns_across, touching
from .dissolve import explained_by_hosts

__all__ = ["mixed_returns", "planes_under_mixed_returns", "release_mixed_returns"]

#: A step is beyond the noise when it exceeds this many noise sigmas of the difference of
#: two returns (each erring by the range noise: sqrt 2 of it).
STEP_SIGMAS = 3.0
#: A neighbour's own step away from the return is "flat" when under this share of the
#: return's step to it: a surface stepping steadily (a face near grazing) continues its
#: steps, a surface the beam straddled onto does not.
CONTINUED = 0.5
#: The fewest returns across (along a row and along a column, the median of each) a curved
#: region's other returns must span for :func:`planes_under_mixed_returns` to ask whether a
#: plane explains them: two returns across lie on a line whatever the surface (a column 4
#: returns wide whose two limbs pass the mixed test: nodding_1deg study seed 1211 scan 3).
BEND_SAMPLES = 3
#: The fewest returns across (as :data:`BEND_SAMPLES` counts them) of a region holding returns
#: of its own between its limbs: mixed returns line a limb one return wide, so a region of them
#: and a few of the surface's own beside it spans fewer. A pipe four returns wide at low noise
#: has both limbs pass the mixed test in every row (its bend steps them off the middle two by
#: far more than three noise sigmas), which is half its returns: noise_2mm study seed 1276
#: scan 2, a column of r 0.13 m at 4.1-4.6 m, 175 px fitted as a cylinder within its noise,
#: was released whole.
OWN_ACROSS = 4


def mixed_returns(ranges: np.ndarray, idx: np.ndarray, sigma: np.ndarray, *,
                  wrap_columns: bool = False) -> np.ndarray:
    """Whether each of the flat pixels ``idx`` of the (H, W) ``ranges`` (NaN: no return) is a
    mixed return: along its row or its column, its range lies between its two neighbours'
    by more than ``STEP_SIGMAS`` noise sigmas of a difference on each side (``sigma``: the
    (H, W) range noise), and neither neighbour continues its step (its own step onward is
    under ``CONTINUED`` of the step to the return; one with no return beyond it, or at the
    grid's edge, tells nothing and the return is not taken for mixed). With
    ``wrap_columns`` the first and last columns are neighbours.
    """
    ranges = np.ascontiguousarray(ranges, dtype=np.float64)
    if ranges.ndim != 2 or np.shape(sigma) != ranges.shape:
        raise ValueError(f"mixed_returns: expected (H, W) ranges and sigma of one shape; got {ranges.shape} "
                         f"and {np.shape(sigma)}")
    idx = np.ascontiguousarray(idx, dtype=np.int64)
    if idx.size and not (0 <= int(idx.min()) and int(idx.max()) < ranges.size):
        raise ValueError(f"mixed_returns: expected flat pixel indices in [0, {ranges.size}); got "
                         f"{int(idx.min())}..{int(idx.max())}")
    return kernels.mixed_at(ranges, np.ascontiguousarray(sigma, dtype=np.float64), idx, STEP_SIGMAS, CONTINUED,
                            bool(wrap_columns))


def release_mixed_returns(ctx: Context, labels: np.ndarray, fits: dict, *, ranges: np.ndarray,
                          k_sigma: float, wrap_columns: bool = False) -> tuple[np.ndarray, dict]:
    """``(labels, fits)`` without the regions at least half of whose pixels are mixed
    returns (:func:`mixed_returns`) that span fewer than :data:`OWN_ACROSS` returns across:
    each of their other pixels goes to the touching fitted
    region (within two pixels) whose model explains it best within ``k_sigma max(sigma,
    rms)``, or is freed; the mixed returns are freed. The regions that took pixels are
    refitted, keeping their kind. A region of mixed returns lies along a limb or an edge: at
    most twice the grid's longer side, the regions looked at. Returns the inputs when
    nothing changed."""
    sizes = label_sizes(labels)
    cap = 2 * max(labels.shape)
    small = [k for k, m in fits.items() if m and 0 < k < sizes.size and 0 < sizes[k] <= cap]
    if not small:
        return labels, fits
    sigma, counts = _mixed_counts(ctx, labels, ranges, small, sizes.size, wrap_columns)
    mostly_mixed = [k for k in small if 2 * counts[k] >= sizes[k]]
    if not mostly_mixed:
        return labels, fits
    regions = region_indices(labels, only=mostly_mixed)
    released = [k for k in mostly_mixed if returns_across(regions[k], labels.shape[1]) < OWN_ACROSS]
    if not released:
        return labels, fits
    out, kept, took = labels.copy(), dict(fits), set()
    for k in sorted(released, key=lambda k: (sizes[k], k)):
        idx = regions[k]
        own_mixed = mixed_returns(ranges, idx, sigma, wrap_columns=wrap_columns)
        out.reshape(-1)[idx] = 0
        del kept[k]
        rest = idx[~own_mixed]
        hosts = sorted(h for h in touching(out, idx, reach=2) if h != k and kept.get(h))
        if rest.size and hosts:
            scatter = np.array([kept[h].rms for h in hosts])[:, None]
            explained, best, _ = explained_by_hosts(ctx, rest, kept, hosts, scatter, k_sigma)
            to = np.asarray(hosts)[best[explained]]
            out.reshape(-1)[rest[explained]] = to
            took.update(np.unique(to).tolist())
    for h, refit in ctx.fitter.refit_regions(ctx.xyz, out, kept, sorted(took & kept.keys())).items():
        if refit and refit.kind == kept[h].kind:
            kept[h] = refit
    return out, kept


def _mixed_counts(ctx: Context, labels: np.ndarray, ranges: np.ndarray, looked_at: list, n: int,
                  wrap_columns: bool) -> tuple[np.ndarray, np.ndarray]:
    # the (H, W) noise and, in one compiled pass, the mixed returns of each region of
    # ``looked_at`` (the per-pixel test then runs on the regions a step changes)
    asked = np.zeros(n, dtype=bool)
    asked[looked_at] = True
    sigma = np.ascontiguousarray(ctx.sigma, dtype=np.float64).reshape(labels.shape)
    counts = kernels.mixed_counts(np.ascontiguousarray(labels, dtype=np.int32),
                                  np.ascontiguousarray(ranges, dtype=np.float64), sigma, asked,
                                  STEP_SIGMAS, CONTINUED, bool(wrap_columns))
    return sigma, counts


def planes_under_mixed_returns(ctx: Context, labels: np.ndarray, fits: dict, *, ranges: np.ndarray,
                               wrap_columns: bool = False) -> tuple[np.ndarray, dict]:
    """``(labels, fits)`` where each small cylinder or sphere region holding mixed returns
    (:func:`mixed_returns`) that the fitter gives a plane once they are left out becomes
    that plane over its other pixels, its mixed returns freed. A narrow box face a few
    returns wide beside an occlusion keeps the returns its edges mixed with the wall behind,
    and they, not the face, bend its fit: noise_20mm study seeds 1212 and 1214 (faces of 72
    and 74 px at 4.5 and 3.9 m, five returns wide, with 13 and 4 mixed returns: a sphere of
    1.5 m, a cylinder of 0.32 m; without them a plane within the noise).

    A curved surface keeps its bend without its limbs' returns: the region stays curved when
    its model refitted to the other returns lowers the plane's squares by more than the noise
    would (:func:`rangeseg_o3d.fullres.resolved_refit`, an F-test; a pipe of 0.15 m at 3.1 m whose
    limbs' returns pass the mixed test, noise_20mm seed 1210 scan 5), and when those returns
    span fewer than :data:`BEND_SAMPLES` across. Regions of at most twice the grid's longer
    side are looked at, as :func:`release_mixed_returns` does. Returns the inputs when nothing
    changed."""
    sizes = label_sizes(labels)
    cap = 2 * max(labels.shape)
    curved = [k for k, m in fits.items()
              if m and m.kind in ("cylinder", "sphere") and 0 < k < sizes.size and 0 < sizes[k] <= cap]
    if not curved:
        return labels, fits
    sigma, counts = _mixed_counts(ctx, labels, ranges, curved, sizes.size, wrap_columns)
    holding = [k for k in curved if counts[k] > 0 and sizes[k] - counts[k] >= ctx.min_size]
    if not holding:
        return labels, fits
    out, kept = None, dict(fits)
    for k, idx in region_indices(labels, only=holding).items():
        own_mixed = mixed_returns(ranges, idx, sigma, wrap_columns=wrap_columns)
        rest = idx[~own_mixed]
        if returns_across(rest, labels.shape[1]) < BEND_SAMPLES:
            continue
        points = ctx.fitter.points(ctx.xyz, rest)
        model = ctx.fitter.fit(points)
        # (a pipe's own bend outlives its limbs: its model refitted to the other returns still
        # lowers the plane's squares by more than the noise would)
        if isinstance(model, Plane) and resolved_refit(ctx.fitter, points, fits[k], model.rms) is None:
            out = labels.copy() if out is None else out
            out.reshape(-1)[idx[own_mixed]] = 0
            kept[k] = model
    return (labels, fits) if out is None else (out, kept)

