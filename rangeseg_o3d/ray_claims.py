"""Pixels a plane region took within the noise of their distances, given back along the rays.

A region takes a pixel of its tile or of the 8 around it within ``k_sigma`` of its noise in
distance to its plane (:func:`rangeseg_o3d.fullres.label_pixels`). On a stereo camera that
noise is along the rays, and a floor seen near grazing takes the bottom of a far box face
standing on it out to the face's tiles: those pixels lie within the floor's distance noise
(a 3-sigma band 24 cm high at 5 m) but many range sigmas from it along their rays, and the
face's plane, which no tile of theirs offered, meets them within their noise (stereo seed 23
scan 2: 489 px of a 2383-px face, 5.5 against 0.7 sigmas along the rays, medians).
:func:`claim_outliers_along_rays` gives such pixels to the plane beside them that explains
them, unless what the region keeps is curved (:func:`curved_along_rays`): then its plane was
no judge of which of its pixels lie beyond the noise.
"""

from __future__ import annotations

import numpy as np

from ._numeric import unique_ints
from . import kernels  # the package: its names load on first use (no compiler at import)
from .fitting.primitives import Plane
from .fitting.region_fitter import model_table, region_indices
from .fitting.robust import curvature_resolved
from .kernels.linalg import CHI_SQUARE_SIGMAS
from .fullres import stats_with_moved
from .ray_planes import ray_terms
from .refinement.context import TRIM_SIGMAS

__all__ = ["CURVE_TEST_PIXELS", "OUTLIER_ROUNDS", "claim_outliers_along_rays", "curved_along_rays"]

#: Rounds of :func:`claim_outliers_along_rays` at most: each passes the pixels one 4-step
#: further from the regions that claim them (a band of a face a floor took: 40 rows of a
#: stereo frame on the studied seeds).
OUTLIER_ROUNDS = 256
#: Pixels of a region (an even subsample) on which :func:`curved_along_rays` fits its plane
#: and its quadric along the rays.
CURVE_TEST_PIXELS = 4096
#: Parameters a quadric along the rays has beyond a plane's (the three second-order terms).
QUADRIC_EXTRA = 3
#: The compiled screen of :func:`_left_curved` (:func:`rangeseg_o3d.kernels.curve_screen`)
#: answers only where a sample pixel's nearness and the F-test are beyond this share of the
#: quantities compared (its rounding differs from numpy's); numpy's form answers the rest.
SCREEN_MARGIN = 1e-6


def claim_outliers_along_rays(cloud, labels: np.ndarray, fits: dict, stats, *, sigma: np.ndarray,
                              inlier_factor: float, correlation_px: int = 1):
    """The pixels of a plane region its plane leaves beyond TRIM_SIGMAS of their range
    noise along their rays, each given to the plane region of a 4-neighbour whose plane
    meets its ray within TRIM_SIGMAS and nearest, round by round from the borders between
    plane regions (a pixel given passes the claim on; at most OUTLIER_ROUNDS rounds,
    :func:`rangeseg_o3d.kernels.claims.outlier_claims`). A region whose kept pixels are then
    curved along the rays (:func:`curved_along_rays`, ``correlation_px`` the side of the
    sensor's matching window) gives none: its plane is not its surface (a pipe's chord at the
    image border, fitted as a plane with a strip of the wall beside it), and the pixels it
    leaves beyond the noise say nothing of another surface.
    Returns ``(labels, stats)``, the statistics moved with the pixels; the inputs when no
    pixel moves. The models do not change.

    Along the rays both planes are judged by one noise, the range's: a plane ``a . p = 1``
    meets the ray of a pixel ``p`` at range ``r`` that far from it, ``r |1 - a . p|``."""
    if labels.ndim != 2 or sigma.shape != labels.shape or cloud.xyz.shape[:2] != labels.shape:
        raise ValueError(f"labels, sigma and the cloud's grid must share one (H, W) shape; got labels "
                         f"{labels.shape}, sigma {sigma.shape}, cloud {cloud.xyz.shape[:2]}")
    n = max(int(labels.max(initial=0)), max(fits, default=0)) + 1
    inverse_planes, is_plane = np.zeros((n, 3)), np.zeros(n, bool)
    for k, m in fits.items():
        if isinstance(m, Plane) and 0 < k < n and m.d != 0:
            inverse_planes[k], is_plane[k] = np.asarray(m.normal) / m.d, True  # the plane a . p = 1
    if np.count_nonzero(is_plane) < 2:
        return labels, stats
    before = np.ascontiguousarray(labels, dtype=np.int32)
    xyz = np.ascontiguousarray(cloud.xyz.reshape(-1, 3), dtype=np.float64)
    noise = np.ascontiguousarray(sigma.reshape(-1), dtype=np.float64)
    out = kernels.outlier_claims(before, xyz, noise, inverse_planes, is_plane, float(TRIM_SIGMAS), OUTLIER_ROUNDS)
    flat = before.reshape(-1)
    changed = np.flatnonzero(out != flat)
    if not changed.size:
        return labels, stats
    givers = unique_ints(flat[changed]).tolist()
    curved = [k for k, idx in region_indices(out.reshape(labels.shape), only=givers).items()
              if _left_curved(xyz, noise, idx, inverse_planes[k], correlation_px)]
    if curved:  # those regions keep what they had
        back = changed[np.isin(flat[changed], curved)]
        out[back] = flat[back]
        changed = np.flatnonzero(out != flat)
        if not changed.size:
            return labels, stats
    table = model_table(fits, n)
    return (out.reshape(labels.shape),
            stats_with_moved(stats, xyz, noise, before, out.reshape(labels.shape), table, changed, inlier_factor))


