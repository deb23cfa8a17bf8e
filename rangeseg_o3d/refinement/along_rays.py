"""Step 9, ``rays``: a laser's border pixels go to the neighbouring plane their range explains.

A laser's single return errs along its ray only: the noise of its distance to a plane is
the range noise times the incidence cosine of its ray, not the range noise. Growth and
``settle`` measure a pixel's distance to a plane in units of the range noise, so a plane
seen near grazing (a box top at incidence cosine 0.1, a side face at 0.3) takes the pixels
of the face it meets within three range sigmas of its distances: the top rows of the front
face below it, a column of the front face beside it (noise_20mm seed 89 scan 6, seed 0
scan 2, seed 71 scan 3), and a least-squares plane of a strip three rows high, as thick
as the noise, can turn to lie along the rays (seed 0 scan 2: a horizontal plane over the
top rows of a box's front face). Measured along the rays, in range sigmas, those pixels
are 5-10 sigmas off the grazing plane and within one of their own face's.

:func:`settle_along_rays` moves each border pixel of a plane region to the 4-neighbouring
plane region whose plane meets its ray within ``k_sigma`` range sigmas of its range and
nearer by more than ``SETTLE_MARGIN`` sigmas than its own plane does, ring by ring, the
planes refitted from moments after each ring. Only for a laser's single returns
(:func:`rangeseg_o3d.refinement.single_returns`): a tile's mean or a camera's return
errs otherwise.
"""

from __future__ import annotations

import numpy as np

from ..fitting.primitives import Plane
from ..scales import GRAZING_COSINE
from .context import Context
from .grow import SETTLE_MARGIN

__all__ = ["settle_along_rays", "range_sigmas"]

# (row, column) steps to the four neighbours
_STEPS = ((-1, 0), (1, 0), (0, -1), (0, 1))


def range_sigmas(points: np.ndarray, rays: np.ndarray, sigma: np.ndarray, normal: np.ndarray,
                 offset: np.ndarray) -> np.ndarray:
    """How many range sigmas each point is from where its ray meets its plane.

    ``points``, ``rays`` (unit, from where the sensor's rays start) and ``normal`` are
    ``(N, 3)``, ``sigma`` (range noise) and ``offset`` ``(N,)``: the plane ``normal . p =
    offset`` of each point. A range error moves a point along its ray, so its distance to
    the plane is the range error times the incidence cosine; the cosine is floored at
    :data:`rangeseg_o3d.scales.GRAZING_COSINE` (a ray nearer grazing than the jump test
    allows is no measurement of the plane's depth).
    """
    distance = np.abs(np.einsum("ij,ij->i", points, normal) - offset)
    cosine = np.maximum(np.abs(np.einsum("ij,ij->i", rays, normal)), GRAZING_COSINE)
    return distance / (np.maximum(sigma, 1e-12) * cosine)


