"""The trimmed fit (:func:`rangeseg_o3d.fitting.robust.trimmed_fit`) judged by the primitive
decision, in one compiled call.

The trimmed fit of a small pool costs about 60 microseconds of compiled proposals and
30 of compiled decision per proposal; with the judge and the inlier count called from
Python, the calls between them cost as much again, and the refinement of a cluttered
frame runs it dozens of times. :func:`trimmed_decision` does the whole search of
``trimmed_fit(points, fitter.fit, pool=...)`` for the built-in fitter (same proposals,
same decision, same order, same scores) and hands back the winner's decision as flat
arrays; :func:`rangeseg_o3d.fitting.classify.model_of_decision` makes the same model of
it that :func:`rangeseg_o3d.fitting.classify.fit_primitive` makes.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import njit  # numba.njit, with this package's cache locator installed
from ..kernels.kinds import CYLINDER, NONE, PARAM_SLOTS, PLANE, SPHERE
from ..kernels.linalg import noise_rms_bound
from ..kernels.trimmed import pool_inliers, trimmed_proposals
from ._compiled import plane_of, prepare_points
from ._decide import ACCEPTED, CURVED_SIZE, RADIUS, RMS, primitive_decision

__all__ = ["trimmed_decision", "DECISION_INTS", "DECISION_FLOATS"]

#: Files whose kernels compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("_decide.py", "_compiled.py", "_codes.py", "../kernels/trimmed.py", "../kernels/linalg.py",
                 "../kernels/labelwise.py", "../kernels/kinds.py", "../kernels/inline.py", "../kernels/grid.py")

#: Slots of the integer fields of a packed decision: kind, status, first, plane inliers.
DECISION_INTS = 4
#: Slots of the float fields: scale, d, plane rms, plane tolerance, eigen rms.
DECISION_FLOATS = 5


@njit(cache=True, nogil=True)
def _world_model(kind, decision, row):
    # The model's parameters as the Python models hold them (classify.fit_primitive's
    # Plane, cylinder.cylinder_model, sphere.sphere_model: the same operations), written
    # into ``row`` (a model table row); returns its rms.
    centroid, scale, normal, d, plane_rms, curved = decision[3], decision[4], decision[5], decision[6], \
        decision[7], decision[12]
    if kind == PLANE:
        row[:3] = normal
        row[3] = d
        return plane_rms
    result = curved[kind]
    if kind == CYLINDER:
        # the axis's sign: its largest-magnitude component (the first of equals) positive
        largest = result[0]
        for a in range(1, 3):
            if abs(result[a]) > abs(largest):
                largest = result[a]
        sign = -1.0 if largest < 0 else 1.0
        for a in range(3):
            row[a] = -result[a] if sign < 0 else result[a]
            row[3 + a] = centroid[a] + scale * result[3 + a]
        row[6] = result[RADIUS] * scale
    else:
        for a in range(3):
            row[a] = centroid[a] + scale * result[a]
        row[3] = result[RADIUS] * scale
    return result[RMS] * scale


@njit(cache=True, nogil=True)
def _pack(decision, ints, floats, centroid, normal, codes, curved):
    ints[0], ints[1], ints[2], ints[3] = decision[0], decision[1], decision[2], decision[10]
    floats[0], floats[1], floats[2], floats[3], floats[4] = decision[4], decision[6], decision[7], \
        decision[8], decision[9]
    centroid[:] = decision[3]
    normal[:] = decision[5]
    codes[:] = decision[11]
    curved[:, :] = decision[12]


@njit(cache=True, nogil=True)
def trimmed_decision(xyz, pool, sigma, min_points, rounds, keep_fraction, max_points, enough, many_points,
                     chi_square_sigmas, planes_only, fit_max_points, fit_min_points, max_rms, axis_hint, hemisphere,
                     hemi_u,
                     hemi_v, hemi_s, cones, plane_rms, cylinder_rms, sphere_rms, rms_per_range2, max_radius,
                     min_arc, curvature_gain, inlier_factor, roundness_cylinder, roundness_sphere,
                     max_iterations, noise_floor):
    """``trimmed_fit(xyz, judge, pool=pool, ...)`` with ``judge`` the region fitter's
    ``fit`` (points subsampled to ``fit_max_points``, at least ``fit_min_points`` of them,
    then ``primitive_decision`` with the arguments after ``max_rms``), refusing a model
    whose rms is over ``max_rms`` (inf: none). With ``planes_only`` the judge is
    ``fit_plane`` instead (the least-squares plane of all the points; the decision's
    arguments are not read).

    Returns ``(found, ints, floats, centroid, normal, codes, curved, inliers)``: whether a
    model won, its decision packed (:data:`DECISION_INTS`, :data:`DECISION_FLOATS` and the
    arrays of :class:`rangeseg_o3d.fitting._decide.Decision`) and its inliers among the pool.
    """
    ints = np.zeros(DECISION_INTS, np.int64)
    floats = np.zeros(DECISION_FLOATS)
    centroid, normal = np.zeros(3), np.zeros(3)
    codes = np.full(4, -1, np.int64)
    curved = np.full((4, CURVED_SIZE), np.nan)
    best_mask = np.zeros(pool.shape[0], np.bool_)
    size = pool.shape[0]
    if size < max(min_points, 6):
        return False, ints, floats, centroid, normal, codes, curved, best_mask
    step = -(-size // max_points)
    m = -(-size // step)
    pts = np.empty((m, 3))
    for i in range(m):
        pts[i] = xyz[pool[i * step]]
    keep = max(int(keep_fraction * m), 6)
    trials = 64 if size < many_points else 256
    plane_near, quad_near = trimmed_proposals(pts, sigma, rounds, min(keep, m), trials, 0)
    n_plane, n_quad = plane_near.sum(), quad_near.sum()
    found, best_noise, best_count = False, False, -1
    row = np.zeros(PARAM_SLOTS)
    # the proposal near more points first (the plane's on a tie)
    for turn in range(2):
        quadric = (turn == 0) == (n_quad > n_plane)
        near, count = (quad_near, n_quad) if quadric else (plane_near, n_plane)
        if count * step < min_points:
            continue
        chosen = np.empty((count, 3))
        j = 0
        for i in range(m):
            if near[i]:
                chosen[j] = pts[i]
                j += 1
        fit_step = -(-count // fit_max_points)
        if fit_step > 1:
            chosen = np.ascontiguousarray(chosen[::fit_step])
        if chosen.shape[0] < max(fit_min_points, 3):
            continue
        row[:] = 0.0
        if planes_only:  # fitting.plane.fit_plane: the plane of prepared points, no other check
            n_bad, p_centroid, p_scale, q, eigvals, eigvecs = prepare_points(chosen)
            if n_bad:
                continue
            ok, p_normal, p_d, rms, p_inliers = plane_of(q, chosen, p_centroid, p_scale, eigvals, eigvecs, np.inf)
            if not ok:
                continue
            kind = PLANE
            row[:3] = p_normal
            row[3] = p_d
        else:
            decision = primitive_decision(chosen, axis_hint, hemisphere, hemi_u, hemi_v, hemi_s, cones, plane_rms,
                                          cylinder_rms, sphere_rms, rms_per_range2, max_radius, min_arc,
                                          curvature_gain, inlier_factor, roundness_cylinder, roundness_sphere,
                                          max_iterations, noise_floor)
            kind = decision[0]
            if decision[1] != ACCEPTED or kind == NONE:
                continue
            rms = _world_model(kind, decision, row)
        if not rms <= max_rms:
            continue
        mask, n_inliers, n_noise = pool_inliers(xyz, pool, kind, row, 3.0 * max(sigma, rms), 3.0 * sigma)
        at_noise = not rms > noise_rms_bound(sigma, float(count), chi_square_sigmas)
        better = at_noise > best_noise or (at_noise == best_noise and n_noise > best_count)
        if n_inliers >= min_points and better:
            found, best_noise, best_count = True, at_noise, n_noise
            best_mask = mask
            if planes_only:  # a plane decision: what model_of_decision reads
                ints[0], ints[1], ints[2], ints[3] = PLANE, ACCEPTED, NONE, p_inliers
                floats[0], floats[1], floats[2] = p_scale, p_d, rms
                centroid[:] = p_centroid
                normal[:] = p_normal
            else:
                _pack(decision, ints, floats, centroid, normal, codes, curved)
            if at_noise and n_noise >= enough * size:
                break
    return found, ints, floats, centroid, normal, codes, curved, best_mask
