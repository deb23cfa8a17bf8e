"""A laser's one-line bands of another face, given back to that face before ``polish``.

A region can grow along one scan row (or column) of the face it meets: a pipe standing
before a wall takes the single row of the wall's returns level with its top, at the
same range where they meet, reaching 20-35 columns beside it (spinning_64x1024: 19-28
returns of the wall in a 0.14-0.23 m pipe's region of 250-420). One line's returns lie on
any surface through the curve the line sweeps, so they tell nothing of how the surface
bends across the line; but they lie on the plane through the pipe's front, metres off any
cylinder of it: with them the region's plane comes under its threshold (27.5-29.9 mm
under 30) and the decision keeps it a plane, a false fitting of the pipe. Without them the
pipe's own returns give its cylinder (r 0.135-0.138 m of 0.142, 12 mm rms).

:func:`release_bands` gives such a band to the neighbouring region whose model its
returns lie on within the range noise along their rays, where the region without the
band is decided a curved surface its band lies off by more than that noise: the band goes
to its own face (which the scoring counts it to) rather than staying as a curved region's
outliers (a cylinder keeping a wall's 39 returns left the wall under 80 % of its truth,
spinning_64x1024 seed 1010 scan 2). The region's model becomes the one decided without
the band; ``polish`` then holds it to the tests every curved model meets on its final
pixels. Sensor-model quantities only: the range noise per pixel, the rays, ``k_sigma``.
"""

from __future__ import annotations

import numpy as np

from ..fitting.primitives import Plane
from .._numeric import median
from ..fitting.region_fitter import label_sizes, region_indices
from ..fitting.robust import beyond_noise, distance_noise
from .context import Context
from .polish import BEND_LINES, RAY_COS_FLOOR, lines_beside

__all__ = ["line_arms", "release_bands"]


def line_arms(labels: np.ndarray, idx: np.ndarray, wrap_columns: bool) -> np.ndarray:
    """Per flat pixel of ``idx`` (one region's, of the (H, W) ``labels``) whether it has
    neither grid neighbour across one of the grid's lines in its region: none above and
    none below (an arm along a row), or none left and none right (one along a column). Off
    the grid is no neighbour; across the seam of a 360-degree grid (``wrap_columns``) is.

    Such a pixel is a single line's return within its region: it tells nothing of how the
    surface bends across that line."""
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise ValueError(f"labels must be an (H, W) image; got shape {labels.shape}")
    height, width = labels.shape
    flat = labels.ravel()
    idx = np.asarray(idx, np.int64)
    if idx.size and (idx.min() < 0 or idx.max() >= flat.size):
        raise ValueError(f"idx must be flat pixels of the {height}x{width} labels; got {idx.min()}..{idx.max()}")
    # (the region's pixels only: a pass over the image costs ~1 ms, these a few us)
    above, below, left, right = (_across(labels, idx, wrap_columns) == flat[idx][:, None]).T
    return ~(above | below) | ~(left | right)


def _across(labels: np.ndarray, idx: np.ndarray, wrap_columns: bool) -> np.ndarray:
    """``(N, 4)`` the labels of the pixels above, below, left and right of the flat pixels
    ``idx`` of ``labels`` (-1 off the grid; across the seam of a 360-degree grid)."""
    height, width = labels.shape
    flat = labels.ravel()
    row, column = idx // width, idx % width
    out = np.zeros((idx.size, 4), dtype=np.int64)
    out[:, 0] = np.where(row > 0, flat[np.maximum(idx - width, 0)], -1)
    out[:, 1] = np.where(row < height - 1, flat[np.minimum(idx + width, flat.size - 1)], -1)
    if wrap_columns and width > 2:
        out[:, 2] = flat[row * width + (column - 1) % width]
        out[:, 3] = flat[row * width + (column + 1) % width]
    else:
        out[:, 2] = np.where(column > 0, flat[np.maximum(idx - 1, 0)], -1)
        out[:, 3] = np.where(column < width - 1, flat[np.minimum(idx + 1, flat.size - 1)], -1)
    return out


def _sigmas_off(ctx: Context, model, idx: np.ndarray) -> np.ndarray:
    """Per flat pixel of ``idx``, its distance to ``model`` over the noise its range noise
    gives that distance along its ray (floored at ``RAY_COS_FLOOR`` of the range noise)."""
    points = ctx.xyz[idx]
    sigma = ctx.sigma[idx]
    noise = np.maximum(distance_noise(model, points, sigma, ctx.viewing_rays(idx)), RAY_COS_FLOOR * sigma)
    return np.abs(model.distances(points)) / noise


