"""Planes fitted along the viewing rays, in inverse range, and the helpers built on them.

A range error moves a return along its ray only: the plane ``a . p = 1`` (``a = n / d``)
meets the unit ray ``u`` at inverse range ``a . u``, linear in ``a``, and the noise of an
inverse range is ``sigma / range**2``. So the plane of a face is the weighted least squares
``a`` of its pixels' inverse ranges (:func:`ray_terms`, :func:`ray_moments`, :func:`ray_fits`),
whatever the face's incidence: a face seen near grazing, whose depth the range noise spans,
is fitted as well as one seen head-on, where a least-squares plane in ``xyz`` turns towards
the rays. :func:`robust_ray_plane` fits a strip that holds a few pixels of other surfaces at
its ends; :func:`ray_plane` reports ``a`` as a :class:`~rangeseg_o3d.fitting.primitives.Plane`;
:func:`seen_near_grazing` tells whether a plane is seen near grazing from pixels.

The steps for faces seen near grazing share these (:mod:`rangeseg_o3d.plane_faces`,
:mod:`rangeseg_o3d.strips`, :mod:`rangeseg_o3d.free_faces`, :mod:`rangeseg_o3d.off_model`).
"""

from __future__ import annotations

import numpy as np

from .fitting.primitives import Plane
from .refinement.context import TRIM_SIGMAS
from .scales import GRAZING_COSINE

__all__ = ["ROBUST_CHUNKS", "TRIM_PASSES", "moment_columns", "pixel_moments", "ray_fits", "ray_moments", "ray_plane", "ray_solutions", "ray_terms",
           "robust_ray_plane", "seen_near_grazing", "split_columns"]

#: Passes of :func:`robust_ray_plane`'s trimmed fit (each refits to the pixels the last
#: one kept within TRIM_SIGMAS).
TRIM_PASSES = 3
#: Equal-count pieces along a strip of which :func:`robust_ray_plane` leaves out up to two.
ROBUST_CHUNKS = 8
#: The pairs of chunks :func:`robust_ray_plane` leaves out together, in row-major order (once:
#: np.triu_indices cost more than the rest of a small strip's fit).
_CHUNK_PAIRS = np.triu_indices(ROBUST_CHUNKS, 1)
#: Relative distance from a threshold within which a compiled decision is left to numpy's
#: (:func:`robust_ray_plane`, :func:`rangeseg_o3d.off_model._ruled_out`). The two round
#: differently (their own 3x3 solves and sums), by about the sums' condition number times
#: 1e-16 on the planes, far less on the residuals at the pixels' own rays.
SCREEN_TOLERANCE = 1e-5


def ray_terms(points: np.ndarray, sigma: np.ndarray):
    """Per point ``(rays, inverse, weight)``: its unit ray, its inverse range and the weight
    of that inverse's noise (``range**4 / sigma**2``). A plane ``n . p = d`` meets the ray
    ``u`` at inverse range ``(n / d) . u``: linear in ``a = n / d``, and a range error moves
    only the inverse range, by ``sigma / range**2`` (a stereo camera's disparity noise, the
    same everywhere), so the plane of a face is the weighted least squares ``a`` of the
    inverse ranges, whatever the face's incidence (:func:`ray_plane`).

    Float64 ``(N, 3)`` points with ``N`` sigmas go through one compiled pass
    (:func:`rangeseg_o3d.kernels.ray_terms_of`, the same bits); anything else through numpy."""
    points = np.asarray(points)
    if (points.dtype == np.float64 and points.ndim == 2 and points.shape[1] == 3 and type(sigma) is np.ndarray
            and sigma.dtype == np.float64 and sigma.shape == (points.shape[0],)):
        from .kernels import ray_terms_of

        return ray_terms_of(np.ascontiguousarray(points), np.ascontiguousarray(sigma))
    return _ray_terms_numpy(points, sigma)


def _ray_terms_numpy(points: np.ndarray, sigma) -> tuple:
    """:func:`ray_terms` in numpy: the form its compiled pass reproduces, and the one for
    other dtypes and shapes."""
    ranges = np.maximum(np.linalg.norm(points, axis=1), 1e-12)
    noise = np.maximum(sigma, 1e-12) / ranges ** 2
    return points / ranges[:, None], 1.0 / ranges, 1.0 / noise ** 2


