"""Residual image: the plane-fit residual of every pixel's neighbourhood, for the whole grid at once.

For pixel (i, j) the valid points of its k x k window are centred and their scatter matrix
``A = sum p' p'^T`` formed; its smallest eigenvalue is the residual sum of squared orthogonal
distances of the best plane (paper-notes, step 1), its eigenvector the plane normal. The
moments come from box filters over the grid and the eigenvalue from the closed-form solution
of the 3x3 symmetric eigenproblem, so there is no loop over pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "neighbourhood_moments",
    "smallest_eigenpairs",
    "residual_image",
    "noise_sigma",
    "block_means",
]


def _box_sum(plane: np.ndarray, window: int) -> np.ndarray:
    # Unnormalised box filter with zero padding: sums over the window, missing pixels count 0.
    return cv2.boxFilter(
        plane, ddepth=-1, ksize=(window, window), normalize=False, borderType=cv2.BORDER_CONSTANT
    )


_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


@np.errstate(invalid="ignore", divide="ignore")  # empty windows give NaN by design
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
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"xyz must have shape (H, W, 3); got {xyz.shape}")
    if window < 3 or window % 2 == 0:
        raise ValueError(f"window must be an odd integer >= 3; got {window}")
    valid = ~np.isnan(xyz[..., 2])
    # A global reference keeps the sums small, so the centred scatter keeps its precision
    # far from the origin.
    # The reference only has to be near the points, so a sparse sample suffices.
    sample = xyz[::4, ::4][valid[::4, ::4]]
    if sample.size == 0:
        sample = xyz[valid]
    reference = sample.mean(axis=0) if sample.size else np.zeros(3)
    # Contiguous coordinate planes: OpenCV would copy strided ones on every call.
    planes = np.empty((3,) + xyz.shape[:2])
    for k in range(3):
        np.subtract(xyz[..., k], reference[k], out=planes[k])
    planes[:, ~valid] = 0.0
    count = _box_sum(valid.astype(np.float64), window)
    first = np.stack([_box_sum(planes[k], window) for k in range(3)])
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = first / count
    scatter = np.empty((6,) + xyz.shape[:2])
    for k, (a, b) in enumerate(_PAIRS):
        scatter[k] = _box_sum(planes[a] * planes[b], window)
        scatter[k] -= first[a] * mean[b]
    return count, mean + reference[:, None, None], scatter


@np.errstate(invalid="ignore", divide="ignore")  # NaN matrices give NaN results by design
def smallest_eigenpairs(scatter: np.ndarray, *, with_vectors: bool = True):
    """Smallest eigenvalue (and unit eigenvector) of packed symmetric 3x3 matrices.

    Closed form (trigonometric solution of the characteristic cubic), vectorised.

    Parameters
    ----------
    scatter : (6, ...) array packed as ``(axx, ayy, azz, axy, axz, ayz)``.
    with_vectors : also return the eigenvectors.

    Returns
    -------
    eigenvalue : (...) smallest eigenvalue, clipped at 0.
    normal : (3, ...) its unit eigenvector, arbitrary sign, NaN where undefined
        (only if ``with_vectors``).
    """
    a11, a22, a33, a12, a13, a23 = np.asarray(scatter, dtype=np.float64)
    q = (a11 + a22 + a33) / 3.0
    b11, b22, b33 = a11 - q, a22 - q, a33 - q
    p1 = a12 * a12 + a13 * a13 + a23 * a23
    p = np.sqrt((b11 * b11 + b22 * b22 + b33 * b33 + 2.0 * p1) / 6.0)
    det = b11 * (b22 * b33 - a23 * a23) - a12 * (a12 * b33 - a23 * a13) + a13 * (a12 * a23 - b22 * a13)
    with np.errstate(invalid="ignore", divide="ignore"):
        half_det = np.where(p > 0, det / (2.0 * p * p * p), 0.0)
    # float32 trigonometry is ample here: its error is relative to q, far below the noise.
    phi = np.arccos(np.clip(half_det, -1.0, 1.0).astype(np.float32)) / np.float32(3.0)
    cos_k1 = np.cos(phi + np.float32(2.0 * np.pi / 3.0)).astype(np.float64)
    eigenvalue = np.maximum(q + 2.0 * p * cos_k1, 0.0)
    if not with_vectors:
        return eigenvalue
    # Eigenvector: the longest cross product of two rows of (A - lambda I).
    d11, d22, d33 = a11 - eigenvalue, a22 - eigenvalue, a33 - eigenvalue
    c01 = np.stack([a12 * a23 - a13 * d22, a13 * a12 - d11 * a23, d11 * d22 - a12 * a12])
    c02 = np.stack([a12 * d33 - a13 * a23, a13 * a13 - d11 * d33, d11 * a23 - a12 * a13])
    c12 = np.stack([d22 * d33 - a23 * a23, a23 * a13 - a12 * d33, a12 * a23 - d22 * a13])
    n01, n02, n12 = (np.einsum("i...,i...->...", c, c) for c in (c01, c02, c12))
    normal = np.where(n01 >= n02, c01, c02)
    best = np.maximum(n01, n02)
    normal = np.where(n12 > best, c12, normal)
    best = np.maximum(best, n12)
    with np.errstate(invalid="ignore", divide="ignore"):
        normal = normal / np.sqrt(best)
    normal[:, ~(best > 0)] = np.nan
    return eigenvalue, normal


def noise_sigma(ranges: np.ndarray, *, sigma0: float, sigma_quadratic: float = 0.0) -> np.ndarray:
    """Range noise model ``sigma(r) = sigma0 + sigma_quadratic * r**2`` in metres.

    A constant term suits time-of-flight lasers (LMS200: ~5 mm); the quadratic term suits
    triangulating depth cameras (Kinect: ~1.425e-3 z^2, the CAPE model).
    """
    return sigma0 + sigma_quadratic * np.square(ranges)


def residual_image(
    xyz: np.ndarray,
    *,
    window: int = 3,
    min_valid: int = 5,
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
    xyz = np.asarray(xyz, dtype=np.float64)
    count, _, scatter = neighbourhood_moments(xyz, window=window)
    if not 3 < min_valid <= window * window:
        raise ValueError(f"min_valid must be in 4..{window * window}; got {min_valid}")
    if with_normals:
        eigenvalue, normals = smallest_eigenpairs(scatter)
        normals = np.moveaxis(normals, 0, 2)
    else:
        eigenvalue, normals = smallest_eigenpairs(scatter, with_vectors=False), None
    if ranges is None:
        ranges = np.linalg.norm(xyz, axis=2)
    sigma = noise_sigma(np.asarray(ranges, dtype=np.float64), sigma0=sigma0,
                        sigma_quadratic=sigma_quadratic * noise_scale)
    dof = np.maximum(count - 3.0, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        residual = eigenvalue / (dof * sigma * sigma)
    valid = ~np.isnan(xyz[..., 2]) & (count >= min_valid) & np.isfinite(residual)
    residual = np.where(valid, residual, np.inf)
    return residual, normals


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
    from .kernels import block_means as _block_means

    if block < 1:
        raise ValueError(f"block must be >= 1; got {block}")
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"xyz must have shape (H, W, 3); got {xyz.shape}")
    means, counts = _block_means(xyz, int(block), float(min_fraction * block * block))
    return means, counts
