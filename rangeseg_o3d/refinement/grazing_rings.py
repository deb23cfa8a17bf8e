"""Faces a spinning lidar sees so near grazing that every step between its rings is a range
jump: recovered from the ring arcs no region took.

A box top a few decimetres high seen from a metre or more above it by a spinning lidar
meets its rays 86-89 degrees from head-on: each ring crossing it is one arc of returns, the
next ring's arc lies tens of centimetres farther, and every return of the face is marked a
range jump. Growth never crosses a jump, the leftover blobs leave jump pixels out and need
a 3x3 core, and no region touches the face to claim it
(:func:`rangeseg_o3d.refinement.recover.claim_grazing_limbs` takes the far row of a face
it found). Region growing finds such faces; of the 18 surfaces the residual edges missed on
36 study scans of 128 x 2048, 9 lay mostly in no region (faces of 66-215 returns on one to
three rings).

The free returns are grouped by their arcs: runs along a ring whose range steps are no
jumps, joined to the runs of the next ring they touch (8-neighbours, across the seam of the
360-degree grid too), whatever the step between them. Each group of at least the size floor
is split into the surfaces it holds (:func:`rangeseg_o3d.refinement.recover.split_blobs`);
a surface found is kept when it is a plane seen beyond ``scales.GRAZING_COSINE`` of head-on
(the incidence at which the steps between rings become jumps: a face seen less obliquely is
the recovery's and growth's) whose returns span two columns at least and which passes the
sensor farther than three range sigmas. A column's returns lie on the plane through its
rays (the vertical fan of one azimuth), as do mixed returns strewn along their rays at a
jump edge: such a plane passes through the sensor (spinning_64x1024 study seeds
1127-1132: pieces of 20-26 returns over one column, incidence cosine and rms 0 to the
printed digits). So does the plane fitted to one
ring's arc of a face: a short arc is nearly a line, about which the plane turns freely (a
box top's single ring of 114 returns at 2.6 m: the plane 2.7 cm from the sensor, 89.4
degrees from its rays); a face on one ring stays free.
"""

from __future__ import annotations

import numpy as np

from ..fitting.primitives import Plane
from ..fitting.region_fitter import fresh_label
from ..scales import GRAZING_COSINE
from .context import Context

__all__ = ["recover_grazing_rings", "ring_arc_groups"]


def recover_grazing_rings(ctx: Context, labels: np.ndarray, fits: dict, *, ranges: np.ndarray,
                          jump_ratio: float, jump_min: float) -> tuple[np.ndarray, dict]:
    """The faces seen beyond grazing among the free returns (see the module's docstring).

    ``ranges``: (H, W), NaN where no return; ``jump_ratio`` and ``jump_min`` the jump test
    (a step between neighbours over ``max(jump_min, jump_ratio * nearer range)``). Returns
    new ``(labels, fits)``, or the inputs when no face was found."""
    from .recover import split_blobs

    if np.shape(ranges) != labels.shape:
        raise ValueError(f"recover_grazing_rings: ranges must have the labels' shape {labels.shape}, "
                         f"got {np.shape(ranges)}")
    start = fresh_label(labels, fits)
    groups = ring_arc_groups(labels == 0, ranges, jump_ratio=jump_ratio, jump_min=jump_min,
                             min_size=ctx.min_size, first_label=start, wrap_columns=ctx.wrap_columns)
    if groups is None:
        return labels, fits
    found, found_fits = split_blobs(ctx, labels, fits, groups)
    flat = found.ravel()
    kept = False
    for k in [k for k in found_fits if k >= start]:
        idx = np.flatnonzero(flat == k)
        if idx.size and _grazing_face(ctx, found_fits[k], idx):
            kept = True
            continue
        flat[idx] = 0
        del found_fits[k]
    return (found, found_fits) if kept else (labels, fits)


def ring_arc_groups(free: np.ndarray, ranges: np.ndarray, *, jump_ratio: float, jump_min: float,
                    min_size: int, first_label: int, wrap_columns: bool = False):
    """``(H, W)`` int32 groups of the ``free`` pixels with a range, numbered from
    ``first_label`` (0 elsewhere), each at least ``min_size`` pixels; None when there are
    none. A group: runs along a row whose range steps are no jumps, joined to the runs of
    the next row they touch (8-neighbours), and across the seam with ``wrap_columns``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    h, w = free.shape
    free = free & np.isfinite(ranges)
    if int(free.sum()) < min_size:
        return None

    def no_jump(a, b):
        return np.abs(a - b) <= np.maximum(jump_min, jump_ratio * np.minimum(a, b))

    along = free[:, :-1] & free[:, 1:] & no_jump(ranges[:, :-1], ranges[:, 1:])
    starts = free.copy()
    starts[:, 1:] &= ~along
    run = (np.cumsum(starts.ravel()).reshape(h, w) * free).astype(np.int64)  # run ids from 1
    n = int(run.max())
    first, second = [], []
    if wrap_columns:  # the last column's run goes on in the first column's
        seam = free[:, -1] & free[:, 0] & no_jump(ranges[:, -1], ranges[:, 0])
        first.append(run[seam, -1])
        second.append(run[seam, 0])
    for dc in (-1, 0, 1):  # the runs of the next row each run touches, whatever the step
        lo, hi = max(0, -dc), min(w, w - dc)
        a, b = run[:-1, lo:hi], run[1:, lo + dc:hi + dc]
        both = (a > 0) & (b > 0)
        first.append(a[both])
        second.append(b[both])
        if wrap_columns and dc:  # diagonal neighbours across the seam
            edge_a, edge_b = (run[:-1, 0], run[1:, -1]) if dc < 0 else (run[:-1, -1], run[1:, 0])
            both = (edge_a > 0) & (edge_b > 0)
            first.append(edge_a[both])
            second.append(edge_b[both])
    first, second = np.concatenate(first), np.concatenate(second)
    graph = coo_matrix((np.ones(first.size, np.int8), (first, second)), shape=(n + 1, n + 1))
    _, component = connected_components(graph, directed=False)
    ids, inverse, counts = np.unique(component[run[free]], return_inverse=True, return_counts=True)
    keep = counts >= min_size
    if not keep.any():
        return None
    number = np.zeros(ids.size, np.int32)
    number[keep] = first_label + np.arange(int(keep.sum()), dtype=np.int32)
    groups = np.zeros((h, w), np.int32)
    groups[free] = number[inverse.ravel()]
    return groups


def _grazing_face(ctx: Context, model, idx: np.ndarray) -> bool:
    """Whether the region of flat pixels ``idx`` is a plane seen beyond ``GRAZING_COSINE`` of
    head-on, over two columns at least, that passes the sensor farther than three range
    sigmas (the plane through one column's rays, or through mixed returns strewn along
    their rays, passes through it)."""
    if not isinstance(model, Plane):
        return False
    cols = idx % ctx.width
    if cols.min() == cols.max():
        return False
    normal = np.asarray(model.normal, dtype=float)
    cosine = float(np.median(np.abs(ctx.viewing_rays(idx) @ normal)))
    origins = ctx.ray_origins(idx)
    apart = np.abs(float(model.d) - (0.0 if origins is None else origins @ normal))
    return cosine < GRAZING_COSINE and float(np.median(apart)) > 3.0 * float(np.median(ctx.sigma[idx]))
