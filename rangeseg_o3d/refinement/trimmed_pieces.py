"""A piece of a curved surface that also holds returns of no surface: the curved region takes
the part of the piece its model explains, and the rest, a rim along the limb, is freed.

A laser's beam at a column's limb spreads over centimetres of range (the surface turns
away within its footprint, or part of it falls on what lies behind): the return lies off
every surface by more than the noise. The recovery fits a strip of the limb together with
such returns, its own model bent to hold them within the noise, and the union with the
column's region leaves them beyond the parts' rms, so neither merge joins the two
(:func:`rangeseg_o3d.refinement.merge.merge_regions` for two cylinders,
:func:`rangeseg_o3d.refinement.merge.merge_into_curved` for a plane strip). At 2 mm of range
noise seven columns of r 0.19-0.28 m at 5.0-5.9 m of the study scans were split so, up to
45 of a piece's 31-99 returns on no surface.

The union is trimmed instead: the curved model, refitted with the piece's returns that lie
within ``TRIM_SIGMAS`` range sigmas of it (twice: the refit moves the model towards
them), must keep its kind, its rms within ``rms_factor`` of the curved part's and within
the noise; the returns it explains, at least the size floor, join the curved region, and
the rest of the piece, when each of its pixels touches the joined ones (a rim along the
limb), is freed; a piece with more (a face beyond a crease, whose column at the crease
lies on both surfaces) stays whole. The fitter would fit the rim a plane: one or two
columns of returns along a limb lie on one within the noise, whatever they are (two strips
of 20 and 45 such returns at 2 mm rms). A freed return that a region beside it explains
within the noise of its distances is claimed later
(:func:`rangeseg_o3d.refinement.recover.claim_grazing_limbs`); the others stay in no region.

With ``merge_disjoint`` the pieces apart from a curved region are asked too, each only when
the curved model lies within the noise of the piece's returns at the median: a column cut
by a nearer surface crossing before it comes in pieces, and the piece beside the crossing
holds mixed returns along its limbs (nodding_1deg study seed 1456: columns of r 0.13-0.17 m
at 3.9-5.0 m, three and four returns wide, smaller pieces of 26 and 32 px holding 2-3 such
returns 14-41 mm off the union's surface, which the merge refused: both columns counted split).
"""

from __future__ import annotations

import numpy as np

from .._numeric import rows_at
from ..fitting.primitives import Plane
from ..fitting.region_fitter import region_indices
from .context import TRIM_SIGMAS, Context, without
from .merge import beyond_median_noise, pieces_near

__all__ = ["join_trimmed_pieces"]

#: Refits of the union (each with the returns of the piece the last model explains).
REFITS = 2


def join_trimmed_pieces(ctx: Context, labels: np.ndarray, fits: dict, adjacency: set, *,
                        rms_factor: float, apart: set = frozenset(),
                        apart_sigmas: float = 3.0) -> tuple[np.ndarray, dict, set]:
    """Each touching pair of a curved region and a smaller piece (of any kind, at least the
    size floor ``ctx.min_size``), smallest piece first: the returns of the piece that the
    curved model refitted with them explains join the curved region (see the module's
    docstring for the tests). ``apart``: pairs ``(min, max)`` that do not touch, tried too,
    each only when the curved model lies within ``apart_sigmas`` noise sigmas of the piece's
    returns at the median (a column seen above and below a pipe crossing before it: the
    piece below, mixed returns along its limbs, lies off the union's surface by more than
    :func:`rangeseg_o3d.refinement.merge.merge_regions` allows, while its own returns lie on
    it). Returns new ``(labels, fits, adjacency)``; ``labels`` itself when no piece was joined."""
    pairs, regions = _pairs(ctx, labels, fits, adjacency, apart, apart_sigmas)
    fits, flat, changed = dict(fits), None, set()  # (changed: the pairs' labels joined this pass)
    for _, big, small in pairs:
        if big in changed or small in changed:
            continue  # (their pixels or models moved this pass)
        joined = _trimmed_union(ctx, fits[big], regions[big], regions[small], rms_factor)
        if joined is None:
            continue
        union, inside = joined
        rest = without(regions[small], inside)
        if flat is None:
            flat = labels.ravel().copy()
        if not _all_beside(flat, labels.shape, rest, big, ctx.wrap_columns, joining=inside):
            continue  # (a face at a crease: its column there lies on both)
        flat[inside] = big
        fits[big] = union
        flat[rest] = 0
        del fits[small]
        adjacency = {pair for pair in adjacency if small not in pair}
        changed.update((big, small))
    if not changed:
        return labels, fits, adjacency
    return flat.reshape(labels.shape), fits, adjacency