def release_bands(ctx: Context, labels: np.ndarray, fits: dict, *, k_sigma: float,
                  resolve_bends: float = 0.0) -> tuple[np.ndarray, dict]:
    """``(labels, fits)`` with the one-line bands of plane regions given to the neighbouring
    region whose model explains them, where the band is what keeps the region a plane
    (``labels`` and ``fits`` themselves when none is; neither is changed).

    A plane region of ``labels`` whose plane (``fits``) is beyond the range noise
    (``ctx.sigma``, its median over the region: :func:`rangeseg_o3d.fitting.robust.beyond_noise`)
    and which holds line arms (:func:`line_arms`) is decided by the fitter without them,
    when the rest still spans polish's ``BEND_LINES`` grid lines both ways (line by line).
    Where that decision is a curved model, each arm return within ``k_sigma`` of the model of a region across its
    line (above or below for a row's arm, beside it for a column's; the nearer in noise
    units where both are), its distance over the range noise along its ray, and beyond
    ``k_sigma`` of the curved model, goes to that region; the region's model becomes the
    curved one. Released only where at least half the arm returns go (a band of the
    region's own surface lies on the curved model, or on no neighbour's) and where half the
    rest's returns lie within one noise sigma of the curved model (a region holding a pipe
    and a piece of the face behind it is no pipe bent by a band). Models that took returns
    are refitted from moments (a curved neighbour keeps its model). ``resolve_bends``: the decision's keyword as in
    polish (independent samples per pixel; 0 for not asked)."""
    if k_sigma <= 0:
        raise ValueError(f"k_sigma must be positive; got {k_sigma}")
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise ValueError(f"labels must be an (H, W) image; got shape {labels.shape}")
    planes = [k for k, m in fits.items() if isinstance(m, Plane) and m.rms > 0]
    if not planes:
        return labels, fits
    # (a plane the range noise explains has nothing a band could have bent; one within the
    # noise at the scan's least sigma is within it at its own: most planes end here, before
    # their pixels are grouped, ~10 us a scan instead of ~0.3 ms on the LMS200 suite's)
    noise = ctx.sigma[ctx.sigma > 0]
    if not noise.size:
        return labels, fits
    least = float(noise.min())
    sizes = label_sizes(labels, minlength=max(planes) + 1)
    planes = [k for k in planes if sizes[k] and beyond_noise(float(fits[k].rms), least, int(sizes[k]))]
    if not planes:
        return labels, fits
    width = labels.shape[1]
    bends = {"resolve_bends": float(resolve_bends)} if resolve_bends else {}
    out_labels, out_fits = None, None
    flat_labels = labels.ravel()
    # (one comparison over the grid a region costs ~5 us; grouping every pixel ~0.3 ms)
    regions = (region_indices(labels, only=planes) if len(planes) > 8
               else {k: np.flatnonzero(flat_labels == k) for k in planes})
    for k, idx in regions.items():
        if not beyond_noise(float(fits[k].rms), median(ctx.sigma[idx]), idx.size):
            continue
        arms = line_arms(labels, idx, ctx.wrap_columns)
        if not arms.any() or arms.all():
            continue
        body = idx[~arms]
        if min(lines_beside(body, width, True), lines_beside(body, width, False)) < BEND_LINES:
            continue
        band = idx[arms]
        across = _across(labels, band, ctx.wrap_columns)
        # a row's arm has no own pixel above or below: its neighbours across its line are those
        rows_arm = (across[:, 0] != k) & (across[:, 1] != k)
        candidates = np.where(rows_arm[:, None], across[:, :2], across[:, 2:])
        best = np.full(band.size, np.inf)
        owner = np.zeros(band.size, dtype=np.int64)
        for j in np.unique(candidates).tolist():
            if j == k or j <= 0 or not fits.get(j):
                continue
            at = np.flatnonzero((candidates == j).any(axis=1))
            off = _sigmas_off(ctx, fits[j], band[at])
            nearer = off < best[at]
            best[at[nearer]] = off[nearer]
            owner[at[nearer]] = j
        fitting = best <= k_sigma
        if 2 * int(fitting.sum()) < band.size:  # (most of the band is no neighbour's)
            continue
        decided = ctx.fitter.fit(ctx.fitter.points(ctx.xyz, body), **bends)
        if not decided or isinstance(decided, Plane):
            continue
        # the curved model must be the body's own: half its returns within one noise sigma
        # of it (Gaussian noise leaves 68 % there); a region holding a pipe and a piece of the
        # face behind it is no pipe bent by a band (spinning_64x1024 seed 13 scan 0: 79
        # returns of a pipe, 56 of a plane, its cylinder's median 3 sigmas off)
        if float(np.median(_sigmas_off(ctx, decided, body))) > 1.0:
            continue
        released = fitting & (_sigmas_off(ctx, decided, band) > k_sigma)
        if 2 * int(released.sum()) < band.size:
            continue
        if out_labels is None:
            out_labels, out_fits = np.array(labels, copy=True), dict(fits)
        out_labels.ravel()[band[released]] = owner[released]
        out_fits[k] = decided
        touched = np.unique(owner[released]).tolist()
        for j, refit in ctx.fitter.refit_regions(ctx.xyz, out_labels, out_fits, touched,
                                                 from_points=False).items():
            if refit and refit.kind == out_fits[j].kind:
                out_fits[j] = refit
    if out_labels is None:
        return labels, fits
    return out_labels, out_fits
