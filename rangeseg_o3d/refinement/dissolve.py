"""Step 7, ``dissolve``: small blobs at junctions go to the larger neighbours that explain them.

A blob where surfaces meet can pass for a small curved patch; its kind differs from its
neighbours', so the ``merge`` step never pairs it. Runs after ``merge`` on its adjacency.
"""

from __future__ import annotations

import numpy as np

from ..fitting.region_fitter import region_indices
from .context import Context

__all__ = ["dissolve_small"]


def dissolve_small(ctx: Context, labels: np.ndarray, fits: dict, adjacency: set, *, k_sigma: float):
    """Hand small regions to larger neighbours whose surfaces already explain them.

    When at least 80 % of a region smaller than ``3 * ctx.min_size`` lies within
    ``k_sigma max(sigma, rms)`` of larger neighbours' models (neighbours by
    ``adjacency``, pairs of labels), each such point joins the neighbour that explains it
    best and the rest become unlabelled; the neighbours are refitted where moments suffice
    (planes; spheres and cylinders in the ``polish`` step). Returns new ``(labels, fits)``.
    """
    sizes = np.bincount(labels.ravel())
    if not np.any((sizes[1:] > 0) & (sizes[1:] < 3 * ctx.min_size)):
        return labels, fits
    labels, fits = labels.copy(), dict(fits)
    regions = region_indices(labels)
    small_ones = [k for k in regions if regions[k].size < 3 * ctx.min_size]
    neighbours: dict[int, set[int]] = {}
    for a, b in adjacency:
        neighbours.setdefault(a, set()).add(b)
        neighbours.setdefault(b, set()).add(a)
    changed = set()
    flat = labels.ravel()
    for small in sorted(small_ones, key=lambda k: regions[k].size):
        idx = regions.get(small)
        hosts = [k for k in neighbours.get(small, ()) if k in regions and fits.get(k)
                 and regions[k].size > idx.size]
        if not hosts:
            continue
        pts = ctx.xyz[idx]
        score = np.stack([
            np.abs(fits[k].distances(pts)) / np.maximum(ctx.sigma[idx], fits[k].rms)
            for k in hosts
        ])
        best = np.argmin(score, axis=0)
        explained = score[best, np.arange(idx.size)] <= k_sigma
        if explained.mean() < 0.8:
            continue
        new_labels = np.where(explained, np.asarray(hosts)[best], 0)
        flat[idx] = new_labels
        for k in set(new_labels[explained].tolist()):
            regions[k] = np.concatenate([regions[k], idx[new_labels == k]])
            changed.add(k)
        del regions[small]
        fits.pop(small, None)
    for k, refit in ctx.fitter.refit_regions(
            ctx.xyz, labels, fits, [k for k in changed if k in regions], from_points=False).items():
        if refit:
            fits[k] = refit
    return labels, fits