def _pairs(ctx: Context, labels: np.ndarray, fits: dict, adjacency: set, apart: set,
           apart_sigmas: float) -> tuple[list, dict]:
    """``(pairs, regions)``: the ``(size of piece, curved, piece)`` to try, smallest piece
    first (those of ``apart`` past :func:`rangeseg_o3d.refinement.merge.pieces_near`), and
    the flat pixels of their labels."""
    candidates = [(a, b) for a, b in [*adjacency, *sorted(apart)] if fits.get(a) and fits.get(b)
                  and not (isinstance(fits[a], Plane) and isinstance(fits[b], Plane))]
    if not candidates:
        return [], {}
    regions = region_indices(labels, only={k for pair in candidates for k in pair})
    pairs, far = [], []
    for a, b in candidates:
        if a not in regions or b not in regions:
            continue
        big, small = (a, b) if regions[a].size >= regions[b].size else (b, a)
        if not isinstance(fits[big], Plane) and regions[small].size >= ctx.min_size:
            (far if (a, b) in apart else pairs).append((regions[small].size, big, small))
    if far:
        pairs += [pair for pair, near in zip(far, pieces_near(ctx, fits, regions, far, apart_sigmas)) if near]
    pairs.sort()
    return pairs, regions


def _trimmed_union(ctx: Context, curved, region: np.ndarray, piece: np.ndarray, rms_factor: float):
    """``(union, inside)``: the curved model refitted with the pixels ``inside`` of ``piece``
    it explains, when the union passes the module's tests; else None."""
    model, inside = curved, None
    points = rows_at(ctx.xyz, piece)
    band = TRIM_SIGMAS * ctx.sigma[piece]
    for _ in range(REFITS):
        inside = piece[np.abs(model.distances(points)) <= band]
        if inside.size < ctx.min_size:
            return None
        model = ctx.fitter.refit(ctx.fitter.points_of(ctx.xyz, (region, inside)), curved)
        if not model or model.kind != curved.kind:
            return None
    if model.rms > rms_factor * float(curved.rms):
        return None
    if beyond_median_noise(model.rms, ctx.sigma, (region, inside)):
        return None
    return model, inside


def _all_beside(flat: np.ndarray, shape: tuple[int, int], pixels: np.ndarray, label: int, wrap: bool,
                joining: np.ndarray | None = None) -> bool:
    """Whether each of ``pixels`` (flat indices) has one of its eight neighbours labelled
    ``label`` in ``flat`` (the label image, raveled; ``wrap``: the first and last columns are
    neighbours), the pixels ``joining`` (flat indices) counted as ``label``'s."""
    if pixels.size == 0:
        return True
    joining = np.zeros(0, np.int64) if joining is None else joining
    rows, cols = np.divmod(pixels, shape[1])
    beside = np.zeros(pixels.size, bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == dc == 0:
                continue
            r, c = rows + dr, cols + dc
            inside = (r >= 0) & (r < shape[0])
            if wrap:
                c = c % shape[1]
            else:
                inside &= (c >= 0) & (c < shape[1])
            neighbours = r[inside] * shape[1] + c[inside]
            beside[inside] |= (flat[neighbours] == label) | np.isin(neighbours, joining)
    return bool(beside.all())
