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
from ..kernels.trimmed import local_proposals, pool_inliers, same_mask, trimmed_proposals
from ._compiled import plane_of, prepare_points
from ._decide import ACCEPTED, CURVED_SIZE, RADIUS, RMS, primitive_decision

__all__ = ["trimmed_decision", "decision_fields", "DECISION_INTS", "DECISION_FLOATS", "RECORD_SIZE"]

#: Files whose kernels compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("_decide.py", "_compiled.py", "_codes.py", "../kernels/trimmed.py", "../kernels/linalg.py",
                 "../kernels/labelwise.py", "../kernels/kinds.py", "../kernels/inline.py", "../kernels/grid.py")

#: Slots of the integer fields of a packed decision: kind, status, first, plane inliers.
DECISION_INTS = 4
#: Slots of the float fields: scale, d, plane rms, plane tolerance, eigen rms.
DECISION_FLOATS = 5
#: Slots of a decision record (:func:`trimmed_decision`'s one float64 array): the integer
#: fields (exact as floats: kinds, codes and counts far below 2**53), the float fields,
#: the centroid, the normal, the codes per kind and the curved rows per kind, in order.
#: One array, not six: compiled code hands each array back to Python as a new object (1-2
#: microseconds each), and the refinement of a cluttered frame searches dozens of times.
_CENTROID = DECISION_INTS + DECISION_FLOATS
_NORMAL = _CENTROID + 3
_CODES = _NORMAL + 3
_CURVED = _CODES + 4
RECORD_SIZE = _CURVED + 4 * CURVED_SIZE


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
def _pack(decision, record):
    # a primitive_decision's fields into a decision record (see RECORD_SIZE)
    record[0], record[1], record[2], record[3] = decision[0], decision[1], decision[2], decision[10]
    record[4], record[5], record[6], record[7], record[8] = decision[4], decision[6], decision[7], \
        decision[8], decision[9]
    record[_CENTROID:_NORMAL] = decision[3]
    record[_NORMAL:_CODES] = decision[5]
    record[_CODES:_CURVED] = decision[11]
    record[_CURVED:] = decision[12].ravel()


def decision_fields(record: np.ndarray) -> tuple:
    """The fields of :class:`rangeseg_o3d.fitting._decide.Decision`, in order, of a decision
    record :func:`trimmed_decision` returned (integers as ``int``, the codes as int64, the
    arrays views of the record)."""
    kind, status, first, plane_inliers = (int(value) for value in record[:DECISION_INTS].tolist())
    scale, d, plane_rms, plane_tol, eigen_rms = record[DECISION_INTS:_CENTROID].tolist()
    return (kind, status, first, record[_CENTROID:_NORMAL], scale, record[_NORMAL:_CODES], d, plane_rms,
            plane_tol, eigen_rms, plane_inliers, record[_CODES:_CURVED].astype(np.int64),
            record[_CURVED:].reshape(4, CURVED_SIZE))


