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

from .. import kernels  # the package: its names load on first use (no compiler at import)
from .._numeric import unique_ints
from ..fitting.primitives import Plane
from ..fitting.region_fitter import label_sizes
from ..scales import GRAZING_COSINE
from .context import Context
from .grow import SETTLE_MARGIN

__all__ = ["settle_along_rays"]


def _plane_table(fits: dict, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(normals, offsets)`` per label below ``n``: its plane in ``fits``, a zero normal
    where it has none."""
    normals, offsets = np.zeros((n, 3)), np.zeros(n)
    for k, model in fits.items():
        if 0 < k < n and isinstance(model, Plane):
            normals[k], offsets[k] = model.normal, model.d
    return normals, offsets


def _moves(ctx: Context, labels: np.ndarray, table: tuple, ranges: np.ndarray, *, k_sigma: float,
           jump_ratio: float, jump_min: float) -> tuple[np.ndarray, np.ndarray]:
    """``(pixels, targets)``: the flat border pixels of plane regions that one ring moves
    and the plane region each goes to, decided on ``labels`` as they are
    (:func:`rangeseg_o3d.kernels.settle_moves_along_rays`)."""
    normals, offsets = table
    origins = ctx.row_origins
    origins = np.zeros((0, 3)) if origins is None else np.ascontiguousarray(origins, dtype=np.float64)
    return kernels.settle_moves_along_rays(
        np.ascontiguousarray(ctx.xyz, dtype=np.float64), labels, normals, offsets,
        np.ascontiguousarray(ctx.sigma, dtype=np.float64), np.ascontiguousarray(ranges, dtype=np.float64).ravel(),
        origins, float(k_sigma), SETTLE_MARGIN, float(jump_ratio), float(jump_min), GRAZING_COSINE,
        bool(ctx.wrap_columns))


def settle_along_rays(ctx: Context, labels: np.ndarray, fits: dict, *, ranges: np.ndarray, iterations: int,
                      k_sigma: float, jump_ratio: float, jump_min: float) -> tuple[np.ndarray, dict]:
    """Border pixels of plane regions go to the neighbouring plane their range explains
    clearly better, up to ``iterations`` rings deep; returns new ``(labels, fits)``.

    A border pixel (4-adjacent to another plane region, no range jump between them:
    ``<= max(jump_min, jump_ratio * r)``) moves to the neighbour whose plane is within
    ``k_sigma`` range sigmas of it along its ray (its distance over the range noise times
    the incidence cosine, floored at :data:`rangeseg_o3d.scales.GRAZING_COSINE`: a ray
    nearer grazing than the jump test allows is no measurement of a plane's depth; rays
    from where the sensor's rays start, :attr:`Context.row_origins`) and nearer than its
    own plane by more than ``SETTLE_MARGIN`` of them; the planes that changed are refitted from moments
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
    normals, offsets = table = _plane_table(fits, n)  # kept as the planes are refitted
    for _ in range(iterations):
        idx, targets = _moves(ctx, settled, table, ranges, k_sigma=k_sigma, jump_ratio=jump_ratio,
                              jump_min=jump_min)
        if not idx.size:
            break
        flat = settled.reshape(-1)
        touched = unique_ints(np.concatenate([flat[idx], targets])).tolist()
        flat[idx] = targets
        for k, refit in ctx.fitter.refit_regions(ctx.xyz, settled, fits, touched, from_points=False).items():
            if refit and refit.kind == "plane":
                fits[k] = refit
                if 0 < k < n:  # its row of _plane_table(fits, n)
                    normals[k], offsets[k] = (refit.normal, refit.d) if isinstance(refit, Plane) else (0.0, 0.0)
    left = label_sizes(settled, minlength=n)  # (compiled: numpy's bincount widens the labels first)
    for k in [k for k in fits if 0 < k < n and left[k] == 0 and np.any(labels == k)]:
        del fits[k]
    return settled, fits
