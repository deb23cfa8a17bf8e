"""The plane -> cylinder -> sphere decision of the paper's Fig. 2, guarded against false fittings.

Rule (:func:`fit_primitive`):

1. Fewer than ``min_points`` points, NaN/inf, or collinear points: FitFailure.
2. Fit a plane. If its rms is within ``plane_rms`` and the patch shows no significant
   curvature (a quadratic height field over the plane does not lower the rms by
   ``curvature_gain``, with one standard error of that estimate from N points,
   ``1 / sqrt(N)``, to spare where the plane's rms is within the noise model:
   :func:`rangeseg_o3d.kernels.linalg.flat_by_quadric`), it is a plane.
3. Otherwise fit a cylinder and a sphere. A curved model is acceptable when its rms is
   within its threshold, its radius is at most ``max_radius``, the points cover an arc
   (cylinder cross-section) or cap (sphere) of at least ``min_arc_deg`` -- which bounds
   the radius relative to the patch extent -- and it lowers the plane's rms by at least
   ``curvature_gain``. The principal curvatures of the quadric (step 2) say which
   model to try first: ratio <= 0.35 cylinder, >= 0.65 sphere; if that one is
   acceptable it is kept without trying the other (saves the slow fit of the wrong
   model). Otherwise, or for ratios in between, both are tried and of the acceptable
   ones the lower rms wins. A plane that passed step 2 only by a margin over the
   sensor's noise is no better explained than a curved model within the noise: over
   ``noise_floor`` but within its chi-square spread, or beyond that spread but within a
   ``plane_rms`` set above the noise (1 cm over a 5 mm laser's column piece), the
   curved models are tried too and need only to beat the plane (no ``curvature_gain``);
   in the second case they must also stay within the noise's bound and resolve their
   curvature (an F-test of the drop in squared distances: not the bend of two more
   parameters over noise).
4. No acceptable curved model: the plane if it passed step 2's rms test, else a
   FitFailure listing why each model was refused.

Thresholds are rms distances in metres. The defaults suit the nodding SICK LMS200
(range noise sigma about 5 mm, independent of range): ``plane_rms = 0.01`` is twice the
noise. Sensors whose noise grows with range (RGB-D: sigma about 1.4e-3 z^2 m, CAPE's
model with z in m) add ``rms_per_range2 * R^2`` to every threshold, R being the
distance of the patch centroid from the sensor origin. In a pipeline that term is the
sensor's: ``rms_per_range2 = range_growth * sensor.noise.sigma_quadratic``
(:func:`bind_sensor`, the plugin's configuration holds ``range_growth``), and no threshold
is under the sensor's constant noise ``sigma0`` (a 2 cm laser's planes are not refused for
the 1 cm that suits a 5 mm one).
"""

from __future__ import annotations

import inspect

import numpy as np
from pydantic import ConfigDict, Field

from .. import kernels  # the package: its names load on first use (no compiler at import)
from ..kernels.kinds import CYLINDER, PLANE, SPHERE, ModelKind
from ..registry import Plugin, StrictParams, defaults_of, params_model
from . import _decide  # numba is loaded already (kernels.linalg below): one import, not one a fit
from ._codes import ACCEPTED, COLLINEAR, MIN_POINTS, NON_FINITE
from ._common import Prepared, as_points, decision_reason, input_failure
from .cylinder import _search_grids, axis_from_normals, cylinder_model
from .primitives import Cylinder, FitFailure, Plane, Sphere
from .plane import UNDETERMINED, plane_from_prepared
from ..kernels.linalg import plane_tolerance
from .sphere import sphere_model

__all__ = ["fit_primitive", "refit_primitive", "model_of_decision", "trimmed_primitive", "trimmed_plane",
           "fit_planes_batch", "plane_threshold", "refit_planes_from_moments",
           "PrimitiveFitterConfig", "PLUGIN", "quadric_shape", "bind_sensor"]

INLIER_FACTOR = 3.0
"""Points within INLIER_FACTOR x the kind's rms threshold count as inliers."""

ROUNDNESS_CYLINDER = 0.35
ROUNDNESS_SPHERE = 0.65
"""Principal-curvature ratios below/above which the patch is taken for a cylinder/sphere first."""

