"""Pairs of regions that are one pipe or ball, joined under its cylinder or sphere: two plane
regions, or a plane region beside a curved one.

A depth camera whose noise errs together over a matching window sees a pipe 0.13-0.26 m
in radius at 2.4-5.4 m as two strips whose planes each explain their pixels within the noise:
the tile grid gave one strip a plane region and the pixels its model left were recovered
as a second plane beside it (kinect_real_640x480 study seeds 1117 scan 0, 1120 scan 5,
1125 scan 4; a ball of 0.43 m radius at 4.9 m, seed 1114 scan 0; a stereo camera's pipe at
2.8 m, seed 1102 scan 1). Each strip alone is flat within the noise, so no step that asks
one region sees the bend; the two together do.

The fitter's model of the union (its own order: a plane, else a cylinder, else a sphere)
decides the kind. When it is curved, the misfit pattern across the union's best crease line
(:func:`~rangeseg_o3d.plane_faces.crease_line`, the chi-square over
:data:`~rangeseg_o3d.plane_faces.PATTERN_BINS` equal-count bins of the mean residuals
along the rays, counted over the independent returns) tells a bend from a crease: over two
faces of a box the curved model misses the crease and the far edges along whole bands
(patterns of 60 to 10^6 on the study pairs of different surfaces, in chi-square units
of 16 bins), over one pipe it leaves the noise's pattern (1.2-24). A small box far away
hides its crease in the noise as well (two faces 0.3 m wide at 5.5 m: patterns 6.6-20), but
its two planes leave a pattern ten times smaller still (9.4-10.1 times), where a pipe's two
strips leave one as large as the curved model's or larger (the curved model's 0.13-3.1 times
theirs on the study pipes and balls; 7.5 and more on the study pairs of different surfaces).

The pair joins when the curved model's pattern lies within the chi-square bound of the bins
at :data:`~rangeseg_o3d.kernels.linalg.CHI_SQUARE_SIGMAS` (:data:`PATTERN_BOUND`), within
:data:`JOIN_RATIO` times the two planes' (the F-test of the two patterns, as
:func:`~rangeseg_o3d.plane_faces.faces_of_curved` asks the other way, at three deviations),
and it holds :data:`~rangeseg_o3d.plane_faces.PLANES_COVER` of the union's pixels within
:data:`~rangeseg_o3d.refinement.context.TRIM_SIGMAS` noise sigmas.

The fitter places its model by the points' distances. Where the noise lies along the rays
and is several times a pipe's width there (a stereo camera's, 6-8 cm at 4-5 m), that model
may miss the pipe, or be no model at all: the union's plane in ``xyz`` turns towards the rays
and explains it within the noise. So a cylinder that holds the pixels but leaves a pattern is
placed again by the residuals along the rays
(:func:`~rangeseg_o3d.bent_planes.cylinder_along_rays`), and a union the fitter calls a plane
is asked the bend test a single plane region is asked
(:func:`~rangeseg_o3d.bent_planes.bent_pipe`); either model then meets the same pattern test.

A plane strip can also be left beside the pipe's or ball's own curved region (an end cap
cut off the side of a ball the fitter called a cylinder; the recovery's plane beside the
tile grid's cylinder): the curved region's model, refitted to both, meets the same test.
So do two curved regions of one pipe: the crease search cuts a pipe in two plane faces and
the bend test turns each into a cylinder of its own radius (kinect_real study seed 1376
scan 2: a pipe of r 0.20 m at 2.7-3.3 m as cylinders of r 0.117 and 0.177 m). Each was
judged curved on its own, so the larger's model refitted to both is asked without the
fitter's curvature gain over the union's plane (there: cylinder rms 0.0079 m against the
plane's 0.0098, under the gain of 1.5); the pattern test decides.
"""

from __future__ import annotations

import numpy as np
from scipy.special import fdtri, ndtr

from .bent_planes import TEST_POINTS, bent_pipe, cylinder_along_rays
from .fitting.primitives import Cylinder, Plane, Sphere
from .fitting.region_fitter import region_indices
from .fullres import region_stats
from .kernels.linalg import CHI_SQUARE_SIGMAS
from .plane_faces import PATTERN_BINS, PLANES_COVER, misfit_patterns, share_near_curved
from .refinement.context import Context, touching

