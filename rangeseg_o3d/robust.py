"""Trimmed fitting: find the one surface that most of a mixed point set lies on.

Used where a region holds more than one surface (two objects touching without a crease,
a leftover blob that caught part of its neighbour's edge band): each raw least-squares
model proposes the points near it, the pipeline's fitter judges those points, and the
proposal the fitter accepts with the most inliers wins. This is the paper's "local checks
that remove under-segmentation" (Sec. 6).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .fitting.cylinder import fit_cylinder
from .fitting.plane import fit_plane
from .fitting.sphere import fit_sphere

__all__ = ["trimmed_fit"]

_MAD_TO_SIGMA = 1.4826


def trimmed_fit(points: np.ndarray, judge: Callable, *, sigma: float, min_points: int,
                rounds: int = 2):
    """The best-supported model of ``points`` and the mask of its inliers.

    Parameters
    ----------
    points : (N, 3) array.
    judge : the pipeline's fitter, ``judge(points) -> model | FitFailure``.
    sigma : typical range noise of these points (m); inliers lie within
        ``max(3 sigma, 3 model.rms)`` of the accepted model.
    min_points : fewer inliers than this is no answer.
    rounds : trimming rounds per proposal.

    Returns
    -------
    (model, inliers) or (None, None) when no proposal is accepted.
    """
    pts = np.asarray(points, dtype=float)
    if len(pts) < min_points:
        return None, None
    best, best_mask = None, None
    for propose in (fit_plane, fit_cylinder, fit_sphere):
        model = propose(pts)
        if not model:
            continue
        keep = np.ones(len(pts), bool)
        for _ in range(rounds):
            dist = np.abs(model.distances(pts))
            spread = _MAD_TO_SIGMA * np.median(dist[keep])
            keep = dist <= max(3.0 * sigma, 2.5 * spread)
            if keep.sum() < min_points:
                break
            model = propose(pts[keep])
            if not model:
                break
        if not model or keep.sum() < min_points:
            continue
        judged = judge(pts[keep])
        if not judged:
            continue
        inliers = np.abs(judged.distances(pts)) <= 3.0 * max(sigma, judged.rms)
        if inliers.sum() >= min_points and (best_mask is None or inliers.sum() > best_mask.sum()):
            best, best_mask = judged, inliers
    return best, best_mask
