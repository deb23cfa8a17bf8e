"""Beyond the paper: give edge-band pixels back to regions, merge patches of one surface.

Both are the paper's own future work (Sec. 6). Closing and the 3x3 window leave a band of
edge pixels around every region; small objects lose most of their pixels to it. Regions
are grown back into that band, a ring of pixels at a time, wherever the region's fitted
surface explains the pixel within the local noise; then regions of the same kind whose
union one model explains as well as the parts are merged.
"""

from __future__ import annotations

import cv2
import numpy as np

from .fitting.primitives import Cylinder, Plane, Sphere

__all__ = ["grow_into_edges", "merge_candidates", "region_adjacency"]

def _shifted(array: np.ndarray, dy: int, dx: int, fill) -> np.ndarray:
    # out[i, j] = array[i + dy, j + dx], ``fill`` outside the grid.
    out = np.full_like(array, fill)
    h, w = array.shape[:2]
    ys, yd = (slice(dy, h), slice(0, h - dy)) if dy >= 0 else (slice(0, h + dy), slice(-dy, h))
    xs, xd = (slice(dx, w), slice(0, w - dx)) if dx >= 0 else (slice(0, w + dx), slice(-dx, w))
    out[yd, xd] = array[ys, xs]
    return out


def grow_into_edges(
    xyz: np.ndarray,
    labels: np.ndarray,
    models: dict,
    sigma: np.ndarray,
    ranges: np.ndarray,
    *,
    iterations: int = 3,
    k_sigma: float = 3.0,
    jump_ratio: float = 0.08,
    jump_min: float = 0.05,
) -> np.ndarray:
    """Hand unlabelled valid pixels to the adjacent region whose model fits them best.

    Parameters
    ----------
    xyz : (H, W, 3) points, NaN where invalid.
    labels : (H, W) int labels, 0 = no region.
    models : label -> fitted model (regions without a model do not grow).
    sigma : (H, W) range noise per pixel, metres.
    ranges : (H, W) ranges, for the no-jump test between a pixel and its neighbour.
    iterations : rings of pixels to add at most.
    k_sigma : accept a pixel within ``k_sigma * max(sigma, model.rms)`` of the surface.

    Returns
    -------
    New (H, W) int32 labels.
    """
    from .fitstage import model_table
    from .kernels import grow_rings

    labels = np.array(labels, dtype=np.int32, order="C", copy=True)
    n = int(labels.max(initial=0)) + 1
    kinds, params, rms = model_table(models, n)
    grow_rings(np.ascontiguousarray(xyz.reshape(-1, 3), dtype=np.float64), labels, kinds, params, rms,
               np.ascontiguousarray(sigma, dtype=np.float64).ravel(),
               np.ascontiguousarray(ranges, dtype=np.float64).ravel(),
               int(iterations), float(k_sigma), float(jump_ratio), float(jump_min))
    return labels


def region_adjacency(labels: np.ndarray, *, reach: int = 2, wrap_columns: bool = False) -> set[tuple[int, int]]:
    """Pairs (a < b) of regions whose pixels come within ``reach`` pixels of each other.

    With ``wrap_columns`` (a 360-degree grid) the first and last columns are neighbours too.
    """
    if wrap_columns and labels.shape[1] > 2 * reach:
        # the seam's strip: the last ``reach`` columns, then the first ``reach``
        seam = np.concatenate([labels[:, -reach:], labels[:, :reach]], axis=1)
        return region_adjacency(labels, reach=reach) | region_adjacency(seam, reach=reach)
    n = int(labels.max(initial=0)) + 1
    if n <= 4096:  # an n x n matrix stays small; beyond, collect pairs per shift
        from .kernels import adjacency_matrix

        a, b = np.nonzero(np.triu(adjacency_matrix(np.ascontiguousarray(labels, dtype=np.int32), n, reach)))
        return set(zip(a.tolist(), b.tolist()))
    pairs = set()
    for dy in range(-reach, reach + 1):
        for dx in range(0, reach + 1):
            if (dx == 0 and dy <= 0):
                continue
            other = _shifted(labels, dy, dx, 0)
            touch = (labels > 0) & (other > 0) & (labels != other)
            if touch.any():
                a, b = labels[touch], other[touch]
                codes = np.unique(np.minimum(a, b).astype(np.int64) << 32 | np.maximum(a, b))
                pairs.update((int(c >> 32), int(c & 0xFFFFFFFF)) for c in codes)
    return pairs


def _angle_deg(u: np.ndarray, v: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(abs(float(u @ v)), 0.0, 1.0))))


