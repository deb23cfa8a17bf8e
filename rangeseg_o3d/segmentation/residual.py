"""Residual image: the plane-fit residual of every pixel's neighbourhood, for the whole grid at once.

For pixel (i, j) the valid points of its k x k window are centred and their scatter matrix
``A = sum p' p'^T`` formed; its smallest eigenvalue is the residual sum of squared orthogonal
distances of the best plane (paper-notes, step 1), its eigenvector the plane normal. The
moments, the closed-form smallest eigenvalue of the 3x3 symmetric scatter and the noise
normalisation are one compiled pass over the grid (:mod:`rangeseg_o3d.kernels.window`).
"""

from __future__ import annotations

import numpy as np

from .. import kernels  # the package: its names load on first use (no compiler at import)
from ..sensor import noise_sigma

__all__ = [
    "MIN_VALID",
    "neighbourhood_moments",
    "smallest_eigenpairs",
    "residual_image",
    "noise_sigma",
    "block_means",
]


def _check_grid(xyz, window: int) -> np.ndarray:
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"xyz must have shape (H, W, 3); got {xyz.shape}")
    if window < 3 or window % 2 == 0:
        raise ValueError(f"window must be an odd integer >= 3; got {window}")
    # always read-only (a cloud's points are): numba compiles writable and read-only arrays
    # apart, this gives the kernel one specialisation
    view = xyz.view()
    view.flags.writeable = False
    return view


def _grid_of(values, shape) -> np.ndarray:
    # ``np.ascontiguousarray(np.broadcast_to(values, shape))`` as float64, the same values:
    # an image of that shape or a number without numpy's broadcast machinery (2-4 us a call,
    # twice per residual image; the plausibility check and the segmenter make one each a scan)
    values = np.asarray(values, dtype=np.float64)
    if values.shape == tuple(shape):
        return np.ascontiguousarray(values)
    if values.ndim == 0:
        return np.full(shape, values)
    return np.ascontiguousarray(np.broadcast_to(values, shape))


def _read_only(array: np.ndarray) -> np.ndarray:
    # a read-only view: the kernel then has one specialisation whatever the caller passed
    view = array.view()
    view.flags.writeable = False
    return view


def neighbourhood_moments(xyz: np.ndarray, *, window: int = 3):
    """Count, centroid and centred scatter matrix of the valid points in every window.

    Parameters
    ----------
    xyz : (H, W, 3) float array, NaN where invalid.
    window : odd window size (3 for the paper's 3x3 neighbourhood).

    Returns
    -------
    count : (H, W) float, number of valid points in the window.
    centroid : (3, H, W) mean of those points (NaN where count is 0).
    scatter : (6, H, W) centred scatter ``(axx, ayy, azz, axy, axz, ayz)``.
    """
    from ..kernels import window_moments

    return window_moments(_check_grid(xyz, window), int(window))


def smallest_eigenpairs(scatter: np.ndarray, *, with_vectors: bool = True):
    """Smallest eigenvalue (and unit eigenvector) of packed symmetric 3x3 matrices.

    The smallest root of the characteristic cubic by Newton's method from below
    (:func:`rangeseg_o3d.kernels.smallest_eigenvalues`); the eigenvector is the longest
    cross product of two rows of ``A - lambda I``.

    Parameters
    ----------
    scatter : (6, ...) array packed as ``(axx, ayy, azz, axy, axz, ayz)``.
    with_vectors : also return the eigenvectors.

    Returns
    -------
    eigenvalue : (...) smallest eigenvalue, clipped at 0 (NaN for a NaN matrix).
    normal : (3, ...) its unit eigenvector, arbitrary sign, NaN where undefined
        (only if ``with_vectors``).
    """
    from ..kernels import eigenvectors, smallest_eigenvalues

    scatter = np.asarray(scatter, dtype=np.float64)
    if scatter.ndim < 1 or scatter.shape[0] != 6:
        raise ValueError(f"scatter must have shape (6, ...); got {scatter.shape}")
    shape = scatter.shape[1:]
    packed = np.ascontiguousarray(scatter.reshape(6, -1))
    values = smallest_eigenvalues(packed)
    if not with_vectors:
        return values.reshape(shape)
    return values.reshape(shape), eigenvectors(packed, values).T.reshape((3,) + shape)


# A 3x3 window needs this many valid points for its plane: with fewer, one missing row or
# column leaves a collinear set. The paper's segmenter and the plausibility check use it too.
MIN_VALID = 6