MAX_ITERATIONS = 60
"""Levenberg-Marquardt iterations of the sphere and cylinder fits (a short pipe seen end-on
with its cap, at stereo noise, crawls along its axis for 30-60 before it converges; 30
refused it and its region became a plane: a false fitting)."""


def quadric_shape(points: np.ndarray, plane: Plane) -> tuple[float, float]:
    """Fit a quadratic height field over ``plane``: ``(gain, roundness)``.

    ``gain`` is how much the quadric lowers the rms (plane rms / quadric rms): about 1
    for a flat patch whatever its noise, clearly above 1 for a curved one, inf when the
    quadric is exact but the plane is not. ``roundness`` is the ratio of the smaller to
    the larger principal curvature magnitude: near 0 for a cylinder, near 1 for a sphere.
    """
    pts = np.asarray(points, float)
    centred = pts - pts.mean(axis=0)
    # in-plane coordinates: any orthonormal pair perpendicular to the normal
    helper = np.eye(3)[int(np.argmin(np.abs(plane.normal)))]
    e1 = np.cross(plane.normal, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(plane.normal, e1)
    return _height_field_shape(centred, plane.normal, e1, e2)


def _height_field_shape(centred, normal, e1, e2) -> tuple[float, float]:
    from ..kernels import height_field_shape

    gain, roundness = height_field_shape(np.ascontiguousarray(centred), np.ascontiguousarray(normal),
                                         np.ascontiguousarray(e1), np.ascontiguousarray(e2))
    return float(gain), float(roundness)


def _checked_points(points, kind: str, min_points: int):
    """``(points as a C-ordered (N, 3) float array, FitFailure for too few or None)``.

    Non-finite points are the compiled fits' to find (they pass over the points anyway);
    :func:`_non_finite` words their answer.
    """
    pts = np.ascontiguousarray(as_points(points))
    return pts, input_failure(kind, len(pts), 0, max(int(min_points), 3))


def _non_finite(pts: np.ndarray, kind: str) -> FitFailure:
    n_bad = len(pts) - int(np.count_nonzero(np.isfinite(pts).all(axis=1)))
    return input_failure(kind, len(pts), n_bad, 3)


#: The least arc (degrees) a cylinder's cross-section or a sphere's cap must span: the
#: fitter's ``min_arc_deg`` default, which the steps that judge a cylinder outside the fitter
#: default to as well (the pipeline passes the fitter's own value).
MIN_ARC_DEG = 30.0


def fit_primitive(
    points,
    normals=None,
    *,
    plane_rms: float = 0.01,
    cylinder_rms: float = 0.01,
    sphere_rms: float = 0.01,
    rms_per_range2: float = 0.0,
    min_points: int = 10,
    max_radius: float = 5.0,
    min_arc_deg: float = MIN_ARC_DEG,
    curvature_gain: float = 1.5,
    noise_floor: float = 0.0,
    resolve_bends: float = 0.0,
) -> Plane | Cylinder | Sphere | FitFailure:
    """Explain a region's points by a plane, a cylinder or a sphere (paper Fig. 2).

    See the module docstring for the decision rule.

    Parameters
    ----------
    points : (N, 3) array_like
        The region's points, metres.
    normals : (N, 3) array_like, optional
        Surface normals, used to start the cylinder fit.
    plane_rms, cylinder_rms, sphere_rms : float
        Largest acceptable rms orthogonal distance (m) of each model.
    rms_per_range2 : float
        Added to each threshold times the squared range (m) of the patch centroid, for
        sensors whose noise grows with range; 0 for a laser scanner.
    min_points : int
        Smaller regions are not fitted.
    max_radius : float
        Largest acceptable cylinder or sphere radius (m).
    min_arc_deg : float
        Smallest arc (cylinder cross-section) or cap angle (sphere) the points must
        cover, degrees: a curved model of a nearly flat patch subtends a tiny arc.
    curvature_gain : float
        Factor by which a curved model must lower the plane's rms (>= 1).
    noise_floor : float
        The sensor's constant range noise (m; 0: none): the plane threshold is at least
        what this noise alone gives a plane fitted to the points, up its chi-square
        (:func:`rangeseg_o3d.kernels.linalg.plane_tolerance`).
    resolve_bends : float
        0 (or False): not asked. Else the independent samples each point carries (True: 1,
        independent residuals; points whose noise errs together carry less,
        :meth:`rangeseg_o3d.sensor.NoiseModel.independent_share`): a plane within the noise
        whose quadric resolves a bend over those samples all the same
        (:func:`rangeseg_o3d.kernels.linalg.quadric_resolved`, an F-test) is not settled at
        step 2: a curved model that beats it and resolves its own curvature over them
        replaces it. For a region's final pixels (the refinement's last decision of its
        planes), where a pipe seen on a narrow arc bends by less than the noise over
        hundreds of points.

    Returns
    -------
    Plane, Cylinder, Sphere or FitFailure
        The model, its ``inliers`` counted within 3x its kind's threshold; or a falsy
        FitFailure(kind="primitive") whose reason lists why each model was refused.
    """
    pts, failure = _checked_points(points, "primitive", min_points)
    if failure is not None:
        return failure
    hint = np.full(3, np.nan)
    if normals is not None:
        normals = as_points(normals, "normals")
        if normals.shape != pts.shape:
            raise ValueError(f"normals must have the shape of points {pts.shape}; got {normals.shape}")
        axis = axis_from_normals(normals)
        if axis is not None:
            hint = np.ascontiguousarray(axis)
    min_arc = np.radians(min_arc_deg)
    decision = _decide.decide(
        pts, hint, *_search_grids(), float(plane_rms), float(cylinder_rms), float(sphere_rms),
        float(rms_per_range2), float(max_radius), float(min_arc), float(curvature_gain), INLIER_FACTOR,
        ROUNDNESS_CYLINDER, ROUNDNESS_SPHERE, MAX_ITERATIONS, float(noise_floor), float(resolve_bends))
    if decision.status == NON_FINITE:
        return _non_finite(pts, "primitive")
    if decision.status == COLLINEAR:
        return FitFailure("primitive", f"plane: {UNDETERMINED}")
    if decision.kind in (PLANE, CYLINDER, SPHERE):
        return model_of_decision(decision)
    # every threshold grows by the same amount with range
    extra = rms_per_range2 * float(decision.centroid @ decision.centroid)
    reasons = [f"plane rms {decision.plane_rms:.3g} > {decision.plane_tolerance:.3g}"]
    for kind in (decision.first, decision.other_curved()):
        if decision.codes[kind] >= 0:
            tolerance = (cylinder_rms if kind == CYLINDER else sphere_rms) + extra
            reasons.append(decision_reason(
                ModelKind(kind).label, int(decision.codes[kind]), decision.curved[kind], scale=decision.scale,
                eigen_rms=decision.eigen_rms, plane_rms=decision.plane_rms, n=len(pts), minimum=MIN_POINTS[kind],
                max_iterations=MAX_ITERATIONS, tolerance=tolerance, max_radius=max_radius, min_arc=min_arc,
                curvature_gain=curvature_gain))
    return FitFailure("primitive", "; ".join(reasons))


def model_of_decision(decision) -> Plane | Cylinder | Sphere:
    """The model of an accepted decision (:class:`rangeseg_o3d.fitting._decide.Decision` of
    kind PLANE, CYLINDER or SPHERE), as :func:`fit_primitive` returns it."""
    if decision.kind == PLANE:
        return Plane(normal=decision.normal, d=decision.d, rms=decision.plane_rms,
                     inliers=int(decision.plane_inliers))
    if decision.kind == CYLINDER:
        return cylinder_model(decision.curved[CYLINDER], decision.centroid, decision.scale)
    return sphere_model(decision.curved[SPHERE], decision.centroid, decision.scale)


def trimmed_primitive(xyz, pool, *, sigma: float, min_inliers: int, max_rms: float, fit_max_points: int,
                      planes_only: bool = False, starts: bool = False, proposals: dict | None = None, **params):
    """:func:`rangeseg_o3d.fitting.robust.trimmed_fit` of the points ``xyz[pool]`` judged by
    :func:`fit_primitive` with the keywords ``params`` on at most ``fit_max_points`` points (as a
    :class:`rangeseg_o3d.fitting.region_fitter.RegionFitter` judges), refusing models with an
    rms over ``max_rms``, in one compiled call (:mod:`._trimmed`): the same ``(model, inliers)``
    (``min_inliers`` is ``trimmed_fit``'s ``min_points``). With ``planes_only`` the judge is
    :func:`rangeseg_o3d.fitting.plane.fit_plane` on all the points instead (``params`` unused).
    With ``starts``, ``trimmed_fit(..., starts=True)``: the proposals grown from local starts.
    ``proposals``: a memo of the searches' proposals, which depend on the pool, ``sigma`` and
    ``starts`` only (not on the judge), kept by a caller that searches the same pools of the
    same ``xyz`` with several judges (the facets step); a search of a pool it holds judges
    them without computing them again (the same answer).

    ``xyz`` a C-ordered float64 (N, 3) array, ``pool`` int64 indices into it.
    """
    trimmed_decision, Decision, decision_fields = _compiled_search()
    search, judge = _trimmed_arguments(bool(planes_only), tuple(params.items()))
    seeds = _local_seeds(len(pool)) if starts else _NO_SEEDS
    key = None if proposals is None else (pool.tobytes(), float(sigma), bool(starts))
    given = _NO_PROPOSALS if key is None else proposals.get(key, _NO_PROPOSALS)
    found, record, inliers, judged = trimmed_decision(
        xyz, pool, float(sigma), int(min_inliers), *search, int(fit_max_points), judge[0], float(max_rms),
        *judge[1:], seeds, given)
    if key is not None:
        proposals[key] = judged
    if not found:
        return None, None
    return model_of_decision(Decision._make(decision_fields(record))), inliers


_COMPILED_SEARCH: tuple = ()


def _compiled_search() -> tuple:
    """``(trimmed_decision, Decision, decision_fields)``, imported on the first search (numba loads then) and
    kept: a from-import in each call costs a few microseconds, and the refinement of a
    cluttered frame searches dozens of times."""
    global _COMPILED_SEARCH
    if not _COMPILED_SEARCH:
        from ._decide import Decision
        from ._trimmed import decision_fields, trimmed_decision

        _COMPILED_SEARCH = (trimmed_decision, Decision, decision_fields)
    return _COMPILED_SEARCH


#: The constant arguments of the compiled trimmed search, per judge (planes only or not) and
#: fitter keywords: built once, not per call (a split runs dozens of searches per frame).
_TRIMMED_ARGUMENTS: dict = {}


def _trimmed_arguments(planes_only: bool, params: tuple) -> tuple[tuple, tuple]:
    """``(search, judge)``: the search's arguments after ``min_points`` up to ``planes_only``,
    and the judge's, ``fit_min_points`` first, then those after ``max_rms`` (the decision's)."""
    key = (planes_only, params)
    try:
        known = _TRIMMED_ARGUMENTS.get(key)
    except TypeError:  # a keyword value that cannot be hashed: built for this call only
        key, known = None, None
    if known is not None:
        return known
    from .robust import CHI_SQUARE_SIGMAS, ROUNDS, KEEP_FRACTION, MAX_POINTS, ENOUGH, MANY_POINTS

    p = {**_PRIMITIVE_DEFAULTS, **dict(params)}
    search = (ROUNDS, KEEP_FRACTION, MAX_POINTS, ENOUGH, MANY_POINTS, CHI_SQUARE_SIGMAS, planes_only)
    judge = (3 if planes_only else int(p["min_points"]), _NO_HINT, *_search_grids(),
             float(p["plane_rms"]), float(p["cylinder_rms"]), float(p["sphere_rms"]), float(p["rms_per_range2"]),
             float(p["max_radius"]), float(np.radians(p["min_arc_deg"])), float(p["curvature_gain"]), INLIER_FACTOR,
             ROUNDNESS_CYLINDER, ROUNDNESS_SPHERE, MAX_ITERATIONS, float(p["noise_floor"]))
    if key is not None:
        if len(_TRIMMED_ARGUMENTS) >= 64:  # fitters come and go (tests): keep the table small
            _TRIMMED_ARGUMENTS.clear()
        _TRIMMED_ARGUMENTS[key] = search, judge
    return search, judge


def _local_seeds(size: int) -> np.ndarray:
    # robust.local_seeds of a pool of ``size`` (lazily imported: robust is not needed before)
    from .robust import MAX_POINTS, local_seeds

    return local_seeds(size, MAX_POINTS)


def trimmed_plane(points: np.ndarray, pool: np.ndarray, *, sigma: float, min_points: int,
                  max_rms: float = np.inf, starts: bool = False, proposals: dict | None = None):
    """``trimmed_fit(points, judge, pool=pool, starts=starts, ...)`` with ``judge`` the
    least-squares plane (:func:`rangeseg_o3d.fitting.plane.fit_plane`) refused over
    ``max_rms``, in one compiled call (:func:`trimmed_primitive`, ``proposals`` its memo):
    the same ``(model, inliers)``."""
    from .robust import pool_points

    xyz, indices = pool_points(points, pool)
    if not np.may_share_memory(xyz, points):  # the pool's points gathered: indices name no pool of points
        proposals = None
    return trimmed_primitive(xyz, indices, sigma=sigma, min_inliers=min_points, max_rms=max_rms,
                             fit_max_points=max(len(indices), 1), planes_only=True, starts=starts,
                             proposals=proposals)


_NO_HINT = np.full(3, np.nan)  # no cylinder axis hint (read only by the compiled code)
_NO_SEEDS = np.zeros(0, np.int64)  # the global search (no local starts)
_NO_PROPOSALS = np.zeros((0, 0), np.bool_)  # proposals not known: the search computes them
_PRIMITIVE_DEFAULTS = {name: parameter.default for name, parameter in
                       inspect.signature(fit_primitive).parameters.items()
                       if parameter.kind == inspect.Parameter.KEYWORD_ONLY}


@defaults_of(fit_primitive)
def refit_primitive(
    points,
    model: Plane | Cylinder | Sphere,
    normals=None,
    *,
    plane_rms: float,
    cylinder_rms: float,
    sphere_rms: float,
    rms_per_range2: float,
    min_points: int,
    max_radius: float,
    min_arc_deg: float,
    curvature_gain: float,
    noise_floor: float,
) -> Plane | Cylinder | Sphere | FitFailure:
    """Fit ``points`` with a model of ``model``'s kind, judged as :func:`fit_primitive` would.

    For regions that grew or merged: no plane/cylinder/sphere decision again; a sphere or
    cylinder is refined from ``model``'s parameters (no search, no algebraic start).
    ``normals`` are accepted for the fitter contract and not needed. A refit that breaks the kind's
    thresholds (rms, radius, arc, curvature gain) is a FitFailure with the reason.
    """
    if not isinstance(model, (Plane, Cylinder, Sphere)):
        raise TypeError(f"model must be a Plane, Cylinder or Sphere; got {type(model).__name__}")
    pts, failure = _checked_points(points, model.kind, min_points)
    if failure is not None:
        return failure
    if isinstance(model, Plane):
        base = Prepared(pts, "plane", 3, None)
        if base.n_bad:  # counted by the preparation already
            return input_failure(model.kind, len(pts), base.n_bad, 3)
        plane_tol = plane_threshold(len(pts), base.centroid, plane_rms=plane_rms, noise_floor=noise_floor,
                                    rms_per_range2=rms_per_range2)
        plane = plane_from_prepared(base.specialise("plane", 3, INLIER_FACTOR * plane_tol))
        if not plane:
            return FitFailure(model.kind, f"plane: {plane.reason}")
        if plane.rms > plane_tol:
            return FitFailure("plane", f"plane rms {plane.rms:.3g} > {plane_tol:.3g}")
        return plane
    # Levenberg-Marquardt from the model itself: a region that grew or merged is the same
    # surface, so no search or algebraic start is needed.
    kind = CYLINDER if isinstance(model, Cylinder) else SPHERE
    start = (np.concatenate([model.axis, model.point, [model.radius]]) if kind == CYLINDER
             else np.concatenate([model.center, [model.radius], np.zeros(3)]))
    min_arc = np.radians(min_arc_deg)
    code, centroid, scale, result, tolerance, eigen_rms = _decide.curved_refit(
        kind, pts, start, float(cylinder_rms if kind == CYLINDER else sphere_rms), float(rms_per_range2),
        float(max_radius), float(min_arc), float(curvature_gain), INLIER_FACTOR, MAX_ITERATIONS)
    if code == ACCEPTED:
        return cylinder_model(result, centroid, scale) if kind == CYLINDER else sphere_model(result, centroid, scale)
    if code == NON_FINITE:
        return _non_finite(pts, model.kind)
    return FitFailure(model.kind, decision_reason(
        model.kind, int(code), result, scale=scale, eigen_rms=eigen_rms, plane_rms=eigen_rms, n=len(pts),
        minimum=MIN_POINTS[kind], max_iterations=MAX_ITERATIONS, tolerance=tolerance, max_radius=max_radius,
        min_arc=min_arc, curvature_gain=curvature_gain))


def plane_threshold(n: int, centroid: np.ndarray, *, plane_rms: float, noise_floor: float,
                    rms_per_range2: float) -> float:
    """The plane rms threshold of :func:`fit_primitive` for ``n`` points whose centroid is
    ``centroid``: :func:`rangeseg_o3d.kernels.linalg.plane_tolerance` plus
    ``rms_per_range2 R^2`` at the centroid's range."""
    return (plane_tolerance(float(plane_rms), float(noise_floor), float(n))
            + float(rms_per_range2) * float(centroid @ centroid))


@defaults_of(fit_primitive)
def fit_planes_batch(
    xyz,
    labels,
    *,
    plane_rms: float,
    rms_per_range2: float,
    min_points: int,
    curvature_gain: float,
    noise_floor: float,
    resolve_bends: float = 0.0,
    **_curved,
) -> dict[int, Plane]:
    """Every region of a label image that :func:`fit_primitive` would call a plane, at once.

    One pass over the pixels gives each label's moments, hence its plane; the regions
    whose plane passes step 2 of the decision rule (rms within ``plane_rms`` or the
    ``noise_floor`` bound, plus ``rms_per_range2 R^2``, and no significant curvature by
    the batched quadric test) are returned. The others (curved, too few or collinear
    points) are left to :func:`fit_primitive`; with ``resolve_bends`` (as
    :func:`fit_primitive`'s) also a plane within the noise whose quadric resolves a bend
    over its samples, and one beyond what the noise gives its points (the decision's
    marginal plane, which it tries the curved models against).
    Keywords for the curved models are accepted and ignored.

    Parameters
    ----------
    xyz : (N, 3) points (NaN rows are skipped).
    labels : (N,) int labels, 0 = in no region.

    Returns
    -------
    {label: Plane}, each Plane's ``inliers`` counted within 3x its threshold.
    """
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    labels = np.ascontiguousarray(labels, dtype=np.int32)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or labels.shape != (len(xyz),):
        raise ValueError(f"xyz must be (N, 3) and labels (N,); got {xyz.shape} and {labels.shape}")
    n = int(labels.max(initial=0)) + 1
    settled, normal, d, rms, inliers = kernels.settle_planes(
        xyz, labels, n, float(plane_rms), float(rms_per_range2), int(min_points), float(curvature_gain),
        INLIER_FACTOR, float(noise_floor), float(resolve_bends))
    normal.setflags(write=False)  # rows pass into the Planes as they are, without a copy each
    d, rms, inliers = d.tolist(), rms.tolist(), inliers.tolist()
    return {k: Plane(normal=normal[k], d=d[k], rms=rms[k], inliers=inliers[k])
            for k in np.flatnonzero(settled).tolist()}


@defaults_of(fit_primitive)
def refit_planes_from_moments(
    moments,
    models,
    *,
    plane_rms: float,
    rms_per_range2: float,
    min_points: int,
    noise_floor: float,
    **_curved,
) -> list:
    """:func:`refit_primitive` for the planes among ``models``, from label-wise moments.

    Row ``i`` of ``moments`` (see :func:`rangeseg_o3d.fitting.batch_planes.region_moments`) holds
    the points of ``models[i]``'s region (e.g. two merged regions: the sum of their rows).
    Returns per row a Plane, a FitFailure (too few or collinear points, rms over the
    threshold), or None where the model is not a plane (it needs its points). A Plane's
    ``inliers`` is its number of points: moments carry no distances.
    """
    moments = np.atleast_2d(np.asarray(moments, dtype=np.float64))
    if len(moments) != len(models):
        raise ValueError(f"need one moments row per model; got {len(moments)} rows and {len(models)} models")
    if not any(isinstance(model, Plane) for model in models):
        return [None] * len(models)
    if moments.ndim != 2 or moments.shape[1] != 10:
        raise ValueError(f"moments must have shape (K, 10); got {moments.shape}")
    # the planes and their thresholds in one compiled call (the numpy form of the
    # thresholds cost more than the planes)
    normal, d, rms, tol, ok = kernels.plane_refit_rows(np.ascontiguousarray(moments), float(plane_rms),
                                                       float(noise_floor), float(rms_per_range2))
    minimum = max(int(min_points), 3)
    # Python scalars and read-only normal rows: per row, numpy scalars cost more than the test
    count, ok, rms, d, tol = moments[:, 0].tolist(), ok.tolist(), rms.tolist(), d.tolist(), tol.tolist()
    normal.setflags(write=False)
    out = []
    for i, model in enumerate(models):
        if not isinstance(model, Plane):
            out.append(None)
        elif count[i] < minimum:
            out.append(FitFailure("plane", f"a plane fit needs at least {minimum} points; got {int(count[i])}"))
        elif not ok[i]:
            out.append(FitFailure("plane", UNDETERMINED))
        elif rms[i] > tol[i]:
            out.append(FitFailure("plane", f"plane rms {rms[i]:.3g} > {tol[i]:.3g}"))
        else:
            out.append(Plane(normal=normal[i], d=d[i], rms=rms[i], inliers=int(count[i])))
    return out


class _FitterParams(StrictParams):
    model_config = ConfigDict(allow_inf_nan=False)


PrimitiveFitterConfig = params_model(fit_primitive, dict(
    plane_rms=dict(gt=0, description="largest plane rms, m"),
    cylinder_rms=dict(gt=0, description="largest cylinder rms, m"),
    sphere_rms=dict(gt=0, description="largest sphere rms, m"),
    range_growth=(float, Field(
        1.0, ge=0, description="thresholds grow by this times the sensor's sigma_quadratic r^2")),
    min_points=dict(ge=3, description="smallest region fitted"),
    max_radius=dict(gt=0, description="largest cylinder/sphere radius, m"),
    min_arc_deg=dict(gt=0, le=360, description="smallest arc/cap covered, deg"),
    curvature_gain=dict(ge=1, description="rms reduction a curved model must bring"),
), name="PrimitiveFitterConfig", base=_FitterParams,
    doc="""Parameters of the "primitives" fitter: :func:`fit_primitive`'s keywords (and their
    defaults), with ``range_growth`` in place of ``rms_per_range2`` (see :func:`bind_sensor`).""")


# No curved model's rms threshold is under this many times the sensor's constant noise
# term: a noisier sensor's surfaces are not refused for the noise itself. One sigma, not the
# defaults' two (1 cm for the LMS200's 5 mm): at two, a 3 cm spinning lidar's thresholds of
# 6 cm took cylinders for planes (8 false fittings on the matrix's 4 scans, 0 at one sigma).
RMS_NOISE_FACTOR = 1.0


def bind_sensor(params: dict, sensor) -> dict:
    """:func:`fit_primitive`'s keywords for ``sensor``: a plane's rms threshold is at least
    what the sensor's constant noise ``sigma0`` gives a plane of as many points, up its
    chi-square (``noise_floor``; at one flat sigma a wall seen head-on, whose rms is the
    noise itself within 2 %, was refused half of the time), a curved model's at least
    ``RMS_NOISE_FACTOR`` times ``sigma0``, and the thresholds grow with range as
    ``range_growth`` times its quadratic noise term."""
    kwargs = dict(params)
    floor = RMS_NOISE_FACTOR * sensor.noise.sigma0
    for key in ("cylinder_rms", "sphere_rms"):
        kwargs[key] = max(kwargs[key], floor)
    kwargs["noise_floor"] = float(sensor.noise.sigma0)
    kwargs["rms_per_range2"] = kwargs.pop("range_growth") * sensor.noise.sigma_quadratic
    return kwargs


PLUGIN = Plugin(
    name="primitives",
    config=PrimitiveFitterConfig,
    run=fit_primitive,
    description="plane, else cylinder or sphere (paper Fig. 2), with false-fitting guards",
    refit=refit_primitive,
    fit_batch=fit_planes_batch,
    refit_moments=refit_planes_from_moments,
    bind_sensor=bind_sensor,
    trimmed=trimmed_primitive,
)