def _plane_table(fits: dict, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(normals, offsets)`` per label below ``n``: its plane in ``fits``, a zero normal
    where it has none."""
    normals, offsets = np.zeros((n, 3)), np.zeros(n)
    for k, model in fits.items():
        if 0 < k < n and isinstance(model, Plane):
            normals[k], offsets[k] = model.normal, model.d
    return normals, offsets


def _neighbours(idx: np.ndarray, step: tuple[int, int], shape: tuple[int, int], wrap: bool) -> np.ndarray:
    """The flat neighbour ``step = (dr, dc)`` of each flat pixel ``idx``, -1 off the grid
    (across the columns' seam with ``wrap``)."""
    h, w = shape
    rows, cols = np.divmod(idx, w)
    rows, cols = rows + step[0], cols + step[1]
    if wrap:
        cols = cols % w
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    return np.where(inside, rows * w + cols, -1)


def _borders(labels: np.ndarray, planar: np.ndarray, wrap: bool) -> np.ndarray:
    """The flat pixels of plane regions with a 4-neighbour in another region (increasing)."""
    differs = np.zeros(labels.shape, bool)
    across = labels[1:] != labels[:-1]
    differs[1:] |= across
    differs[:-1] |= across
    along = labels[:, 1:] != labels[:, :-1]
    differs[:, 1:] |= along
    differs[:, :-1] |= along
    if wrap:  # the first and last columns are neighbours
        seam = labels[:, 0] != labels[:, -1]
        differs[:, 0] |= seam
        differs[:, -1] |= seam
    return np.flatnonzero(differs & planar[labels])


def _moves(ctx: Context, labels: np.ndarray, table: tuple, ranges: np.ndarray, *, k_sigma: float,
           jump_ratio: float, jump_min: float) -> tuple[np.ndarray, np.ndarray]:
    """``(pixels, targets)``: the flat border pixels of plane regions that one ring moves
    and the plane region each goes to (decided on ``labels`` as they are)."""
    normals, offsets = table
    planar = np.any(normals != 0.0, axis=1)
    flat, flat_ranges = labels.ravel(), ranges.ravel()
    idx = _borders(labels, planar, ctx.wrap_columns)
    points, rays, sigma = ctx.xyz[idx], ctx.viewing_rays(idx), ctx.sigma[idx]
    own = flat[idx]
    mine = range_sigmas(points, rays, sigma, normals[own], offsets[own])
    # a move needs a neighbour nearer by SETTLE_MARGIN: pixels their own plane explains that
    # well stay (most of a border), and are not looked at again
    keep = mine > SETTLE_MARGIN
    idx, points, rays, sigma, own, mine = idx[keep], points[keep], rays[keep], sigma[keep], own[keep], mine[keep]
    best = np.full(idx.size, np.inf)
    target = np.zeros(idx.size, np.int64)
    for step in _STEPS:
        j = _neighbours(idx, step, labels.shape, ctx.wrap_columns)
        k = np.where(j >= 0, flat[np.maximum(j, 0)], 0)
        r, other = flat_ranges[idx], flat_ranges[np.maximum(j, 0)]
        # no jump between the two (growth's test): a step onto another surface is no border
        smooth = np.abs(r - other) <= np.maximum(jump_min, jump_ratio * np.fmin(r, other))
        ask = np.flatnonzero((j >= 0) & (k != own) & planar[k] & smooth)
        score = range_sigmas(points[ask], rays[ask], sigma[ask], normals[k[ask]], offsets[k[ask]])
        better = score < best[ask]
        best[ask[better]], target[ask[better]] = score[better], k[ask[better]]
    move = (target > 0) & (best <= k_sigma) & (best < mine - SETTLE_MARGIN)
    return idx[move], target[move]


def settle_along_rays(ctx: Context, labels: np.ndarray, fits: dict, *, ranges: np.ndarray, iterations: int,
                      k_sigma: float, jump_ratio: float, jump_min: float) -> tuple[np.ndarray, dict]:
    """Border pixels of plane regions go to the neighbouring plane their range explains
    clearly better, up to ``iterations`` rings deep; returns new ``(labels, fits)``.

    A border pixel (4-adjacent to another plane region, no range jump between them:
    ``<= max(jump_min, jump_ratio * r)``) moves to the neighbour whose plane is within
    ``k_sigma`` range sigmas of it along its ray (:func:`range_sigmas`, rays from where
    the sensor's rays start, :meth:`Context.viewing_rays`) and nearer than its own plane by
    more than ``SETTLE_MARGIN`` of them; the planes that changed are refitted from moments
    after each ring. A region left without pixels loses its model. ``labels`` and ``fits``
    are not changed.
    """
    if iterations < 0:
        raise ValueError(f"iterations must be >= 0; got {iterations}")
    if np.shape(ranges) != np.shape(labels):
        raise ValueError(f"ranges must have the labels' shape {np.shape(labels)}; got {np.shape(ranges)}")
    if sum(isinstance(m, Plane) for m in fits.values()) < 2:
        return labels, fits
    settled = np.array(labels, dtype=np.int32, copy=True)
    fits = dict(fits)
    n = int(settled.max(initial=0)) + 1
    for _ in range(iterations):
        idx, targets = _moves(ctx, settled, _plane_table(fits, n), ranges, k_sigma=k_sigma,
                              jump_ratio=jump_ratio, jump_min=jump_min)
        if not idx.size:
            break
        flat = settled.reshape(-1)
        touched = np.unique(np.concatenate([flat[idx], targets])).tolist()
        flat[idx] = targets
        for k, refit in ctx.fitter.refit_regions(ctx.xyz, settled, fits, touched, from_points=False).items():
            if refit and refit.kind == "plane":
                fits[k] = refit
    left = np.bincount(settled.ravel(), minlength=n)
    for k in [k for k in fits if 0 < k < n and left[k] == 0 and np.any(labels == k)]:
        del fits[k]
    return settled, fits
