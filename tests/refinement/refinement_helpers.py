"""Grids of points for the refinement steps' tests."""

import numpy as np


def plane_grid(h, w, *, z=3.0, slope=0.0, noise=0.0, seed=0, step=0.02):
    """An (h, w, 3) grid of points on z = ``z + slope * x`` with Gaussian ``noise`` in z."""
    v, u = np.mgrid[0:h, 0:w].astype(float)
    x, y = u * step, v * step
    rng = np.random.default_rng(seed)
    return np.dstack([x, y, z + slope * x + rng.normal(0.0, noise, x.shape)])


def folded_strip(noise: float, seed: int = 0):
    """Three planes meeting at two 45-degree creases on a 60 x 90 grid: ``(xyz, truth, normals)``
    with ``truth`` the plane (1, 2, 3) of each pixel and ``normals`` their unit normals."""
    v, u = np.mgrid[0:60, 0:90].astype(float)
    x, y = u * 0.02, v * 0.02
    # heights: flat, rising at 45 deg, then falling at 45 deg (continuous at the creases)
    z = np.where(u < 30, 0.0, np.where(u < 60, x - 0.6, 0.6 - (x - 1.2)))
    truth = np.where(u < 30, 1, np.where(u < 60, 2, 3))
    rng = np.random.default_rng(seed)
    xyz = np.dstack([x, y, 3.0 + z + rng.normal(0.0, noise, z.shape)])
    normals = {1: np.array([0.0, 0.0, 1.0]), 2: np.array([-1.0, 0.0, 1.0]) / np.sqrt(2),
               3: np.array([1.0, 0.0, 1.0]) / np.sqrt(2)}
    return xyz, truth, normals


def best_overlap(labels, truth, k):
    """The label covering most pixels of truth ``k``, and the share of ``k`` it covers."""
    ids, counts = np.unique(labels[truth == k], return_counts=True)
    return int(ids[np.argmax(counts)]), counts.max() / (truth == k).sum()


def leftover_candidates_numpy(labels, valid, jumps, min_size, first):
    """``recover.leftover_candidates`` in OpenCV and numpy, as it was before its compiled pass:
    the 3x3 erosion (border replicated), the cores' 4-connected components, the dilation
    within the leftover, the sizes and the renumbering from ``first``."""
    import cv2

    free = (valid & (labels == 0) & ~jumps).astype(np.uint8)
    kernel = np.ones((3, 3), np.uint8)
    cores = cv2.erode(free, kernel, borderType=cv2.BORDER_REPLICATE)
    if not cores.any():
        return np.zeros(labels.shape, np.int32)
    n, comp = cv2.connectedComponents(cores, connectivity=4, ltype=cv2.CV_32S)
    grown = cv2.dilate(comp.astype(np.float32), kernel).astype(np.int32)
    comp = np.where(free.astype(bool), np.maximum(comp, grown), 0)
    keep = np.bincount(comp.ravel(), minlength=n) >= min_size
    keep[0] = False
    lut = np.zeros(n, np.int32)
    lut[keep] = np.arange(first, first + keep.sum())
    return lut[comp]
