"""Edge mask from the residual image: jump edges, grey-level closing, threshold."""

from __future__ import annotations

import numpy as np

__all__ = ["jump_edges", "close_residual", "edge_mask"]

# Finite stand-in for "no plane could be fitted here" so morphology and display work.
EDGE_CEILING = 1e6


def jump_edges(ranges: np.ndarray, *, jump_ratio: float = 0.08, jump_min: float = 0.05) -> np.ndarray:
    """Occluded side of every depth discontinuity.

    Between 4-neighbours whose ranges differ by more than ``max(jump_min, jump_ratio * r)``
    (``r`` the nearer range) the *farther* pixel is marked: the nearer one is a genuine
    point of the occluding surface, and a thin object only a few pixels wide would lose
    most of itself if both sides were marked (PCL calls these occluded vs occluding edges).
    A mixed pixel between foreground and background is farther than the foreground, so it
    is marked too. The relative term follows the scan spacing, which grows linearly with
    range for a sensor with fixed angular steps, so the test behaves the same near and far;
    the absolute floor keeps range noise from triggering it at short range. It catches the
    jumps the plane residual misses, e.g. between parallel surfaces seen almost edge-on.

    Parameters
    ----------
    ranges : (H, W) ranges in metres, NaN where invalid.
    jump_ratio : relative jump threshold.
    jump_min : absolute jump threshold in metres.

    Returns
    -------
    (H, W) bool mask.
    """
    from .kernels import jump_mask

    r = np.asarray(ranges, dtype=np.float64)
    if r.ndim != 2:
        raise ValueError(f"ranges must have shape (H, W); got {r.shape}")
    # one compiled pass: the same test as a dozen whole-image numpy operations, at a tenth
    return jump_mask(np.ascontiguousarray(r), float(jump_ratio), float(jump_min))


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
    import cv2  # here, not at module level: importing the stage stays light

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