def similar_models(a, b, *, max_angle_deg: float, tolerance: float) -> bool:
    """Cheap pre-test: could ``a`` and ``b`` be the same surface (before fitting the union)?"""
    if a.kind != b.kind:
        return False
    if isinstance(a, Plane):
        sign = 1.0 if float(a.normal @ b.normal) >= 0 else -1.0
        return (_angle_deg(a.normal, b.normal) <= max_angle_deg
                and abs(a.d - sign * b.d) <= tolerance)
    # the radius test first: two numbers, and it rejects most pairs
    if isinstance(a, Cylinder):
        if abs(a.radius - b.radius) > tolerance or _angle_deg(a.axis, b.axis) > max_angle_deg:
            return False
        rel = b.point - a.point
        return bool(np.linalg.norm(rel - (rel @ a.axis) * a.axis) <= tolerance)
    if isinstance(a, Sphere):
        return abs(a.radius - b.radius) <= tolerance and bool(np.linalg.norm(a.center - b.center) <= tolerance)
    return False


def merge_candidates(models: dict, *, max_angle_deg: float, tolerance: float,
                     adjacency: set[tuple[int, int]], disjoint: bool = True) -> list[tuple[int, int]]:
    """Pairs of labels worth a union fit, cheapest first (by the parts' rms sum).

    Adjacent regions of one kind are always candidates: two pieces of one small cylinder
    can disagree on their axes more than any parameter test would allow, and the union
    fit decides. Regions that do not touch are candidates only with ``disjoint`` and when
    :func:`similar_models` says their parameters agree.
    """
    keys = sorted(models)
    out = []
    planes = [k for k in keys if isinstance(models[k], Plane)]
    if len(planes) > 1:
        # planes: every pair's parameter test at once
        normals = np.array([models[k].normal for k in planes])
        offsets = np.array([models[k].d for k in planes])
        dots = normals @ normals.T
        sign = np.where(dots >= 0, 1.0, -1.0)
        close = np.abs(dots) >= np.cos(np.radians(max_angle_deg)) - 1e-12
        close &= np.abs(offsets[:, None] - sign * offsets[None, :]) <= tolerance
        wanted = close if disjoint else np.zeros_like(close)
        position = {k: i for i, k in enumerate(planes)}
        for a, b in adjacency:
            if a in position and b in position:
                wanted[position[a], position[b]] = True
        first, second = np.nonzero(np.triu(wanted, 1))
        out.extend((planes[i], planes[j]) for i, j in zip(first.tolist(), second.tolist()))
    others = [k for k in keys if not isinstance(models[k], Plane)]
    for i, a in enumerate(others):
        for b in others[i + 1:]:
            if models[a].kind != models[b].kind:
                continue
            if (a, b) in adjacency or (disjoint and similar_models(
                    models[a], models[b], max_angle_deg=max_angle_deg, tolerance=tolerance)):
                out.append((a, b))
    out.sort(key=lambda ab: (models[ab[0]].rms + models[ab[1]].rms, ab))
    return out


def leftover_candidates(labels: np.ndarray, valid: np.ndarray, jumps: np.ndarray, *,
                        min_size: int, first_label: int) -> np.ndarray:
    """Compact blobs of valid, unlabelled, non-jump pixels: regions the edge band swallowed whole.

    Small curved objects far away have a residual above the threshold everywhere, so no
    region seeds them and growth cannot reach them. The leftover pixels form a network of
    thin crease bands with such blobs attached; one 3x3 erosion cuts the bands, the
    surviving cores are flood-filled, then dilated back by one pixel within the leftover.

    Returns
    -------
    (H, W) int32 candidate labels numbered from ``first_label`` (0 elsewhere); each must
    still be accepted by a fit.
    """
    free = (valid & (labels == 0) & ~jumps).astype(np.uint8)
    kernel = np.ones((3, 3), np.uint8)
    # The grid border is no edge: a surface seen only by the first rows must keep its core.
    cores = cv2.erode(free, kernel, borderType=cv2.BORDER_REPLICATE)
    n, comp = cv2.connectedComponents(cores, connectivity=4, ltype=cv2.CV_32S)
    if n <= 1:
        return np.zeros(labels.shape, np.int32)
    grown = cv2.dilate(comp.astype(np.float32), kernel).astype(np.int32)
    # Dilation takes the larger id where two cores meet; only leftover pixels may join.
    comp = np.where(free.astype(bool), np.maximum(comp, grown), 0)
    sizes = np.bincount(comp.ravel(), minlength=n)
    keep = sizes >= min_size
    keep[0] = False
    lut = np.zeros(n, np.int32)
    lut[keep] = np.arange(first_label, first_label + int(keep.sum()), dtype=np.int32)
    return lut[comp]