__all__ = ["JOIN_RATIO", "PATTERN_BOUND", "curved_from_plane_pairs"]

#: The largest misfit pattern (chi-square over PATTERN_BINS bins, in units of the
#: independent returns) the noise alone leaves, CHI_SQUARE_SIGMAS deviations up its law.
PATTERN_BOUND = PATTERN_BINS * (1.0 + CHI_SQUARE_SIGMAS * float(np.sqrt(2.0 / PATTERN_BINS)))
#: The most the curved model's misfit pattern may exceed the two planes' across the same
#: line: the F distribution's quantile of PATTERN_BINS and PATTERN_BINS degrees of freedom
#: at the tail of three normal deviations (4.94).
JOIN_RATIO = float(fdtri(PATTERN_BINS, PATTERN_BINS, ndtr(3.0)))


def curved_from_plane_pairs(cloud, labels: np.ndarray, fits: dict, stats, *, sigma: np.ndarray, fitter,
                            min_size: int, inlier_factor: float, correlation_px: int = 1,
                            wrap_columns: bool = False, share: float = 1.0, stepped: bool = False):
    """Touching plane regions of ``min_size`` pixels or more each whose union the fitter
    gives a cylinder or sphere that leaves no misfit pattern across its best crease line
    (see the module's docstring) become one region of that model, under the larger one's
    label; so does a plane region beside a cylinder or sphere region at least as large whose
    model, refitted to both, leaves none (the strip an end cap or the recovery cut off a
    pipe or ball), unless the plane lies across the cylinder's axis as its cap does and the
    union stays a cylinder (:func:`_cap_of`); and so do two touching cylinder or sphere
    regions whose larger one's model, refitted to both, leaves none. A union's cylinder
    gives way to its sphere when the sphere joins the pixels as well and fits them as
    closely (:func:`_sphere_when_simpler`).
    Each region joins at most one other, the pairs of least pattern first. Returns ``(labels,
    fits, stats)``, the regions changed measured again; the inputs when none joins.

    ``sigma``: each pixel's range noise (the grid's shape); ``correlation_px``: the side
    (px) of the box over which the returns err together (``NoiseModel.correlation_px``);
    ``share``: the independent returns each pixel carries (``NoiseModel.independent_share(1)``)
    and ``stepped``: the depth comes in steps (``NoiseModel.step_quadratic > 0``), for the
    bend test of a union the fitter gives a plane (:func:`rangeseg_o3d.bent_planes.bent_pipe`)."""
    if not 0.0 < share <= 1.0:
        raise ValueError(f"share: expected a number in (0, 1], got {share!r}")
    sigma = np.asarray(sigma, dtype=np.float64)
    if sigma.shape != labels.shape:
        raise ValueError(f"sigma: expected shape {labels.shape}, got {sigma.shape}")
    counts = stats.counts
    sized = [k for k, m in fits.items()
             if isinstance(m, (Plane, Cylinder, Sphere)) and 0 < k < counts.size and counts[k] >= min_size]
    planes = {k for k in sized if isinstance(fits[k], Plane)}
    if len(sized) < 2:
        return labels, fits, stats
    members = region_indices(labels, only=sized)
    ctx = Context(cloud, fitter, sigma, min_size, wrap_columns=wrap_columns,
                  correlation_px=max(int(correlation_px), 1))
    found, curved = [], set(sized) - planes
    bend = dict(shape=labels.shape, share=share, stepped=stepped)  # (the bend test of a union called a plane)
    asked_of = set(sized)
    for a in sorted(sized):
        for b in sorted(touching(labels, members[a], 1) & asked_of):
            asked = _asked(a, b, fits, counts, planes) if b > a else None
            if asked is None:
                continue
            one, other, model_of_other = asked
            pattern, model = _one_curved_surface(ctx, members[one], members[other], correlation_px, bend=bend,
                                                 curved=model_of_other, both_curved=one in curved)
            if model is None or (one in planes and other in curved and isinstance(model, Cylinder)
                                 and _cap_of(fits[one], fits[other])):
                continue
            found.append((pattern, a, b, model))
    if not found:
        return labels, fits, stats
    out = np.array(labels, dtype=np.int32, order="C")
    flat = out.reshape(-1)
    fits, used = dict(fits), set()
    for _, a, b, model in sorted(found, key=lambda item: item[0]):
        if a in used or b in used:
            continue
        keep, gone = (a, b) if members[a].size >= members[b].size else (b, a)
        flat[members[gone]] = keep
        fits[keep] = model
        fits.pop(gone)
        used |= {a, b}
    stats = region_stats(cloud.xyz, out, fits, sigma, inlier_factor, known=stats, stale=used)
    return out, fits, stats