def _left_curved(xyz: np.ndarray, noise: np.ndarray, kept: np.ndarray, own: np.ndarray,
                 correlation_px: int) -> bool:
    # whether a region's kept pixels (flat indices ``kept``, its plane ``own``: a . p = 1) are
    # curved along the rays, judged on an even sample of them within twice TRIM_SIGMAS of its
    # plane: a return beyond, which no plane beside took, is no more the region's than any
    # other's, and one would outweigh hundreds (the wide bound keeps a chord's bent rim)
    # the compiled screen answers wherever its rounding cannot change the answer (~0.1 ms
    # against numpy's ~1.3 ms a region, 4-5 a stereo scan)
    answer = kernels.curve_screen(xyz, noise, kept, np.ascontiguousarray(own, dtype=np.float64),
                                  CURVE_TEST_PIXELS, 2.0 * TRIM_SIGMAS, int(correlation_px), QUADRIC_EXTRA, CHI_SQUARE_SIGMAS,
                                  SCREEN_MARGIN)[0]
    if answer >= 0:
        return bool(answer)
    return _left_curved_numpy(xyz, noise, kept, own, correlation_px)


def _left_curved_numpy(xyz: np.ndarray, noise: np.ndarray, kept: np.ndarray, own: np.ndarray,
                       correlation_px: int) -> bool:
    # _left_curved in numpy (the answer wherever the compiled screen's rounding could change it)
    sample = kept[:: max(1, kept.size // CURVE_TEST_PIXELS)]
    points, sigma = xyz[sample], noise[sample]
    with np.errstate(invalid="ignore"):  # (a pixel without a return is left out)
        near = np.linalg.norm(points, axis=1) * np.abs(1.0 - points @ own) <= 2.0 * TRIM_SIGMAS * sigma
    pixels = kept.size * np.count_nonzero(near) / max(sample.size, 1)
    return curved_along_rays(points[near], sigma[near], correlation_px, pixels=pixels)


def curved_along_rays(points: np.ndarray, sigma: np.ndarray, correlation_px: int = 1,
                      pixels: float | None = None) -> bool:
    """Whether a quadric along the rays explains the inverse ranges of ``points`` (N, 3)
    better than a plane by more than their noise would (an F-test,
    :func:`rangeseg_o3d.fitting.robust.curvature_resolved`, with QUADRIC_EXTRA parameters
    more), counted in independent returns: returns that err together over a
    ``correlation_px`` square window count once per window, and an even subsample of at most
    CURVE_TEST_PIXELS points, spread over the region, counts each point once. ``pixels``:
    the pixels ``points`` are an even sample of (``len(points)`` unless given).

    A plane ``a . p = 1`` meets the ray ``u`` at inverse range ``a . u``, which over the image
    coordinates ``x = u_x / u_z``, ``y = u_y / u_z`` is ``u_z (a_z + a_x x + a_y y)``: the
    quadric adds ``u_z`` times the three second-order terms of ``x`` and ``y``, both fitted by
    weighted least squares in range sigmas (:func:`rangeseg_o3d.ray_planes.ray_terms`).
    Points without a finite return are left out; fewer than the quadric's parameters and
    one more: False."""
    points = np.asarray(points, dtype=np.float64)
    sigma = np.asarray(sigma, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or sigma.shape != points.shape[:1]:
        raise ValueError(f"points must be (N, 3) with sigma (N,); got {points.shape} and {sigma.shape}")
    if not (isinstance(correlation_px, (int, np.integer)) and correlation_px >= 1):
        raise ValueError(f"correlation_px must be an integer >= 1; got {correlation_px!r}")
    total = float(points.shape[0] if pixels is None else pixels)
    if total < points.shape[0]:
        raise ValueError(f"pixels must be at least the points' count {points.shape[0]}; got {pixels!r}")
    step = max(1, points.shape[0] // CURVE_TEST_PIXELS)
    points, sigma = points[::step], sigma[::step]
    finite = np.isfinite(points).all(axis=1) & np.isfinite(sigma) & (sigma > 0)
    points, sigma = points[finite], sigma[finite]
    m = points.shape[0]
    if m < 4 + QUADRIC_EXTRA:
        return False
    rays, inverse, weight = ray_terms(points, sigma)
    if not (rays[:, 2] > 0).all():
        return False  # (rays at or beyond 90 degrees off the axis: no image coordinates)
    root = np.sqrt(weight)
    x, y = rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2]
    x, y = x - x.mean(), y - y.mean()
    scale = max(float(x.std()), float(y.std()), 1e-12)  # (a well-conditioned design)
    x, y = x / scale, y / scale
    column = root * rays[:, 2]
    design = column[:, None] * np.column_stack([np.ones(m), x, y, x * x, x * y, y * y])
    target = root * inverse
    plane_squares = _least_squares_rest(design[:, :3], target)
    curved_squares = _least_squares_rest(design, target)
    # the sums over the sample count its independent returns: at most one a window
    independent = min(float(m), total * m / max(finite.size, 1) / float(correlation_px) ** 2)
    share = independent / m
    return curvature_resolved(plane_squares * share, curved_squares * share, int(independent), QUADRIC_EXTRA)


def _least_squares_rest(design: np.ndarray, target: np.ndarray) -> float:
    # the sum of squared residuals of the least-squares fit of target by design's columns,
    # by the normal equations (a few columns, centred and scaled: well conditioned)
    solution, *_ = np.linalg.lstsq(design.T @ design, design.T @ target, rcond=None)
    rest = target - design @ solution
    return float(rest @ rest)