@njit(cache=True, nogil=True)
def trimmed_decision(xyz, pool, sigma, min_points, rounds, keep_fraction, max_points, enough, many_points,
                     chi_square_sigmas, planes_only, fit_max_points, fit_min_points, max_rms, axis_hint, hemisphere,
                     hemi_u,
                     hemi_v, hemi_s, cones, plane_rms, cylinder_rms, sphere_rms, rms_per_range2, max_radius,
                     min_arc, curvature_gain, inlier_factor, roundness_cylinder, roundness_sphere,
                     max_iterations, noise_floor, seeds, given):
    """``trimmed_fit(xyz, judge, pool=pool, ...)`` with ``judge`` the region fitter's
    ``fit`` (points subsampled to ``fit_max_points``, at least ``fit_min_points`` of them,
    then ``primitive_decision`` with the arguments after ``max_rms``), refusing a model
    whose rms is over ``max_rms`` (inf: none). With ``planes_only`` the judge is
    ``fit_plane`` instead (the least-squares plane of all the points; the decision's
    arguments are not read).

    With ``seeds`` (indices into the pool's even subsample, as ``trimmed_fit(...,
    starts=True)`` spreads them; empty: the global search) the proposals are the local
    starts' quadrics (:func:`rangeseg_o3d.kernels.local_proposals`): the distinct ones,
    largest first, at most :data:`LOCAL_JUDGED` judged, the first answer at the noise
    ends the search and only an answer at the noise counts.

    The proposals depend on the pool's points, ``sigma`` and the seeds only, not on the
    judge: ``given`` (a proposals array this search returned for the same pool, sigma and
    seeds; no rows: none) is judged instead of computing them again.

    Returns ``(found, record, inliers, proposals)``: whether a model won, its decision as
    one record (:data:`RECORD_SIZE`; :func:`decision_fields` reads it), its inliers among the
    pool and the proposals judged (in order; what ``given`` takes).
    """
    record = np.zeros(RECORD_SIZE)
    record[_CODES:_CURVED] = -1.0
    record[_CURVED:] = np.nan
    best_mask = np.zeros(pool.shape[0], np.bool_)
    size = pool.shape[0]
    local = seeds.shape[0] > 0
    if size < max(min_points, 6) or (local and size < 2 * min_points):
        return False, record, best_mask, np.zeros((0, 0), np.bool_)
    step = -(-size // max_points)
    m = -(-size // step)
    pts = np.empty((m, 3))
    for i in range(m):
        pts[i] = xyz[pool[i * step]]
    limit = LOCAL_JUDGED if local else 2
    if given.shape[0] > 0:
        proposals = given
    elif local:
        proposals = _distinct(local_proposals(pts, sigma, rounds, seeds, max(m // seeds.shape[0], 6)))
    else:
        keep = max(int(keep_fraction * m), 6)
        trials = 64 if size < many_points else 256
        plane_near, quad_near = trimmed_proposals(pts, sigma, rounds, min(keep, m), trials, 0)
        # the proposal near more points first (the plane's on a tie)
        proposals = np.empty((2, m), np.bool_)
        first_quad = quad_near.sum() > plane_near.sum()
        proposals[0] = quad_near if first_quad else plane_near
        proposals[1] = plane_near if first_quad else quad_near
    found, best_noise, best_count, judged = False, False, -1, 0
    previous = -1  # the proposal judged last
    row = np.zeros(PARAM_SLOTS)
    for turn in range(proposals.shape[0]):
        near = proposals[turn]
        count = near.sum()
        if count * step < min_points:
            continue
        if judged >= limit:
            break
        judged += 1
        # the same points again (a pool both proposals cover alike): the same decision, no
        # better than itself
        if previous >= 0 and same_mask(near, proposals[previous]):
            continue
        previous = turn
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
                record[0], record[1], record[2], record[3] = PLANE, ACCEPTED, NONE, p_inliers
                record[4], record[5], record[6] = p_scale, p_d, rms
                record[_CENTROID:_NORMAL] = p_centroid
                record[_NORMAL:_CODES] = p_normal
            else:
                _pack(decision, record)
            if at_noise and n_noise >= enough * size:
                break
        if local and best_noise:  # the local starts take the first answer at the noise
            break
    if local and not best_noise:  # and only an answer at the noise
        found = False
    return found, record, best_mask, proposals


#: Distinct local proposals the fitter judges at most (``trimmed_fit``'s ``_LOCAL_JUDGED``).
LOCAL_JUDGED = 4


@njit(cache=True, nogil=True)
def _distinct(masks):
    """The rows of ``masks``, largest first (a stable order), without empty ones and those
    mostly covered by a larger one kept (``fitting.robust.distinct_masks``)."""
    k = masks.shape[0]
    counts = np.empty(k, np.int64)
    for s in range(k):
        counts[s] = masks[s].sum()
    order = np.argsort(-counts, kind="mergesort")
    kept = np.empty(k, np.int64)
    n_kept = 0
    for s in order:
        count = counts[s]
        if count == 0:
            continue
        distinct = True
        for t in range(n_kept):
            if np.count_nonzero(masks[s] & masks[kept[t]]) >= 0.8 * count:
                distinct = False
                break
        if distinct:
            kept[n_kept] = s
            n_kept += 1
    out = np.empty((n_kept, masks.shape[1]), np.bool_)
    for t in range(n_kept):
        out[t] = masks[kept[t]]
    return out