def _one_curved_surface(ctx, one: np.ndarray, other: np.ndarray, correlation_px: int, bend: dict, curved=None,
                        both_curved: bool = False):
    """``(pattern, model)``: the fitter's cylinder or sphere of the flat pixels of two
    regions ``one`` and ``other`` (each increasing) and its misfit pattern across their best
    crease line, when that pattern is the noise's, within JOIN_RATIO times the two planes'
    across the line, and the model holds PLANES_COVER of them within TRIM_SIGMAS; ``(inf,
    None)`` otherwise. With ``curved`` (``other``'s cylinder or sphere), that model refitted
    to both is asked instead of the fitter's choice (kinect_real study seed 1353 scan 0: a
    pipe of r 0.21 m at 6.2-6.8 m as a cylinder region of 2590 px and a plane strip of 1006
    beside it; joined, 3596 of its 3766 px). Where the fitter gives the union a plane, the
    cylinder the bend of its pixels along the rays gives it is asked instead (``bend``: ``shape``, ``share`` and
    ``stepped`` of :func:`rangeseg_o3d.bent_planes.bent_pipe`): a pipe's two strips, each flat
    within the noise, may together be flat in ``xyz`` too, their plane turned towards the rays
    (stereo study seed 1341 scan 2: a pipe of r 0.115 m at 3.7-5.8 m in two strips of 2360 and
    2136 px, a plane to the fitter; the bend test's cylinder r 0.114 m). With ``both_curved``
    (``one`` is curved too), a refit the fitter refuses for want of its curvature gain over
    the union's plane is made again without it."""
    # the fitter's subsample gathered from the two regions without building their union (a
    # wall's union with each region it touches cost a stereo scan 1.5-4 s in numpy's union1d)
    points = ctx.fitter.points_of(ctx.xyz, (one, other))
    model = ctx.fitter.fit(points) if curved is None else ctx.fitter.refit(points, curved)
    if both_curved and not model:
        model = ctx.fitter.refit(points, curved, curvature_gain=1.0)
    by_distances = True  # (the fitter's; the bend test's cylinder is placed along the rays already)
    if isinstance(model, Plane):
        by_distances = False
        # (the test pixels drawn from each region: no sort of the union of a wall and a floor)
        count = one.size + other.size
        step = max(1, count // TEST_POINTS)
        params = ctx.fitter.params
        model = bent_pipe(ctx.xyz, ctx.sigma, np.sort(np.concatenate((one[::step], other[::step]))), count,
                          max_radius=float(params["max_radius"]), window=ctx.correlation_px,
                          min_arc_deg=float(params["min_arc_deg"]), **bend)
    if not isinstance(model, (Cylinder, Sphere)):
        return np.inf, None
    union = np.sort(np.concatenate((one, other)))
    if share_near_curved(ctx, model, union) < PLANES_COVER:
        return np.inf, None  # (as the patterns' test would say: no join, no refit along the rays)
    patterns = misfit_patterns(ctx, model, union, correlation_px)
    if patterns is None:
        return np.inf, None
    if by_distances and isinstance(model, Cylinder) and patterns[2][0] >= PLANES_COVER and not _joins(patterns):
        # the pixels lie on the fitter's cylinder, placed by their distances: the one placed by
        # their residuals along the rays, where the noise lies, is asked instead (its pattern
        # is the pipe's where the fitter's misses it by a band: cylinder_along_rays)
        along = cylinder_along_rays(model, ctx.xyz[union], ctx.sigma[union],
                                    max_radius=float(ctx.fitter.params["max_radius"]))
        if along is not None:
            model, patterns = along, misfit_patterns(ctx, along, union, correlation_px)
    if patterns is None or not _joins(patterns):
        return np.inf, None
    if isinstance(model, Cylinder):
        model, patterns = _sphere_when_simpler(ctx, union, model, patterns, correlation_px)
    return patterns[0], model


def _asked(a: int, b: int, fits: dict, counts: np.ndarray, planes: set):
    """How the touching regions ``a`` and ``b`` are asked (see
    :func:`curved_from_plane_pairs`): ``(one, other, model)``, the region whose model (None:
    the fitter's choice for the union) is refitted to both last, or None when the pair is not
    asked. Two planes: the fitter's model. A plane and a curved region: the curved one's,
    unless the plane is the larger (a wall beside a pipe: no model of the pipe's is the
    union's). Two curved regions: the larger's."""
    if a in planes and b in planes:
        return a, b, None
    if a in planes or b in planes:
        plane, curved = (a, b) if a in planes else (b, a)
        return None if counts[plane] > counts[curved] else (plane, curved, fits[curved])
    one, other = (a, b) if counts[a] < counts[b] else (b, a)
    return one, other, fits[other]


def _cap_of(plane, curved) -> bool:
    """Whether ``plane`` lies across the cylinder ``curved``'s axis, as its end cap does (its
    normal within 45 degrees of the axis), where a strip of the pipe's own surface holds the
    axis. A cap is a surface of its own beside a pipe, a few per cent of the union's pixels,
    whose misfit the pattern's equal-count bins dilute (stereo seed 1889 scan 0, held out until
    this was traced: a cap of 540 px at the end of a pipe's 17079 joined it); the side an end cap cut off a ball the
    fitter called a cylinder joins only under the union's sphere (:func:`_sphere_when_simpler`)."""
    if not isinstance(curved, Cylinder):
        return False
    return abs(float(np.dot(plane.normal, curved.axis))) >= _CAP_COSINE


#: The cosine of the angle within which a plane's normal lies along a cylinder's axis when
#: the plane is taken for its cap (:func:`_cap_of`): 45 degrees, halfway between a cap's 0 and
#: a strip's 90.
_CAP_COSINE = float(np.cos(np.radians(45.0)))


def _joins(patterns: tuple) -> bool:
    # the curved model's misfit pattern the noise's, within JOIN_RATIO times the two planes',
    # the model holding PLANES_COVER of the pixels within TRIM_SIGMAS
    curved, planes, inliers, _, _ = patterns
    return curved <= PATTERN_BOUND and curved <= JOIN_RATIO * planes and inliers[0] >= PLANES_COVER


def _sphere_when_simpler(ctx, union: np.ndarray, cylinder, patterns: tuple, correlation_px: int) -> tuple:
    """``(model, patterns)``: the sphere of the flat pixels ``union`` (the fitter's refit of
    their least-squares sphere) with its misfit patterns when it joins them too (:func:`_joins`)
    and leaves a mean squared residual along the rays (over the pixels within TRIM_SIGMAS of
    it) no larger than the ``cylinder``'s: one parameter fewer, the same fit. Else the cylinder
    with its ``patterns``. Under a stereo camera's noise the fitter may call a ball's pixels a
    cylinder, and a cylinder's end cap cut off the ball's side (stereo study seed 1370 scan 3:
    a ball of r 0.35 m at 4.4-5.1 m; over its 3590 px the sphere's pattern 12.9 and mean
    square 0.97, the cylinder's 36.4 and 1.31)."""
    from .fitting.sphere import fit_sphere

    start = fit_sphere(ctx.xyz[union[:: max(1, union.size // TEST_POINTS)]])
    if not isinstance(start, Sphere):
        return cylinder, patterns
    sphere = ctx.fitter.refit(ctx.fitter.points(ctx.xyz, union), start)
    if not isinstance(sphere, Sphere):
        return cylinder, patterns
    found = misfit_patterns(ctx, sphere, union, correlation_px)
    if found is None or not _joins(found) or found[3][0] > patterns[3][0]:
        return cylinder, patterns
    return sphere, found