def ray_fits(moments: tuple) -> tuple[np.ndarray, np.ndarray]:
    """``(chi2, a)`` of the weighted least squares of inverse ranges from stacked sums
    ``moments = (sum w u u^T, sum w q u, sum w q^2)``: the planes ``a . p = 1`` and their
    sums of squared inverse-range residuals in units of their noise."""
    outer, first, second = moments
    a = ray_solutions(outer, first)
    return second - np.einsum("ki,ki->k", first, a), a


def ray_solutions(outer: np.ndarray, first: np.ndarray) -> np.ndarray:
    """The planes ``a`` of :func:`ray_fits` alone (stacked sums ``sum w u u^T``, ``sum w q u``),
    for callers that do not read the chi-square."""
    # a ridge of 1e-12 of the trace: the rays of one column of pixels span a plane only
    ridge = 1e-12 * np.trace(outer, axis1=-2, axis2=-1)[..., None, None] * np.eye(3)
    return np.linalg.solve(outer + ridge, first[..., None])[..., 0]


def ray_moments(rays: np.ndarray, inverse: np.ndarray, weight: np.ndarray):
    """The sums :func:`ray_fits` takes, over all points (stacked, one set)."""
    from .kernels.rays import ray_moment_sums

    # compiled: numpy's terms and sums bit for bit, without the (N, 3, 3) products
    outer, first, second = ray_moment_sums(np.ascontiguousarray(rays, dtype=np.float64),
                                           np.ascontiguousarray(inverse, dtype=np.float64),
                                           np.ascontiguousarray(weight, dtype=np.float64))
    return outer[None], first[None], np.array([second])


def pixel_moments(xyz: np.ndarray, sigma: np.ndarray, pixels: np.ndarray):
    """``ray_moments(*ray_terms(xyz[pixels], sigma[pixels]))``: the sums :func:`ray_fits` takes
    over the flat ``pixels`` of the points ``xyz`` (N, 3) and their range noise ``sigma`` (N,),
    the same bits in one compiled pass (:func:`rangeseg_o3d.kernels.pixel_ray_moments`)."""
    from .kernels.rays import pixel_ray_moments

    outer, first, second = pixel_ray_moments(np.ascontiguousarray(xyz, dtype=np.float64),
                                             np.ascontiguousarray(sigma, dtype=np.float64),
                                             np.ascontiguousarray(pixels, dtype=np.int64))
    return outer[None], first[None], np.array([second])