def residual_image(
    xyz: np.ndarray,
    *,
    window: int = 3,
    min_valid: int = MIN_VALID,
    ranges: np.ndarray | None = None,
    sigma0: float = 0.005,
    sigma_quadratic: float = 0.0,
    with_normals: bool = True,
    noise_scale: np.ndarray | float = 1.0,
):
    """Noise-normalised plane-fit residual of every pixel's neighbourhood.

    The raw residual ``R = lambda_min(A)`` grows with the number of valid neighbours and,
    at creases, with the point spacing; inside a plane it is ``sigma^2 (N - 3)`` on average
    for N points with orthogonal noise sigma. Dividing by ``(N - 3) sigma(r)^2`` (``sigma(r)``
    from :func:`noise_sigma`) therefore gives a chi-square-like statistic near 1 on planar
    surfaces at every range and for every count of valid neighbours, so one threshold
    (in units of the noise variance) behaves the same near and far.

    Parameters
    ----------
    xyz : (H, W, 3) points, NaN where invalid.
    window : odd neighbourhood size.
    min_valid : fewer valid points in a window than this gives an infinite residual (an edge).
    ranges : (H, W) ranges for the noise model; the distance from the origin if omitted.
    sigma0, sigma_quadratic : noise model coefficients (metres, 1/metre).
    with_normals : also return the window normals (costs about as much as the residual).
    noise_scale : factor on the range-dependent noise term per pixel, e.g. ``1/sqrt(n)``
        for points that are means of ``n`` samples (see :func:`block_means`). ``sigma0`` is
        not scaled: it stands for what averaging does not remove (depth quantisation
        terraces, calibration ripple).

    Returns
    -------
    residual : (H, W) float; ``inf`` where the window has too few points or the pixel is invalid.
    normals : (H, W, 3) unit plane normals of the windows (NaN where undefined), or None.
    """
    xyz = _check_grid(xyz, window)
    if not 3 < min_valid <= window * window:
        raise ValueError(f"min_valid must be in 4..{window * window}; got {min_valid}")
    if not with_normals:  # one compiled pass, the same values as the steps below
        shape = xyz.shape[:2]
        quadratic = np.asarray(sigma_quadratic * noise_scale, dtype=np.float64)
        if ranges is None:
            # the ranges enter through the quadratic term only: without it, sigma0 + 0 r^2 is
            # sigma0 at any range (and the windows of non-finite points are edges either way)
            ranges = np.linalg.norm(xyz, axis=2) if quadratic.any() else 0.0
        ranges = _grid_of(ranges, shape)
        quadratic = _grid_of(quadratic, shape)
        return kernels.window_residuals(xyz, int(window), int(min_valid), _read_only(ranges),
                                        float(sigma0), _read_only(quadratic)), None
    if ranges is None:
        ranges = np.linalg.norm(xyz, axis=2)
    count, _, scatter = neighbourhood_moments(xyz, window=window)
    eigenvalue, normals = smallest_eigenpairs(scatter)
    normals = np.moveaxis(normals, 0, 2)
    sigma = noise_sigma(np.asarray(ranges, dtype=np.float64), sigma0=sigma0,
                        sigma_quadratic=sigma_quadratic * noise_scale)
    with np.errstate(invalid="ignore", divide="ignore"):
        residual = eigenvalue / (np.maximum(count - 3.0, 1.0) * sigma * sigma)
    valid = ~np.isnan(xyz[..., 2]) & (count >= min_valid) & np.isfinite(residual)
    return np.where(valid, residual, np.inf), normals


def block_means(xyz: np.ndarray, block: int, *, min_fraction: float = 0.5):
    """Mean point of every ``block x block`` tile of the grid (NaN-aware).

    Averaging ``n`` samples divides the range noise by ``sqrt(n)``, which is what lets a
    3x3 window see creases in depth-camera data whose noise at a few metres exceeds the
    pixel spacing. Tiles straddling a depth jump give a point between the two surfaces;
    the jump test flags it like a mixed pixel.

    Returns
    -------
    means : (ceil(H/block), ceil(W/block), 3), NaN where fewer than ``min_fraction`` of the
        tile's pixels are valid.
    counts : the number of valid pixels averaged per tile.
    """
    from ..kernels import block_means as _block_means

    if block < 1:
        raise ValueError(f"block must be >= 1; got {block}")
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"xyz must have shape (H, W, 3); got {xyz.shape}")
    means, counts = _block_means(xyz, int(block), float(min_fraction * block * block))
    return means, counts
