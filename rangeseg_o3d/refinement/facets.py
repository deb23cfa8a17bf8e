"""Step 4, ``facets``: a curved model that fits worse than the sensor's noise is tested
against planes, then against the fitter's own split.

A cylinder bent over the crease of two block faces (or a sphere over a corner of three)
fits their pixels within the fitter's tolerance, but its residuals are far larger than
the noise: the faces are flat and the model is wrong. The noise model tells when: the
mean squared residual of ``n`` pixels of a right model is ``sigma^2`` within a few
standard deviations ``sigma^2 sqrt(2 / n)`` of the chi-square law. Only such regions
are split into planes (the split's sequential trimmed extraction with a planes-only
judge), and the planes replace the curved model when they explain the region at least
as closely as it did and at the noise (facets of a truly curved surface, a tunnel, do
not): on a sensor whose curved surfaces fit at their noise (a laser's pipes and balls)
nothing runs. When planes do not do it, the same split with the pipeline's fitter as the
judge (any kind, each within the curved model's rms) is held to the same rules: a pipe
whose region took its end cap (or a box face beside it) comes back as its cylinder and
the plane.
"""

from __future__ import annotations

import copy

import numpy as np

from ..fitting.plane import fit_plane
from ..fitting.primitives import Plane
from ..fitting.region_fitter import region_indices
from ..fitting.robust import beyond_noise, curvature_resolved, trimmed_plane
from .context import Context, without

__all__ = ["planes_for_curved"]

#: Share of the region's pixels the planes must take (the crease band between them is left).
PLANES_COVER = 0.9
#: Parameters of each curved kind (a plane has 3): what the curvature test weighs.
CURVED_PARAMETERS = {"cylinder": 5, "sphere": 4}
#: Searches per region (bounds the time; a crease region holds two or three faces).
_MAX_ATTEMPTS = 6


class _PlaneJudge:
    """A planes-only stand-in for the pipeline's fitter (what :class:`Context` calls),
    refusing a plane whose rms exceeds ``max_rms``."""

    def __init__(self, fitter, max_rms: float):
        self.fitter = fitter
        self.max_rms = max_rms

    def fit(self, points: np.ndarray):
        plane = fit_plane(points)
        return plane if plane and plane.rms <= self.max_rms else None

    def refit(self, points: np.ndarray, model):
        return self.fit(points)

    def points(self, xyz_flat: np.ndarray, idx: np.ndarray) -> np.ndarray:
        return self.fitter.points(xyz_flat, idx)

    def trimmed(self, xyz_flat: np.ndarray, pool: np.ndarray, *, sigma: float, min_points: int,
                starts: bool = False):
        # trimmed_fit with this judge in one compiled call (what Context.dominant_piece asks)
        return trimmed_plane(xyz_flat, pool, sigma=sigma, min_points=min_points, max_rms=self.max_rms,
                             starts=starts)


class _BoundJudge(_PlaneJudge):
    """The pipeline's fitter (any kind), refusing a model whose rms exceeds ``max_rms``."""

    def fit(self, points: np.ndarray):
        model = self.fitter.fit(points)
        return model if model and model.rms <= self.max_rms else None

    def refit(self, points: np.ndarray, model):
        refit = self.fitter.refit(points, model)
        return refit if refit and refit.rms <= self.max_rms else None

    def trimmed(self, xyz_flat: np.ndarray, pool: np.ndarray, *, sigma: float, min_points: int,
                starts: bool = False):
        # the fitter's compiled trimmed fit with this judge's bound (None: it has none)
        return self.fitter.trimmed(xyz_flat, pool, sigma=sigma, min_points=min_points, max_rms=self.max_rms,
                                   starts=starts)


def _surfaces_of(ctx: Context, idx: np.ndarray, judge) -> list[tuple[np.ndarray, object]]:
    """The surfaces a sequential trimmed split with ``judge`` finds in the pixels ``idx``,
    with their pixels."""
    planar = copy.copy(ctx)  # the same points, noise and size floor
    planar.fitter = judge
    found, pools = [], planar.pieces(idx)
    for _ in range(_MAX_ATTEMPTS):
        if not pools:
            break
        pool = pools.pop()
        piece, plane = planar.dominant_piece(pool)
        if piece is None:
            continue
        found.append((piece, plane))
        pools.extend(planar.pieces(without(pool, piece)))
        pools.sort(key=len)
    return found


def planes_for_curved(ctx: Context, labels: np.ndarray, fits: dict):
    """Replace each curved model that fits worse than the noise by the planes (failing them,
    the surfaces of any kind) that explain its region (returns new ``(labels, fits)``).

    The planes (surfaces) must take ``PLANES_COVER`` of the region's pixels with a pooled rms no
    larger than the curved model's on the same pixels and within the noise's chi-square
    bound; the first keeps the label, the others take new labels, the pixels none takes
    are freed.
    """
    curved = [k for k, m in fits.items() if m and not isinstance(m, Plane)]
    if not curved:
        return labels, fits
    wanted = set(curved)
    regions = {k: idx for k, idx in region_indices(labels).items() if k in wanted}
    labels, fits = labels.copy(), dict(fits)
    flat = labels.ravel()
    next_label = int(labels.max(initial=0)) + 1
    for k, idx in regions.items():
        model = fits[k]
        sigma = float(np.median(ctx.sigma[idx]))
        distances = model.distances(ctx.xyz[idx])
        rms = float(np.sqrt(np.mean(distances * distances)))
        if not beyond_noise(rms, sigma, idx.size):
            continue
        for judge in (_PlaneJudge(ctx.fitter, rms), _BoundJudge(ctx.fitter, rms)):
            surfaces = _surfaces_of(ctx, idx, judge)
            if _explains(ctx, model, idx, surfaces, sigma):
                break
        else:
            continue
        flat[idx] = 0
        for i, (piece, surface) in enumerate(surfaces):
            label = k if i == 0 else next_label
            next_label += i > 0
            flat[piece] = label
            fits[label] = surface
    return labels, fits


def _explains(ctx: Context, model, idx: np.ndarray, surfaces: list, sigma: float) -> bool:
    # The surfaces take PLANES_COVER of the pixels. One plane (two parameters fewer than the
    # curved model) replaces it when the curved model does not resolve a curvature over the
    # pixels the plane takes (the F-test of curvature_resolved, on the model's own residuals:
    # mixed pixels or an oblique view do not enter). Several surfaces must be no farther from
    # the pixels than ``model`` and at the noise (facets of a truly curved surface do not
    # fit at the noise).
    taken = sum(piece.size for piece, _ in surfaces)
    if not surfaces or taken < PLANES_COVER * idx.size:
        return False
    squares = sum(float(np.sum(surface.distances(ctx.xyz[piece]) ** 2)) for piece, surface in surfaces)
    covered = np.concatenate([piece for piece, _ in surfaces])
    model_squares = float(np.sum(model.distances(ctx.xyz[covered]) ** 2))
    if len(surfaces) == 1 and isinstance(surfaces[0][1], Plane):
        return not curvature_resolved(squares, model_squares, taken, CURVED_PARAMETERS[model.kind] - 3)
    if squares > model_squares:
        return False
    return not beyond_noise(np.sqrt(squares / taken), sigma, taken)
