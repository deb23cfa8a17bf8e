"""Edge mask from the residual image: jump edges, grey-level closing, threshold."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["jump_edges", "close_residual", "edge_mask"]

# Finite stand-in for "no plane could be fitted here" so morphology and display work.
EDGE_CEILING = 1e6


def jump_edges(ranges: np.ndarray, *, jump_ratio: float = 0.08, jump_min: float = 0.05) -> np.ndarray:
    """Pixels on either side of a depth discontinuity.

    A pixel is a jump edge when the range difference to one of its 4-neighbours exceeds
    ``max(jump_min, jump_ratio * r)`` with ``r`` the nearer of the two ranges. The relative
    term follows the spacing of the scan, which grows linearly with range for a sensor with
    fixed angular steps, so the test behaves the same near and far; the absolute floor keeps
    range noise from triggering it at short range. It catches the jumps the plane residual
    misses, e.g. between two parallel surfaces seen almost edge-on.

    Parameters
    ----------
    ranges : (H, W) ranges in metres, NaN where invalid.
    jump_ratio : relative jump threshold.
    jump_min : absolute jump threshold in metres.

    Returns
    -------
    (H, W) bool mask.
    """
    r = np.asarray(ranges, dtype=np.float64)
    if r.ndim != 2:
        raise ValueError(f"ranges must have shape (H, W); got {r.shape}")
    mask = np.zeros(r.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        for axis in (0, 1):
            a = r[:-1, :] if axis == 0 else r[:, :-1]
            b = r[1:, :] if axis == 0 else r[:, 1:]
            jump = np.abs(a - b) > np.maximum(jump_min, jump_ratio * np.fmin(a, b))
            if axis == 0:
                mask[:-1, :] |= jump
                mask[1:, :] |= jump
            else:
                mask[:, :-1] |= jump
                mask[:, 1:] |= jump
    return mask


def close_residual(residual: np.ndarray, *, iterations: int = 2, kernel: int = 3) -> np.ndarray:
    """Grey-level closing (dilate, then erode) of the residual image, ``iterations`` times.

    Closing fills the gaps along an edge line so that region borders do not leak
    (paper, Sec. 3.2: closing twice). Infinite residuals are clipped to a large finite value.
    """
    res = np.asarray(residual, dtype=np.float64)
    if res.ndim != 2:
        raise ValueError(f"residual must have shape (H, W); got {res.shape}")
    if iterations < 0:
        raise ValueError(f"iterations must be >= 0; got {iterations}")
    img = np.minimum(np.nan_to_num(res, nan=EDGE_CEILING, posinf=EDGE_CEILING), EDGE_CEILING)
    img = img.astype(np.float32)
    if iterations == 0:
        return img
    element = cv2.getStructuringElement(cv2.MORPH_RECT, (kernel, kernel))
    return cv2.morphologyEx(
        img, cv2.MORPH_CLOSE, element, iterations=iterations, borderType=cv2.BORDER_REPLICATE
    )


def edge_mask(closed: np.ndarray, *, threshold: float, valid: np.ndarray | None = None,
              jumps: np.ndarray | None = None) -> np.ndarray:
    """Binary edge image: closed residual above ``threshold``, jump edges, and invalid pixels."""
    if not threshold > 0:
        raise ValueError(f"threshold must be positive; got {threshold}")
    edges = np.asarray(closed) > threshold
    if jumps is not None:
        edges |= jumps
    if valid is not None:
        edges |= ~valid
    return edges
