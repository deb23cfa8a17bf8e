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


def trimmed_fit(points: np.ndarray, judge: Callable, *, sigma: float, min_points: int,
                rounds: int = 4, keep_fraction: float = 0.6, max_points: int = 2000):
    """The best-supported model of ``points`` and the mask of its inliers.

    Least trimmed squares by concentration steps: starting from each raw least-squares
    model (plane, cylinder, sphere), refit on the ``keep_fraction`` of points closest to
    the current model, ``rounds`` times; then take every point within
    ``max(3 sigma, 3 rms)`` of it and let ``judge`` decide.

    Parameters
    ----------
    points : (N, 3) array.
    judge : the pipeline's fitter, ``judge(points) -> model | FitFailure``.
    sigma : typical range noise of these points (m).
    min_points : fewer inliers than this is no answer.
    rounds : concentration steps per proposal.
    keep_fraction : share of the points kept in each step (the surface must hold more).
    max_points : proposals and trimming run on an even subsample of at most this size;
        the inliers are counted on all points.

    Returns
    -------
    (model, inliers) or (None, None) when no proposal is accepted.
    """
    all_pts = np.asarray(points, dtype=float)
    if len(all_pts) < min_points:
        return None, None
    step = -(-len(all_pts) // max_points)
    pts = all_pts[::step]
    h = max(int(keep_fraction * len(pts)), min(min_points, len(pts)))
    best, best_mask = None, None
    for propose in (fit_plane, fit_cylinder, fit_sphere):
        model = propose(pts)
        for _ in range(rounds):
            if not model:
                break
            closest = np.argpartition(np.abs(model.distances(pts)), h - 1)[:h]
            model = propose(pts[closest])
        if not model:
            continue
        near = np.abs(model.distances(pts)) <= 3.0 * max(sigma, model.rms)
        if near.sum() * step < min_points:
            continue
        judged = judge(pts[near])
        if not judged:
            continue
        inliers = np.abs(judged.distances(all_pts)) <= 3.0 * max(sigma, judged.rms)
        if inliers.sum() >= min_points and (best_mask is None or inliers.sum() > best_mask.sum()):
            best, best_mask = judged, inliers
    return best, best_mask