def moment_columns(rays: np.ndarray, inverse: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Each point's terms of the sums :func:`ray_fits` takes, as 13 columns (the 9 of
    ``w u u^T``, the 3 of ``w q u``, ``w q^2``): sums of rows are sums of terms."""
    outer = (weight[:, None, None] * rays[:, :, None] * rays[:, None, :]).reshape(-1, 9)
    first = (weight * inverse)[:, None] * rays
    return np.concatenate([outer, first, (weight * inverse * inverse)[:, None]], axis=1)


def split_columns(columns: np.ndarray) -> tuple:
    """The stacked sums of :func:`ray_fits` from rows of :func:`moment_columns` sums."""
    return columns[:, :9].reshape(-1, 3, 3), columns[:, 9:12], columns[:, 12]


def ray_plane(a: np.ndarray, points: np.ndarray):
    """The :class:`Plane` ``a . p = 1`` with the rms of the orthogonal distances of ``points``
    (None when ``a`` is no plane)."""
    norm = float(np.linalg.norm(a))
    if not np.isfinite(norm) or norm <= 0:
        return None
    normal, d = a / norm, 1.0 / norm
    distances = points @ normal - d
    return Plane(normal=normal, d=d, rms=float(np.sqrt(np.mean(distances ** 2))), inliers=int(len(points)))


def robust_ray_plane(rays: np.ndarray, inverse: np.ndarray, weight: np.ndarray, rows: np.ndarray,
                      cols: np.ndarray):
    """``(a, keep, mean square)``: the plane ``a . p = 1`` of a strip's pixels fitted along
    their rays (:func:`ray_terms`; their grid ``rows``, ``cols``), the pixels within TRIM_SIGMAS
    of it and their mean squared residual in noise units; None when no plane is.

    A strip left over beside a face holds a few pixels of the surfaces at its ends (the side
    of a box beside its top), far off the face's plane: one least-squares fit over all of
    them turns the plane, and trimming from it keeps the wrong pixels. The strip is cut
    into ROBUST_CHUNKS equal-count pieces along its longer axis on the grid; the plane of
    every set leaving out up to two of them is tried, and the one of least truncated
    chi-square over every pixel is refitted to the pixels within TRIM_SIGMAS of it,
    TRIM_PASSES times.

    The 37 trial planes and the trims are decided in one compiled call
    (:func:`rangeseg_o3d.kernels.robust_ray_sets`; numpy's ~40 calls on a strip of a hundred
    pixels cost ~0.1 ms) and the plane it ends with is solved here from numpy's sums, as numpy
    solves it: the same answer as numpy's fit (:func:`_robust_ray_plane_numpy`), which decides
    the strips where a decision lies within SCREEN_TOLERANCE of going the other way."""
    from .kernels import robust_ray_sets

    n = inverse.size
    if n < 3 * ROBUST_CHUNKS:
        return None
    along = cols if cols.max() - cols.min() >= rows.max() - rows.min() else rows
    status, keep, sums = robust_ray_sets(np.ascontiguousarray(rays, dtype=np.float64),
                                         np.ascontiguousarray(inverse, dtype=np.float64),
                                         np.ascontiguousarray(weight, dtype=np.float64),
                                         np.ascontiguousarray(along, dtype=np.int64), ROBUST_CHUNKS, TRIM_PASSES,
                                         float(TRIM_SIGMAS), SCREEN_TOLERANCE)
    if status == 1:
        return None
    if status == 0:
        # numpy's last solve and trim, on the sums numpy adds (the same bits); the kernel's
        # kept set must be what that trim keeps (a check: its decisions were clear of the bound)
        a = ray_solutions(*split_columns(sums[None])[:2])
        residual = weight * (inverse - rays @ a[0]) ** 2
        now = residual <= TRIM_SIGMAS * TRIM_SIGMAS
        if np.array_equal(now, keep) or not now.any():
            return a[0], keep, float(np.mean(residual[keep]))
    return _robust_ray_plane_numpy(rays, inverse, weight, along)


def _robust_ray_plane_numpy(rays: np.ndarray, inverse: np.ndarray, weight: np.ndarray, along: np.ndarray):
    """:func:`robust_ray_plane` in numpy (the strip's pixels in chunks by ``along``, its
    longer grid axis): the reference its compiled decisions reproduce, and the fit of the
    strips whose decisions lie too near their thresholds for them."""
    n = inverse.size
    order = np.argsort(along, kind="stable")
    chunk = np.empty(n, np.int64)
    chunk[order] = np.arange(n) * ROBUST_CHUNKS // n
    columns = moment_columns(rays, inverse, weight)
    sums = np.zeros((ROBUST_CHUNKS, columns.shape[1]))
    np.add.at(sums, chunk, columns)
    total = sums.sum(axis=0)
    # every set of chunks leaving out none, one or two of them (pairs in row-major order),
    # solved at once
    one, other = _CHUNK_PAIRS
    stacked = np.concatenate([total[None], total - sums, total - (sums[one] + sums[other])])
    planes = ray_solutions(*split_columns(stacked)[:2])
    squares = weight[None, :] * (inverse[None, :] - planes @ rays.T) ** 2
    within = squares <= TRIM_SIGMAS * TRIM_SIGMAS
    # the least truncated chi-square (a pixel off by more than TRIM_SIGMAS counts as that):
    # counting the pixels within alone favours a plane turned towards the rays, within whose
    # noise band the range noise puts most pixels, the strip's ends too
    pick = int(np.argmin(np.minimum(squares, TRIM_SIGMAS * TRIM_SIGMAS).sum(axis=1)))
    keep = within[pick]
    if not keep.any():
        return None
    for _ in range(TRIM_PASSES):
        a = ray_solutions(*split_columns(columns[keep].sum(axis=0)[None])[:2])
        residual = weight * (inverse - rays @ a[0]) ** 2
        now = residual <= TRIM_SIGMAS * TRIM_SIGMAS
        if np.array_equal(now, keep) or not now.any():
            break
        keep = now
    return a[0], keep, float(np.mean(residual[keep]))


def seen_near_grazing(a: np.ndarray, points: np.ndarray) -> bool:
    """Whether the plane ``a . p = 1`` is seen near grazing from ``points`` (N, 3): the median
    of ``|cos|`` between their rays from the origin and its normal under
    ``scales.GRAZING_COSINE``."""
    rays = points / np.maximum(np.linalg.norm(points, axis=1), 1e-12)[:, None]
    return float(np.median(np.abs(rays @ (a / max(float(np.linalg.norm(a)), 1e-300))))) < GRAZING_COSINE
