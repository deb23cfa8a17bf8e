"""Step 1, ``split``: a region no model explains is split into all the surfaces it holds.

The paper's "local checks that remove under-segmentation" (Sec. 6): least trimmed squares
(:func:`rangeseg_o3d.fitting.robust.trimmed_fit`), one surface after the other, each cut
to its largest connected piece; only what no surface takes is freed.
"""

from __future__ import annotations

import numpy as np

from .._numeric import rows_at

from ..fitting.region_fitter import fresh_label, region_indices
from ..fitting.robust import beyond_noise, distance_noise
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
    ``face_band``: :meth:`Context.dominant_piece`'s; when that band found one of a region's
    surfaces, the region's pixels the planes found took go each to the plane it lies
    nearest (:func:`_to_nearest_plane`): the face the one-sigma band found holds a strip of
    its neighbour along the corner, which the sequential extraction does not give back.
    """
    labels, fits = (labels if own else labels.copy()), dict(fits)
    flat = labels.ravel()
    if pixels is None:
        pixels = region_indices(labels)
    regions = {k: pixels[k] for k in sorted(failed) if k in pixels}
    next_label = fresh_label(labels, fits)
    for k, idx in regions.items():
        label, found, by_band = k, False, False
        surfaces = []
        pools = ctx.pieces(idx)
        attempts = 0
        while pools and attempts < _MAX_SPLIT_ATTEMPTS:
            attempts += 1
            pool = pools.pop()  # the largest piece (pools are kept sorted by size)
            piece, model, by_face_band = ctx.dominant_search(pool, face_band=face_band, after_band=by_band)
            if piece is None:
                continue
            by_band = by_band or by_face_band
            if held is not None:
                piece, model = _held_to_distance_noise(ctx, piece, model, held)
            if not found:
                flat[idx] = 0  # the failed region dissolves into what is found
                found = True
            flat[piece] = label
            fits[label] = model
            surfaces.append(label)
            label, next_label = next_label, next_label + 1
            pools.extend(ctx.pieces(pool, piece))
            pools.sort(key=len)
        if by_band:  # (the labels found increase: the region's own, then new ones above the largest)
            _to_nearest_plane(ctx, flat, fits, idx, [s for s in surfaces if fits[s].kind == "plane"])
    return labels, fits


def _to_nearest_plane(ctx: Context, flat: np.ndarray, fits: dict, idx: np.ndarray, planes: list[int]) -> None:
    """Each of the flat pixels ``idx`` that one of ``planes`` took goes to the plane it lies
    fewest noise sigmas off (the noise of its distance: range noise x incidence cosine),
    when within ``TRIM_SIGMAS`` of it; each plane keeps its largest connected piece,
    refitted. Changes ``flat`` and ``fits`` in place, or nothing when a plane would keep
    less than the size floor or its refit fails.

    The sequential extraction gives each pixel to the first surface whose band holds it;
    at a corner of two faces a few noise sigmas wide (a 20 mm laser's box), the face found
    first keeps a strip of the other one along the corner, enough to make its region
    impure, and the settle step's margin in range noise does not move it back."""
    if len(planes) < 2:
        return
    taken = idx[np.isin(flat[idx], planes)]
    points, sigma = rows_at(ctx.xyz, taken), ctx.sigma[taken]
    sigmas = np.stack([np.abs(fits[k].distances(points)) /
                       np.maximum(distance_noise(fits[k], points, sigma), 1e-12) for k in planes])
    nearest = np.argmin(sigmas, axis=0)
    own = np.searchsorted(planes, flat[taken])  # each pixel's own plane's row (labels increase)
    keep = sigmas[nearest, np.arange(taken.size)] > TRIM_SIGMAS  # off every plane's noise: stays
    to = np.asarray(planes)[np.where(keep, own, nearest)]
    settled = {}
    for k in planes:
        piece = ctx.largest_piece(taken[to == k])
        if piece.size < ctx.min_size:
            return
        refit = ctx.fitter.refit(ctx.fitter.points(ctx.xyz, piece), fits[k])
        if not refit or refit.kind != "plane":
            return
        settled[k] = piece, refit
    flat[taken] = 0
    for k, (piece, refit) in settled.items():
        flat[piece] = k
        fits[k] = refit


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
    points = rows_at(ctx.xyz, idx)
    rays = points / np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-12)
    noise = np.maximum(ctx.sigma[idx] * np.maximum(np.abs(rays @ plane.normal), GRAZING_COSINE), floor)
    return np.abs(plane.distances(points)), noise


def _beyond(distances: np.ndarray, noise: np.ndarray) -> bool:
    # the distances' rms beyond the noise's (chi-square bound, fitting.robust.beyond_noise)
    return beyond_noise(float(np.sqrt(np.mean(distances ** 2))), float(np.sqrt(np.mean(noise ** 2))),
                        int(distances.size))

