"""Trimmed fitting: find the one surface that most of a mixed point set lies on.

Used where a region holds more than one surface (two objects touching without a crease,
a leftover blob that caught part of its neighbour's edge band). Least trimmed squares by
concentration steps on a quadratic height field, which locally describes a plane, a
cylinder and a sphere alike, finds the dominant smooth surface cheaply (a 6-parameter
linear fit per step); the pipeline's fitter then judges the points near it. This is the
paper's "local checks that remove under-segmentation" (Sec. 6).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..kernels.kinds import NONE
from ..kernels.linalg import CHI_SQUARE_SIGMAS, noise_rms_bound
from ..kernels.linalg import curvature_resolved as linalg_curvature_resolved
from .primitives import Cylinder, Sphere
from .region_fitter import model_row

__all__ = ["trimmed_fit", "distinct_masks", "beyond_noise", "union_out_of_reach", "curvature_resolved", "distance_noise",
           "lateral_distance_noise",
           "CHI_SQUARE_SIGMAS", "REACH_MARGIN", "REACH_TRUSTED_SHARE"]

# Pools of at least this many points get four times the random three-point planes.
MANY_POINTS = 5000
# trimmed_fit's defaults (also those of the compiled search, fitting._trimmed)
ROUNDS, KEEP_FRACTION, MAX_POINTS, ENOUGH = 5, 0.6, 600, 0.9


#: :func:`union_out_of_reach` refuses a union only when its first-order bound exceeds the
#: limit by this factor: the bound linearises the distances over the moves a model fitting
#: the first part within the limit can make, and the factor covers their curvature...
REACH_MARGIN = 2.0
#: ...while those moves stay under this share of the radius (axis tilts: radians); a model
#: its region determines less well is left to the refit.
REACH_TRUSTED_SHARE = 0.5


def beyond_noise(rms: float, sigma: float, n: int) -> bool:
    """Whether a fit's ``rms`` over ``n`` points is larger than noise of rms ``sigma``
    explains: over :func:`rangeseg_o3d.kernels.linalg.noise_rms_bound` with ``n`` degrees
    of freedom and ``CHI_SQUARE_SIGMAS``."""
    # the kernel's Python form: one scalar needs no compiled signature of its own
    return rms > noise_rms_bound.py_func(float(sigma), float(n), CHI_SQUARE_SIGMAS)


def union_out_of_reach(model, points: np.ndarray, first: int, max_rms: float) -> bool:
    """Whether no cylinder or sphere near ``model`` (of its kind) fits ``points`` within
    ``max_rms``, by a first-order bound that costs about one step of the refit.

    ``model`` fits ``points[:first]`` (a region); ``points[first:]`` is a piece whose union
    with it would be refitted. A model fitting the union within ``max_rms`` keeps the
    region's sum of squared distances within ``n max_rms^2`` (``n`` all the points): with
    the distances linearised at ``model``, that confines it to an ellipsoid about the
    region's best step, over which the piece's distances change by at most
    ``sqrt(trace(H_region^-1 H_piece) x spread)`` (``H = J^T J``). A piece farther than that
    from every such model by :data:`REACH_MARGIN` times ``sqrt(n) max_rms`` leaves the
    union beyond ``max_rms`` (a wall beside a column). A first-order rule, not a proof: it
    answers only while the ellipsoid keeps the axis, centre and radius within
    :data:`REACH_TRUSTED_SHARE` of the radius (tilts within as many radians), False for
    other kinds or a model the region determines less well (the refit decides).
    """
    from ._compiled import cylinder_union_reach, sphere_union_reach

    points = np.ascontiguousarray(points, dtype=np.float64)
    n = len(points)
    if not 0 < first < n:
        return False
    budget = n * max_rms * max_rms
    if isinstance(model, Cylinder):
        reach = cylinder_union_reach(points, int(first), np.asarray(model.axis, np.float64),
                                     np.asarray(model.point, np.float64), float(model.radius), budget,
                                     REACH_TRUSTED_SHARE)
    elif isinstance(model, Sphere):
        reach = sphere_union_reach(points, int(first), np.asarray(model.center, np.float64),
                                   float(model.radius), budget, REACH_TRUSTED_SHARE)
    else:
        return False
    return bool(reach > REACH_MARGIN * np.sqrt(budget))


def distance_noise(model, points: np.ndarray, sigma: np.ndarray, rays: np.ndarray | None = None) -> np.ndarray:
    """Per point, the noise of its distance to ``model`` when the model is right: range
    noise ``sigma`` moves a point along its ray (from the sensor at the origin, or the unit
    ``rays`` given per point), which changes its distance to the surface by the cosine of
    the incidence only.

    A wall seen head-on keeps the whole range noise; the flanks of a column or pipe, seen
    at grazing incidence, almost none. A model's rms over its region is thus compared with
    the rms of these values, not with the range noise (a cylinder over its end cap is
    beyond this noise while well within the range noise).

    On a cylinder or sphere of radius ``r`` a move ``delta`` along the ray also changes the
    distance by the second-order term ``delta**2 c**2 / (2 r)``, ``c`` the ray's component
    along the surface's curved direction (for a sphere the sine of the incidence; for a
    cylinder the ray's part across both the normal and the axis); its mean square,
    ``3 (sigma**2 c**2 / (2 r))**2`` for Gaussian range noise, is added in quadrature. At a
    pillar's flanks under a depth camera's centimetres of noise it is most of the noise
    there is (sigma 3 cm, r 0.15 m: 5 mm), which the first-order term calls zero; under a
    laser's millimetres it is a few microns. The compiled twin
    (``kernels.inline._distance_noise``, used by ``kernels.nearer_models``) has the same
    term, and so does the crease-side kernel (``kernels.sides``); the compiled strip and
    tile kernels (``kernels.strips``, ``kernels.tiles``) still use the first-order term alone.
    """
    points = np.asarray(points, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    if rays is None:
        rays = points / np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-12)
    cosines = np.abs(np.einsum("ij,ij->i", rays, model.normals(points)))
    first = sigma * cosines
    if isinstance(model, Cylinder):
        along_axis = rays @ np.asarray(model.axis, dtype=float)
        curved = np.maximum(1.0 - cosines * cosines - along_axis * along_axis, 0.0)
    elif isinstance(model, Sphere):
        curved = np.maximum(1.0 - cosines * cosines, 0.0)
    else:
        return first
    if not model.radius > 0:
        return first
    sagitta = sigma * sigma * curved / (2.0 * float(model.radius))
    return np.sqrt(first * first + 3.0 * sagitta * sagitta)


def lateral_distance_noise(model, points: np.ndarray, sigma: np.ndarray, lateral: float) -> np.ndarray:
    """Per point, the noise of its distance to the plane ``model`` when the model is right and
    the sensor measures the surface up to ``lateral`` (rms, metres per metre of range) across
    the ray it reports: the range noise times the incidence cosine (:func:`distance_noise`)
    and the lateral offset times its sine, added in quadrature.

    Head-on the lateral offset slides a point along its surface (no distance); at grazing
    incidence, where the range noise moves it by almost nothing, it is all the distance noise
    there is (a structured-light camera whose spot is wider than its pixel).
    """
    points = np.asarray(points, dtype=float)
    ranges = np.maximum(np.linalg.norm(points, axis=1), 1e-12)
    cosines = np.abs(points @ np.asarray(model.normal, dtype=float)) / ranges
    across = lateral * ranges
    along = np.asarray(sigma, dtype=float) * cosines
    return np.sqrt(along * along + across * across * np.maximum(1.0 - cosines * cosines, 0.0))


def curvature_resolved(plane_squares: float, curved_squares: float, n: int, extra: int = 2) -> bool:
    """Whether a curved model, with ``extra`` parameters more than a plane, lowers the sum
    of squared distances of ``n`` points by more than noise alone would (an F-test).

    Were the points a plane, the drop from its ``plane_squares`` to the curved model's
    ``curved_squares`` would be the noise variance times a chi-square of ``extra``
    degrees of freedom; the variance is estimated from the curved model's own residuals,
    so the test needs no noise model (no incidence factor, no tile-mean scaling). The
    drop must exceed that chi-square's mean by ``CHI_SQUARE_SIGMAS`` of its deviations
    (:func:`rangeseg_o3d.kernels.linalg.curvature_resolved`, which the fitter's decision
    calls). With no degree of freedom left the curvature counts as resolved (nothing to test).
    """
    return bool(linalg_curvature_resolved.py_func(float(plane_squares), float(curved_squares), int(n),
                                                  int(extra), CHI_SQUARE_SIGMAS))


def trimmed_fit(points: np.ndarray, judge: Callable, *, sigma: float, min_points: int,
                rounds: int = ROUNDS, keep_fraction: float = KEEP_FRACTION, max_points: int = MAX_POINTS,
                enough: float = ENOUGH, pool: np.ndarray | None = None, starts: bool = False):
    """The dominant surface of ``points`` as judged by the fitter, and its inliers.

    Two proposals: a plane started from the best random three-point plane and refitted on
    its inliers (within three noise sigmas), which locks onto the largest of several planes
    meeting at creases; and a quadratic height field refined by concentration steps
    (refit on the ``keep_fraction`` of points closest to it), which follows a cylinder or
    a sphere. The fitter judges the points near each, the larger set first; the answer
    with most inliers wins, and one with ``enough`` of the points ends the search.
    Both proposals come from one compiled call (:func:`rangeseg_o3d.kernels.trimmed_proposals`).

    With ``starts``, the proposals are quadrics grown from local starts instead
    (:func:`rangeseg_o3d.kernels.local_proposals`: seeds spread over the points, each
    started on its nearest eighth of them), the largest distinct ones judged first, at
    most four, and only an answer that fits at the noise counts; fewer than
    ``2 min_points`` points get none (no room for two surfaces). For points holding
    several surfaces of about equal size (a floor and the two columns standing on it)
    the global proposals straddle them: the best random plane is the one tangent to both
    columns, and the quadric bends over all three; a start on one surface does not.

    Parameters
    ----------
    points : (N, 3) array.
    judge : the pipeline's fitter, ``judge(points) -> model | FitFailure``.
    sigma : typical range noise of these points (m).
    min_points : fewer inliers than this is no answer.
    rounds : refinement steps per proposal.
    keep_fraction : share kept per step (the dominant surface must hold more).
    max_points : the steps run on an even subsample of at most this size; inliers are
        counted on all points.
    enough : a share of inliers at which the first answer is taken without trying more.
    pool : indices into ``points``: fit ``points[pool]`` (gathered only when a model is
        judged, the subsample before: a large pool no model explains costs no gather).
    starts : the local starts' proposals (above) instead of the global ones.

    Returns
    -------
    (model, inliers) or (None, None) when the fitter accepts nothing.
    """
    from ..kernels import local_proposals, trimmed_proposals

    if pool is None:
        pool = slice(None)
        size = len(points)
    else:
        size = len(pool)
    if size < max(min_points, 6):
        return None, None
    step = -(-size // max_points)
    pts = np.ascontiguousarray(points[pool][::step] if isinstance(pool, slice) else points[pool[::step]],
                               dtype=float)
    search = _Search(points, pool, judge, sigma, min_points, step, pts, enough * size)
    if not starts:
        keep = max(int(keep_fraction * len(pts)), 6)
        # a pool of many surfaces (a region that leaked through a whole room) needs more
        # random three-point planes before one lies on a single surface
        trials = 64 if size < MANY_POINTS else 256
        search.judge_all(trimmed_proposals(pts, float(sigma), int(rounds), min(keep, len(pts)), trials, 0))
        return search.best, search.best_mask
    if size < 2 * min_points:  # no room for two surfaces of min_points: the global answer stands
        return None, None
    seeds = local_seeds(size, max_points)
    local = local_proposals(pts, float(sigma), int(rounds), seeds, max(len(pts) // _LOCAL_SEEDS, 6))
    if search.judge_all(distinct_masks(local), limit=_LOCAL_JUDGED, first_at_noise=True):
        return search.best, search.best_mask
    return None, None


# Seeds of the local proposals, and how many distinct ones the fitter judges at most
# (fitting._trimmed.LOCAL_JUDGED, the compiled search's, is the same).
_LOCAL_SEEDS = 8
_LOCAL_JUDGED = 4


def local_seeds(size: int, max_points: int = MAX_POINTS) -> np.ndarray:
    """The local starts' seeds of a pool of ``size`` points: ``_LOCAL_SEEDS`` indices spread
    evenly over its subsample of at most ``max_points`` (a pool's pixels come in raster
    order: over the image)."""
    step = -(-size // max_points)
    last = -(-size // step) - 1
    # np.linspace(0, last, _LOCAL_SEEDS).astype(np.int64), the same float products
    # truncated, without its overhead (a tenth of a small pool's search)
    spacing = last / (_LOCAL_SEEDS - 1)
    return np.array([int(i * spacing) for i in range(_LOCAL_SEEDS - 1)] + [last], np.int64)


def distinct_masks(masks) -> list[np.ndarray]:
    """The masks, largest first, without those mostly covered by a larger one (starts on
    one surface find the same points)."""
    out = []
    for mask in sorted(masks, key=lambda m: -int(m.sum())):
        count = int(mask.sum())
        if count and all(np.count_nonzero(mask & kept) < 0.8 * count for kept in out):
            out.append(mask)
    return out


class _Search:
    """The best answer so far of :func:`trimmed_fit` over the proposals judged."""

    def __init__(self, points, pool, judge, sigma, min_points, step, pts, enough):
        self.points, self.pool, self.judge, self.sigma = points, pool, judge, sigma
        self.min_points, self.step, self.pts, self.enough = min_points, step, pts, enough
        self.all_pts = None
        self.best, self.best_mask, self.best_score = None, None, (False, -1)

    def judge_all(self, proposals, limit: int | None = None, first_at_noise: bool = False) -> bool:
        """Judge ``proposals`` (the one near more points first: often the only one judged),
        at most ``limit``; True when an answer fits at the noise. The search stops after
        one at the noise with ``enough`` points, or (``first_at_noise``) any at the noise."""
        judged_count = 0
        for near in sorted(proposals, key=lambda mask: -int(mask.sum())):
            if near.sum() * self.step < self.min_points:
                continue
            if limit is not None and judged_count >= limit:
                break
            judged_count += 1
            if self._judge(near) or (first_at_noise and self.best_score[0]):
                break
        return self.best_score[0]

    def _judge(self, near) -> bool:
        # True when this answer ends the search
        judged = self.judge(self.pts[near])
        if not judged:
            return False
        if self.all_pts is None:  # the pool's points, as pool_inliers reads them
            self.all_pts = pool_points(self.points, None if isinstance(self.pool, slice) else self.pool)
        xyz, indices = self.all_pts
        sigma = self.sigma
        # Candidates are compared within one tolerance: with each model's own, a worse
        # fit (a cylinder bent over the crease of two planes) would win by its larger rms.
        # One that fits at the noise beats one that does not, whatever their counts: the
        # bent cylinder takes more points within the tolerance (some of either face) than
        # the plane of one face, but its residuals are not noise.
        kind, row = model_row(judged)
        if kind != NONE:  # one compiled pass: the models' distances, counted twice
            from ..kernels import pool_inliers

            inliers, n_inliers, n_noise = pool_inliers(xyz, indices, kind, row, 3.0 * max(sigma, judged.rms),
                                                       3.0 * sigma)
        else:  # another plugin's model type: its own distances
            distances = np.abs(judged.distances(xyz[indices]))
            inliers = distances <= 3.0 * max(sigma, judged.rms)
            n_inliers, n_noise = int(inliers.sum()), int(np.count_nonzero(distances <= 3.0 * sigma))
        score = (not beyond_noise(judged.rms, sigma, int(near.sum())), n_noise)
        if n_inliers >= self.min_points and score > self.best_score:
            self.best, self.best_mask, self.best_score = judged, inliers, score
            return score[0] and score[1] >= self.enough
        return False


def pool_points(points: np.ndarray, pool: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``(xyz, indices)`` with ``xyz[indices]`` the pool's points, ``xyz`` read-only.

    The points themselves when they are a C-ordered float array (no gather of a large
    pool), else the gathered pool."""
    # read-only either way: a cloud's points are, and the compiled pool_inliers then has one signature
    if pool is not None and points.dtype == np.float64 and points.flags.c_contiguous and points.ndim == 2:
        xyz, indices = points.view(), np.ascontiguousarray(pool, dtype=np.int64)
    else:
        xyz = np.ascontiguousarray(points if pool is None else points[pool], dtype=float)
        xyz = xyz.view()
        indices = np.arange(len(xyz))
    xyz.flags.writeable = False
    return xyz, indices
