"""Regions: connected components of the non-edge pixels, small ones discarded."""

from __future__ import annotations

import numpy as np

__all__ = ["label_regions", "relabel_sequential"]


def relabel_sequential(labels: np.ndarray) -> np.ndarray:
    """Renumber the positive labels 1..n, keeping their order; 0 (and negatives) become 0."""
    labels = np.asarray(labels)
    present = np.unique(labels[labels > 0])
    lut = np.zeros(int(labels.max(initial=0)) + 1, dtype=np.int32)
    lut[present] = np.arange(1, present.size + 1, dtype=np.int32)
    return lut[np.maximum(labels, 0)]


def label_regions(edges: np.ndarray, *, min_size: int = 30, connectivity: int = 4) -> np.ndarray:
    """Flood-fill the non-edge pixels into regions.

    Parameters
    ----------
    edges : (H, W) bool, True on edges (and invalid pixels).
    min_size : regions with fewer pixels are dropped (label 0).
    connectivity : 4 (default: a one-pixel diagonal edge line still separates) or 8.

    Returns
    -------
    (H, W) int32 labels, 0 = in no region, regions 1..n ordered by first pixel (row-major).
    """
    edges = np.asarray(edges, dtype=bool)
    if edges.ndim != 2:
        raise ValueError(f"edges must have shape (H, W); got {edges.shape}")
    if connectivity not in (4, 8):
        raise ValueError(f"connectivity must be 4 or 8; got {connectivity}")
    if min_size < 1:
        raise ValueError(f"min_size must be >= 1; got {min_size}")
    import cv2  # here, not at module level: importing the stage stays light

    free = (~edges).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(free, connectivity=connectivity,
                                                           ltype=cv2.CV_32S)
    keep = np.zeros(n, dtype=bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_size
    # OpenCV numbers components by first pixel (row-major): renumbering the kept ones
    # 1..n in that order needs no sort
    lut = np.zeros(n, dtype=np.int32)
    lut[keep] = np.arange(1, int(keep.sum()) + 1, dtype=np.int32)
    return lut[labels]
