"""Step 1, ``split``: a region no model explains is split into all the surfaces it holds.

The paper's "local checks that remove under-segmentation" (Sec. 6): least trimmed squares
(:func:`rangeseg_o3d.fitting.robust.trimmed_fit`), one surface after the other, each cut
to its largest connected piece; only what no surface takes is freed.
"""

from __future__ import annotations

import numpy as np

from ..fitting.region_fitter import region_indices
from ..fitting.robust import beyond_noise
from ..scales import GRAZING_COSINE
from .context import TRIM_SIGMAS, Context, without

__all__ = ["split_regions"]

# searches per split region (found surfaces and failed pieces alike): bounds the split's time
_MAX_SPLIT_ATTEMPTS = 24


def split_regions(ctx: Context, labels: np.ndarray, fits: dict, failed: list[int], *,
                  pixels: dict | None = None, own: bool = False, held: float | None = None,
                  face_band: bool = False):
    """Split every region of ``failed`` into all the surfaces it holds; returns new ``(labels, fits)``.

    Sequential robust extraction with connectivity kept: the dominant surface of a
    connected pool of the region's pixels, cut to its largest 4-connected piece, becomes a
    region; the rest of the pool falls apart into its connected pieces, and each is
    searched in turn, until every piece is smaller than the size floor or no model
    explains enough of it. Regions leaking through creases the edge image missed (floor,
    walls and the objects on them in one) come back as one region per surface; what no
    surface takes (the crease bands) is freed for growth. A region of which nothing is
    explained keeps its failure (reported as unfitted). The first surface found keeps the
    region's label, the others take new labels above the largest. ``pixels`` (optional):
    the flat pixels (increasing) of each failed region, when the caller has them (saves a
    pass over the grid). ``own``: ``labels`` is the caller's own C-ordered int32 copy, which
    this split may change in place and return (a frame-sized copy less at full resolution).
    ``held`` (metres, None: not held): a plane found is held to the noise of its own
    distances, at least ``held`` (:func:`_held_to_distance_noise`; the regions the
    segmenter could not fit, where a face seen near grazing meets the faces beyond it).
    ``face_band``: :meth:`Context.dominant_piece`'s.
    """
    labels, fits = (labels if own else labels.copy()), dict(fits)
    flat = labels.ravel()
    if pixels is None:
        pixels = region_indices(labels)
    regions = {k: pixels[k] for k in sorted(failed) if k in pixels}
    next_label = int(labels.max(initial=0)) + 1
    for k, idx in regions.items():
        label, found = k, False
        pools = ctx.pieces(idx)
        attempts = 0
        while pools and attempts < _MAX_SPLIT_ATTEMPTS:
            attempts += 1
            pool = pools.pop()  # the largest piece (pools are kept sorted by size)
            piece, model = ctx.dominant_piece(pool, face_band=face_band)
            if piece is None:
                continue
            if held is not None:
                piece, model = _held_to_distance_noise(ctx, piece, model, held)
            if not found:
                flat[idx] = 0  # the failed region dissolves into what is found
                found = True
            flat[piece] = label
            fits[label] = model
            label, next_label = next_label, next_label + 1
            pools.extend(ctx.pieces(without(pool, piece)))
            pools.sort(key=len)
    return labels, fits


def _held_to_distance_noise(ctx: Context, piece: np.ndarray, model, floor: float):
    """``(piece, model)`` as the search found them, or, for a plane whose distances to its
    piece are beyond their noise (range noise x incidence cosine, the cosine at least
    ``scales.GRAZING_COSINE``, the noise at least ``floor``; chi-square bound), the largest connected part of the piece
    within ``TRIM_SIGMAS`` of that noise and the plane refitted to it, when that part keeps
    the size floor. A face seen close to grazing has its plane along the rays beside it:
    the face or ball behind it, a metre away along those rays, lies within the range noise
    of that plane (the search's test) but not within the noise the incidence leaves."""
    if model.kind != "plane":
        return piece, model
    distances, noise = _distances_and_noise(ctx, piece, model, floor)
    if not _beyond(distances, noise):
        return piece, model
    held = ctx.largest_piece(piece[distances <= TRIM_SIGMAS * noise])
    if held.size < ctx.min_size or ctx.largest_piece(without(piece, held)).size < ctx.min_size:
        return piece, model  # no face of its own, or nothing but scattered pixels off it
    refit = ctx.fitter.refit(ctx.fitter.points(ctx.xyz, held), model)
    if not refit or refit.kind != "plane" or _beyond(*_distances_and_noise(ctx, held, refit, floor)):
        return piece, model  # no face within its noise there: the search's answer stands
    return held, refit


def _distances_and_noise(ctx: Context, idx: np.ndarray, plane, floor: float):
    # the pixels' absolute distances to the plane and the noise of each (range noise x
    # incidence cosine, the cosine at least scales.GRAZING_COSINE, the noise at least ``floor``)
    points = ctx.xyz[idx]
    rays = points / np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-12)
    noise = np.maximum(ctx.sigma[idx] * np.maximum(np.abs(rays @ plane.normal), GRAZING_COSINE), floor)
    return np.abs(plane.distances(points)), noise


def _beyond(distances: np.ndarray, noise: np.ndarray) -> bool:
    # the distances' rms beyond the noise's (chi-square bound, fitting.robust.beyond_noise)
    return beyond_noise(float(np.sqrt(np.mean(distances ** 2))), float(np.sqrt(np.mean(noise ** 2))),
                        int(distances.size))

