"""Step 4, ``facets``: a curved model that fits worse than the sensor's noise is tested
against planes, then against the fitter's own split.

A cylinder bent over the crease of two block faces (or a sphere over a corner of three)
fits their pixels within the fitter's tolerance, but its residuals are far larger than
the noise: the faces are flat and the model is wrong. The noise model tells when: the
mean squared residual of ``n`` pixels of a right model is ``sigma^2`` within a few
standard deviations ``sigma^2 sqrt(2 / n)`` of the chi-square law. Only such regions
are split into planes (the split's sequential trimmed extraction with a planes-only
judge), and the planes replace the curved model when they explain the region at least
as closely as it did and at the noise (facets of a truly curved surface, a tunnel, do
not): on a sensor whose curved surfaces fit at their noise (a laser's pipes and balls)
nothing runs. When planes do not do it, the same split with the pipeline's fitter as the
judge (any kind, each within the curved model's rms) is held to the same rules: a pipe
whose region took its end cap (or a box face beside it) comes back as its cylinder and
the plane. A cylinder within the range noise that misfits its region in a pattern across
its axis (a wall and a corner of what stands before it, seen obliquely) faces the two
least-squares planes of its sides (:func:`_two_planes_across_the_axis`). Last, a
cylinder's region is looked at for an end cap the distances cannot
show (on a noisy or far sensor the whole cap lies within the noise of the cylinder): a
disc across the axis, whose pixels share one axial coordinate (:func:`cap_split`),
also in what a split kept of the region when it only trimmed it to a cylinder.
"""

from __future__ import annotations

import copy
import functools

import numpy as np

from .. import kernels  # the package: its names load on first use (no compiler at import)
from .._numeric import median, rows_at
from ..fitting.classify import INLIER_FACTOR, trimmed_plane
from ..fitting.plane import fit_plane
from ..fitting.primitives import Cylinder, Plane, Sphere, squared_distances
from ..fitting.region_fitter import fresh_label, model_row, model_table, region_indices
from ..fitting.robust import CHI_SQUARE_SIGMAS, beyond_noise, curvature_resolved, distance_noise
from ..kernels.linalg import noise_rms_bound
from .context import SCREEN_SLACK, Context, without
from .grid_lines import on_one_grid_line
from .grow import SETTLE_MARGIN

__all__ = ["planes_for_curved", "cap_split", "axial_noise"]

#: Share of the region's pixels the planes must take (the crease band between them is left).
PLANES_COVER = 0.9
#: Parameters of each curved kind (a plane has 3): what the curvature test weighs.
CURVED_PARAMETERS = {"cylinder": 5, "sphere": 4}
#: Searches per region (bounds the time; a crease region holds two or three faces).
_MAX_ATTEMPTS = 6
#: Bins of angle about a cylinder's axis in which its mean distance is tested, over every
#: pixel of its region (:func:`_two_planes_across_the_axis`).
ANGLE_BINS = 8
#: Equal-count cuts of a cylinder region by angle tried for the planes of its two sides.
CUTS = 33


class _PlaneJudge:
    """A planes-only stand-in for the pipeline's fitter (what :class:`Context` calls),
    refusing a plane whose rms exceeds ``max_rms``. ``proposals``: the compiled searches'
    memo of proposals (:func:`rangeseg_o3d.fitting.classify.trimmed_primitive`), shared by the
    judges of one region: both split it from the same pools, and a pool's proposals do not
    depend on the judge."""

    def __init__(self, fitter, max_rms: float, proposals: dict | None = None):
        self.fitter = fitter
        self.max_rms = max_rms
        self.proposals = proposals

    def fit(self, points: np.ndarray):
        plane = fit_plane(points)
        return plane if plane and plane.rms <= self.max_rms else None

    def refit(self, points: np.ndarray, model):
        return self.fit(points)

    def points(self, xyz_flat: np.ndarray, idx: np.ndarray) -> np.ndarray:
        return self.fitter.points(xyz_flat, idx)

    def trimmed(self, xyz_flat: np.ndarray, pool: np.ndarray, *, sigma: float, min_points: int,
                starts: bool = False):
        # trimmed_fit with this judge in one compiled call (what Context.dominant_piece asks)
        return trimmed_plane(xyz_flat, pool, sigma=sigma, min_points=min_points, max_rms=self.max_rms,
                             starts=starts, proposals=self.proposals)


class _BoundJudge(_PlaneJudge):
    """The pipeline's fitter (any kind), refusing a model whose rms exceeds ``max_rms``."""

    def fit(self, points: np.ndarray):
        model = self.fitter.fit(points)
        return model if model and model.rms <= self.max_rms else None

    def refit(self, points: np.ndarray, model):
        refit = self.fitter.refit(points, model)
        return refit if refit and refit.rms <= self.max_rms else None

    def trimmed(self, xyz_flat: np.ndarray, pool: np.ndarray, *, sigma: float, min_points: int,
                starts: bool = False):
        # the fitter's compiled trimmed fit with this judge's bound (None: it has none)
        return self.fitter.trimmed(xyz_flat, pool, sigma=sigma, min_points=min_points, max_rms=self.max_rms,
                                   starts=starts, proposals=self.proposals)


def _surfaces_of(ctx: Context, idx: np.ndarray, judge) -> list[tuple[np.ndarray, object]]:
    """The surfaces a sequential trimmed split with ``judge`` finds in the pixels ``idx``,
    with their pixels; the split stops as soon as they cannot take PLANES_COVER of ``idx``
    (:func:`_covers` then refuses what it found anyway)."""
    planar = copy.copy(ctx)  # the same points, noise and size floor
    planar.fitter = judge
    found, pools = [], planar.pieces(idx)
    taken, needed = 0, PLANES_COVER * idx.size
    for _ in range(_MAX_ATTEMPTS):
        # every surface still to be found is a piece of a pool left, and the pieces are disjoint
        if not pools or taken + sum(pool.size for pool in pools) < needed:
            break
        pool = pools.pop()
        piece, plane = planar.dominant_piece(pool)
        if piece is None:
            continue
        found.append((piece, plane))
        taken += piece.size
        pools.extend(planar.pieces(pool, piece))
        pools.sort(key=len)
    return found


def _nearest(ctx: Context, surfaces: list) -> list[tuple[np.ndarray, object]]:
    """``surfaces`` with a pixel they took moved to another whose model is nearer by more
    than SETTLE_MARGIN times the noise of its distance to its own, twice: a surface whose
    pixels changed is refitted to them in between (the split's model was pulled towards the
    pixels it took from its neighbour: a pipe's cylinder over the wall beside it) and at the
    end. Each surface is then cut to its connected pieces of ``ctx.min_size``, a curved one
    to its largest (a few pixels apart determine a plane, not a curvature). The sequential
    split hands the first surface every pixel within its inlier band, the rim of a pipe's
    end cap with it; the margin leaves the pixels on the crease line, which both explain,
    where they were (as the settle step does)."""
    if len(surfaces) < 2:
        return surfaces
    pixels = np.concatenate([piece for piece, _ in surfaces])
    start = np.repeat(np.arange(len(surfaces)), [piece.size for piece, _ in surfaces])
    points = rows_at(ctx.xyz, pixels)
    models = [model for _, model in surfaces]
    owner, held = start, [None] * len(surfaces)
    for round_ in range(NEAREST_ROUNDS):
        moved = _moved_to_nearer(ctx, pixels, points, owner, models)
        if moved is None:
            break
        owner = moved
        last = round_ == NEAREST_ROUNDS - 1
        models, held = zip(*(_refit_held(ctx, pixels[owner == i], model, held[i], last)
                             for i, model in enumerate(models)))
    if owner is start:
        return surfaces
    kept = []
    for (pieces, union, deferred), model in zip(held, models):  # the pieces each model was refitted to last
        for piece in pieces:
            own = _refit_to(ctx, np.sort(piece), model) if len(pieces) > 1 else model
            if deferred and own is model:  # the piece's refit failed: its plane's refit to them all
                own = _refit_to(ctx, union, model)
            if own and own.kind == model.kind:
                kept.append((np.sort(piece), own))
    return kept


def _refit_held(ctx: Context, idx: np.ndarray, model, held, last: bool):
    # ``(pieces, pixels, deferred)`` of the pixels ``idx`` a surface holds (:func:`_pieces_of`)
    # and its model refitted to those pixels. ``held``: the same triple from the round before,
    # when ``model`` is its refit; a plane refitted to the very pixels it was just refitted to
    # is kept (a plane's refit does not start from the model: the same pixels give the same
    # plane, or fail again and leave the model). In the ``last`` round, a plane of several
    # pieces is not refitted (deferred): each piece takes its own plane, and the refit to
    # them all is only what a piece whose refit fails falls back to
    pieces = _pieces_of(ctx, idx, model)
    pixels = np.sort(np.concatenate(pieces or [idx[:0]]))
    if held is not None and isinstance(model, Plane) and np.array_equal(pixels, held[1]):
        return model, (pieces, pixels, False)
    if last and isinstance(model, Plane) and len(pieces) > 1:
        return model, (pieces, pixels, True)
    return _refit_to(ctx, pixels, model), (pieces, pixels, False)


def _pieces_of(ctx: Context, idx: np.ndarray, model) -> list[np.ndarray]:
    # the connected pieces of ``ctx.min_size`` of the pixels ``idx`` a surface holds; of a
    # curved one only the largest (a few pixels apart determine a plane, not a curvature)
    pieces = ctx.pieces(np.sort(idx))  # smallest first
    return pieces if isinstance(model, Plane) else pieces[-1:]


#: Rounds of :func:`_nearest` (each with the models refitted to the pixels the last one left them).
NEAREST_ROUNDS = 2


def _moved_to_nearer(ctx: Context, pixels: np.ndarray, points: np.ndarray, owner: np.ndarray, models: list):
    # ``owner`` with each pixel nearer another model by more than SETTLE_MARGIN times the noise
    # of its distance to its own (the range noise along the ray) given to it; None if none is
    # (kernels.nearer_models: one pass, no (models x pixels) distances)
    kinds, params = zip(*(model_row(model) for model in models))
    owner, moved = kernels.nearer_models(np.ascontiguousarray(points, dtype=np.float64), ctx.sigma[pixels],
                                         np.ascontiguousarray(owner, dtype=np.int64), np.array(kinds, np.int8),
                                         np.array(params), float(SETTLE_MARGIN))
    return owner if moved else None


def _refit_to(ctx: Context, idx: np.ndarray, model):
    # ``model`` refitted to the pixels ``idx``: the refit from it or, for a curved model, the
    # fitter's own fit from scratch, whichever of the model's kind fits closer (a refit
    # started from a model pulled far off, a pipe's cylinder bent over the wall beside it,
    # can stay in its valley); the model itself when neither keeps its kind or too few
    # pixels are left
    if idx.size < ctx.min_size:
        return model
    points = ctx.fitter.points(ctx.xyz, idx)
    tries = [ctx.fitter.refit(points, model)]
    if not isinstance(model, Plane):
        tries.append(ctx.fitter.fit(points))
    tries = [m for m in tries if m and m.kind == model.kind]
    return min(tries, key=lambda m: m.rms) if tries else model


def planes_for_curved(ctx: Context, labels: np.ndarray, fits: dict, *, faces_beyond_noise: bool = False):
    """Replace each curved model that fits worse than the noise by the planes (failing them,
    the surfaces of any kind) that explain its region (returns new ``(labels, fits)``).

    The planes (surfaces) must take ``PLANES_COVER`` of the region's pixels with a pooled rms no
    larger than the curved model's on the same pixels and within the noise's chi-square
    bound; the first keeps the label, the others take new labels, the pixels none takes
    are freed; a pixel the surfaces took goes to a clearly nearer one (:func:`_nearest`). A
    curved model within the range noise but beyond the noise of its distances
    (:func:`rangeseg_o3d.fitting.robust.distance_noise`: range noise moves a point along
    its ray, and the flanks of a pipe are seen at grazing incidence), with a connected
    region's worth of pixels far beyond it, holds another surface too (a pipe and its end
    cap): there the surfaces of any kind are tried, held to the noise of their distances.
    A cylinder within the range noise that holds no other surface is tried against the two
    planes of its sides when it misfits across its axis (:func:`_two_planes_across_the_axis`),
    which must also resolve what it leaves (an F-test); with ``faces_beyond_noise`` (a
    laser's single returns, where it was measured) beyond the range noise too, where the
    searches find nothing, each side within the range noise of its own pixels
    (:func:`_two_faces_across_the_axis`). Failing all these, a cylinder and
    the end cap its region holds (:func:`cap_split`), held to the same rules; a split that
    only trims a cylinder's region to a cylinder is asked for the end cap the trimmed pixels
    hold (:func:`_cap_of_trimmed`); a split that only turns a region to the other curved kind
    is refused where the fitter's fit of its pixels is of its own kind again and fits the
    split's pixels as closely (:func:`_only_turns_the_kind`). A compiled pretest
    (:func:`_may_split`) returns the inputs at once where no region can pass the tests that
    let a split run.
    """
    curved = [k for k, m in fits.items() if m and not isinstance(m, Plane)]
    if not curved or not _may_split(ctx, labels, fits, curved):
        return labels, fits
    wanted = set(curved)
    regions = region_indices(labels, only=wanted)  # (the curved labels' pixels alone: no sort of the others)
    labels, fits = labels.copy(), dict(fits)
    flat = labels.ravel()
    next_label = fresh_label(labels, fits)
    for k, idx in regions.items():
        model = fits[k]
        sigma = median(ctx.sigma[idx])
        distances = model.distances(rows_at(ctx.xyz, idx))
        rms = float(np.sqrt(np.mean(distances * distances)))
        if beyond_noise(rms, sigma, idx.size):
            proposals = {}  # both judges search the same first pools
            judges, noise = (_PlaneJudge(ctx.fitter, rms, proposals), _BoundJudge(ctx.fitter, rms, proposals)), sigma
        elif _holds_another(ctx, model, idx, distances, rms):
            judges, noise = (_BoundJudge(ctx.fitter, rms),), None  # the model's own kind and the other's
        else:
            judges, noise = (), None
        # each split with the noise it is held to and whether its surfaces must resolve what
        # the curved model leaves; last, a cylinder and its end cap, held to the noise of
        # their distances
        splits = [(functools.partial(_surfaces_of, ctx, idx, judge), noise, True, False) for judge in judges]
        if not judges:
            # within the range noise, a cylinder that misfits across its axis faces the two
            # planes of its sides, which must resolve what it leaves (a crease, not a curve)
            splits.append((functools.partial(_two_planes_across_the_axis, ctx, model, idx, distances), None, True,
                           True))
        elif noise is not None and faces_beyond_noise:
            # beyond the range noise the trimmed split's band (k_sigma of that noise) may span a
            # crease seen near grazing: its first plane takes both faces along it, and what it
            # leaves no plane explains (a spinning lidar's box top four rows deep at 1.5 cm
            # noise, bent with the face below it into one cylinder); the cut across the axis
            # needs no band, its two planes held to the range noise and the F-test as above
            splits.append((functools.partial(_two_faces_across_the_axis, ctx, model, idx, distances), noise, True,
                           True))
        splits.append((functools.partial(cap_split, ctx, model, idx, distances), _EACH_SURFACE, False, False))
        for split, split_noise, settle, resolve in splits:
            surfaces = split()
            if not _covers(surfaces, idx) or (resolve and len(surfaces) < 2):
                continue
            if settle and isinstance(split_noise, float) and _settling_out_of_reach(ctx, idx, surfaces, split_noise):
                continue  # refused before the reassignment, the split's costliest step
            if settle:  # the cap split hands each pixel to its nearer model itself
                surfaces = _nearest(ctx, surfaces)
            if _explains(ctx, idx, distances, surfaces, split_noise, model.kind, resolve=resolve, model=model):
                break
        else:
            continue
        if len(surfaces) == 1 and surfaces[0][1].kind == model.kind:
            # a split that only trimmed the region to a surface of its own kind left it the
            # cap, if it held one (the loop stops at the first split that explains the region)
            surfaces = _cap_of_trimmed(ctx, *surfaces[0]) or surfaces
        elif _only_turns_the_kind(ctx, idx, model, surfaces):
            continue
        flat[idx] = 0
        for i, (piece, surface) in enumerate(surfaces):
            label = k if i == 0 else next_label
            next_label += i > 0
            flat[piece] = label
            fits[label] = surface
    return labels, fits


def _only_turns_the_kind(ctx: Context, idx: np.ndarray, model, surfaces: list) -> bool:
    """Whether a split of ``model``'s region (pixels ``idx``) into ``surfaces`` only turns it
    to the other curved kind, where the fitter's fit of the region's pixels is of its own kind
    again and leaves the pixels the split's surface takes no more squared distances than that
    surface does. A model fitted before its region grew misfits the grown region by the growth
    alone, and such a split replaced a model that was right (kinect study seed 1478 scan 0: a
    ball's sphere from 21 tile means held on 51, 5.2 mm rms against 3.3 mm of noise, cut into
    one cylinder at 2.0 mm that kept the region, where the sphere fitted to the 51 leaves 1.6).
    A split whose surface fits its pixels better stands (nodding_0.5deg study seed 1480 scan
    0, region growing: a ball's stale cylinder on 88 px, the fitter's cylinder there 7.6 mm
    rms over the split's 87, its sphere 2.7 mm)."""
    if len(surfaces) != 1 or surfaces[0][1].kind in ("plane", model.kind):
        return False
    decided = ctx.fitter.fit(ctx.fitter.points(ctx.xyz, idx))
    if not decided or decided.kind != model.kind:
        return False
    piece, surface = surfaces[0]
    points = rows_at(ctx.xyz, piece)
    return squared_distances(decided, points) <= squared_distances(surface, points)


def _cap_of_trimmed(ctx: Context, idx: np.ndarray, model) -> list:
    """The cylinder ``model`` of the pixels ``idx`` (a split's one surface of a region, of the
    region's kind) and the end cap those pixels hold, by :func:`cap_split` and held to the
    cap split's rules in :func:`planes_for_curved` (``_explains`` with ``_EACH_SURFACE``);
    [] when they hold none.

    A cylinder beyond the range noise over a pipe and its end cap is split by the fitter's
    sequential search first, whose band (``k_sigma`` range sigmas) takes most of the cap with
    the pipe: a cylinder again, on PLANES_COVER of the region, which explains it, so the cap
    split, tried last, was never asked (spinning_64x1024 study seed 1394 scan 1: a 0.125 m
    pipe at 2.6-3.9 m, 162 px of it, and its cap seen at 31 degrees, 78 px, one region at 22.6 mm
    rms over 15 mm of noise; the search kept a cylinder of 221 px holding 59 of the cap's)."""
    idx = np.sort(idx)
    distances = model.distances(rows_at(ctx.xyz, idx))  # (once: the cap split and the rules read them)
    split = cap_split(ctx, model, idx, distances)
    return split if split and _explains(ctx, idx, distances, split, _EACH_SURFACE, model.kind, model=model) else []


def _may_split(ctx: Context, labels: np.ndarray, fits: dict, curved: list) -> bool:
    """Whether :func:`planes_for_curved` may change any of the ``curved`` regions (False: it
    surely returns them as they are).

    One compiled pass (:func:`rangeseg_o3d.kernels.curved_may_split`) asks of every sphere and
    cylinder region the tests that let a split run, each bounded on the safe side by
    SCREEN_SLACK: its rms beyond the range noise at the median (:func:`beyond_noise`), a
    region's worth of its outliers (:func:`_holds_another`'s first test), a cylinder's misfit
    across its axis and the planes of its sides (:func:`_two_planes_across_the_axis`'s compiled
    gate and last refusal) and an end cap's band
    (:func:`_no_cap_band`). On 9 of the LMS200 suite's 10 scans no region passes any, and
    the step's grouping, distances, medians and splits per region cost 0.6-0.9 ms a scan
    there, where it changes nothing. Another plugin's curved model leaves the answer to the
    step."""
    if not all(isinstance(fits[k], (Cylinder, Sphere)) for k in curved):
        return True
    flat = np.ascontiguousarray(labels.ravel())
    if flat.dtype != np.int32:  # (the label images' type: one compiled signature)
        flat = flat.astype(np.int32)
    kinds, params, _ = model_table({k: fits[k] for k in curved}, max(curved) + 1)
    may = kernels.curved_may_split(flat, np.ascontiguousarray(ctx.xyz, dtype=np.float64),
                                   np.ascontiguousarray(ctx.sigma, dtype=np.float64), kinds, params, int(ctx.min_size),
                                   INLIER_FACTOR, CHI_SQUARE_SIGMAS, ANGLE_BINS, CUTS, PLANES_COVER,
                                   CURVED_PARAMETERS["cylinder"] - 3, SCREEN_SLACK)
    return bool(may.any())


def _holds_another(ctx: Context, model, idx: np.ndarray, distances: np.ndarray, rms: float, *,
                   count_outliers: bool = True, noise: np.ndarray | None = None) -> bool:
    """Whether ``model``'s region (its ``distances``, their ``rms``) is beyond the noise of its
    distances and its pixels beyond CHI_SQUARE_SIGMAS of that noise hold a connected piece
    of ``ctx.min_size``: another surface, not a model a little off everywhere (a tapered
    mug) or the noise's tail. ``count_outliers``: first the cheap test, a region's worth of
    the model's outliers (beyond INLIER_FACTOR x its rms); a plane over two faces has
    none (its rms spreads over both). ``noise``: the pixels' distance noise
    (:func:`~rangeseg_o3d.fitting.robust.distance_noise`), when the caller has it."""
    if count_outliers and np.count_nonzero(np.abs(distances) > INLIER_FACTOR * rms) < ctx.min_size:
        return False
    if noise is None:
        noise = distance_noise(model, rows_at(ctx.xyz, idx), ctx.sigma[idx])
    if not beyond_noise(rms, float(np.sqrt(np.mean(noise * noise))), idx.size):
        return False
    far = idx[np.abs(distances) > CHI_SQUARE_SIGMAS * noise]
    return far.size >= ctx.min_size and ctx.largest_piece(far).size >= ctx.min_size


def _two_planes_across_the_axis(ctx: Context, model, idx: np.ndarray, distances: np.ndarray) -> list:
    """A cylinder region within the range noise cut at one angle about the axis into the
    least-squares planes of its two sides (``[(pixels, plane)] * 2``, pixels increasing),
    when the cylinder misfits it in a pattern across its axis; empty otherwise.

    The pattern (:func:`rangeseg_o3d.kernels.crease_sides`, one compiled call): over every
    pixel of the region, the cylinder's rms is beyond the noise of its distances (the range
    noise along each ray, :func:`rangeseg_o3d.fitting.robust.distance_noise`), and so is its
    mean distance in each of ANGLE_BINS equal-count bins of angle about the axis (a
    chi-square over the bins). An arc bent over a crease seen obliquely (two box faces, a
    wall and a corner of what stands before it) is off the same way along whole bands of
    angle; a right cylinder on a sensor noisier than its model says is off at random. Every
    pixel, not a sample: the chi-square bound tightens with their number, and a shallow
    crease a thousand tile means show is within the bound of a few hundred (a stereo
    camera's wall and the box face beside it at 3 m, 1551 tile means, one cylinder 1.2 x the
    noise of its distances, which the gate on a sample of 256 did not see). The cut is the
    one of CUTS equal-count cuts by angle (each side ``ctx.min_size``) whose planes leave the fewest squared
    distances; none when even the PLANES_COVER share of the pixels nearest those planes
    leaves more than the cylinder's curvature test allows (a true cylinder: nothing
    :func:`_nearest` or :func:`_explains` could accept).
    """
    if not isinstance(model, Cylinder):
        return []
    first = kernels.crease_sides(ctx.xyz, ctx.sigma, np.ascontiguousarray(idx, dtype=np.int64), distances, model.axis,
                                 model.point, float(model.radius), ctx.min_size, ANGLE_BINS, idx.size, CUTS, CHI_SQUARE_SIGMAS,
                                 PLANES_COVER, CURVED_PARAMETERS["cylinder"] - 3)
    if not first.size:
        return []
    sides = [idx[first], idx[~first]]
    planes = [fit_plane(rows_at(ctx.xyz, side)) for side in sides]
    return list(zip(sides, planes)) if all(planes) else []


def _two_faces_across_the_axis(ctx: Context, model, idx: np.ndarray, distances: np.ndarray) -> list:
    """:func:`_two_planes_across_the_axis` for a cylinder beyond the range noise: its two
    sides, each of whose planes is within the range noise of its own pixels (two faces);
    empty otherwise. A face and the mixed returns along its edge bent into one cylinder cut
    in two leaves a side beyond the noise (nodding_1deg seed 23: a box face four columns wide
    cut into 67 and 21 pixels, the second a third mixed returns)."""
    sides = _two_planes_across_the_axis(ctx, model, idx, distances)
    for side, plane in sides:
        if beyond_noise(float(plane.rms), median(ctx.sigma[side]), side.size):
            return []
    return sides


def _settling_out_of_reach(ctx: Context, idx: np.ndarray, surfaces: list, noise: float) -> bool:
    """Whether :func:`_nearest` cannot bring several ``surfaces`` (``(pixels, model)`` pairs
    a split found in the pixels ``idx``) within the range ``noise`` :func:`_explains` holds
    them to, so that the split is refused before its reassignment and refits (most of its
    time on a truly curved region: a tunnel's facets).

    What settles must take PLANES_COVER of ``idx`` (``needed`` pixels) from the surfaces'
    own pixels. With the models held, no choice of that many pixels and owners leaves less
    than the ``needed`` pixels nearest a surface, each at its distance to the nearest. The
    refits move the models: were the surfaces right at the noise, refitting ``P``
    parameters to the pixels takes about ``P noise^2`` off the squared distances (a
    chi-square of ``P`` degrees of freedom, here up to CHI_SQUARE_SIGMAS deviations), with
    ``P`` as many as the settled pieces can hold (each of ``ctx.min_size`` pixels, each
    with a curved kind's parameters at most). Out of reach when those nearest squared
    distances exceed the acceptance's noise bound at ``needed`` pixels (the loosest it
    gives a cover: it tightens with more) by more than that. One surface is never out of
    reach (:func:`_explains` judges one plane by the curvature test, not the noise)."""
    if len(surfaces) < 2:
        return False
    pixels = np.concatenate([piece for piece, _ in surfaces])
    needed = int(np.ceil(PLANES_COVER * idx.size))
    if pixels.size < needed:
        return False  # not a cover: _explains refuses it anyway
    points = rows_at(ctx.xyz, pixels)
    nearest = np.abs(surfaces[0][1].distances(points))
    for _, model in surfaces[1:]:
        np.minimum(nearest, np.abs(model.distances(points)), out=nearest)
    squares = np.partition(nearest * nearest, needed - 1)[:needed]
    parameters = float(max(CURVED_PARAMETERS.values()) * (pixels.size // ctx.min_size))
    bound = noise_rms_bound.py_func(noise, float(needed), CHI_SQUARE_SIGMAS)
    refits = parameters * noise_rms_bound.py_func(noise, parameters, CHI_SQUARE_SIGMAS) ** 2
    return float(np.sum(squares)) > needed * bound * bound + refits


def _noise_rms(ctx: Context, surfaces: list) -> float:
    """The rms distance noise of the pixels of ``surfaces`` (``(pixels, model)`` pairs) about
    their models were those right: the range noise times each pixel's incidence cosine."""
    squares = sum(float(np.sum(distance_noise(model, rows_at(ctx.xyz, idx), ctx.sigma[idx]) ** 2))
                  for idx, model in surfaces)
    return float(np.sqrt(squares / max(sum(idx.size for idx, _ in surfaces), 1)))


def _covers(surfaces: list, idx: np.ndarray) -> bool:
    """Whether ``surfaces`` take PLANES_COVER of the pixels ``idx``."""
    return bool(surfaces) and sum(piece.size for piece, _ in surfaces) >= PLANES_COVER * idx.size


#: ``_explains``' noise for the cap split: each surface held to the noise of its own distances
_EACH_SURFACE = "each surface"


def _explains(ctx: Context, idx: np.ndarray, distances: np.ndarray, surfaces: list, noise,
              kind: str, *, resolve: bool = False, model=None) -> bool:
    # The surfaces take PLANES_COVER of the pixels. One plane (two parameters fewer than the
    # curved model) replaces it when the curved model does not resolve a curvature over the
    # pixels the plane takes (the F-test of curvature_resolved, on the model's own residuals:
    # mixed pixels or an oblique view do not enter). Several surfaces must be no farther from
    # the pixels than the curved model (of ``kind``, its ``distances`` to the pixels ``idx``)
    # and at the noise (facets of a truly curved surface do not fit at the noise): ``noise``,
    # the range noise, or (None: a region beyond the noise of its distances only) that of the
    # surfaces' distances, _noise_rms. With ``resolve`` (a curved model within the range
    # noise) several surfaces must also lower the squared distances by more than their extra
    # parameters would (the F-test, each plane's three and a border line between two,
    # against the curved model's own). With ``noise`` _EACH_SURFACE (the cap split: a
    # cylinder and the plane across its axis, no facets of a curve), surfaces beyond their
    # pooled distance noise pass when each is at the noise of its own distances or, beyond
    # it, no farther from its pixels in those units than the curved ``model``
    # (:func:`_each_at_noise`).
    if not _covers(surfaces, idx):
        return False
    taken = sum(piece.size for piece, _ in surfaces)
    squares = sum(squared_distances(surface, rows_at(ctx.xyz, piece)) for piece, surface in surfaces)
    covered = np.concatenate([piece for piece, _ in surfaces])
    model_squares = float(np.sum(distances[np.searchsorted(idx, covered)] ** 2))  # the curved model's
    if len(surfaces) == 1 and isinstance(surfaces[0][1], Plane):
        return not curvature_resolved(squares, model_squares, taken, CURVED_PARAMETERS[kind] - 3)
    if squares > model_squares:
        return False
    extra = 4 * len(surfaces) - 1 - CURVED_PARAMETERS[kind]
    if resolve and not curvature_resolved(model_squares, squares, taken, max(extra, 1)):
        return False
    each = noise is _EACH_SURFACE
    if noise is None or each:
        noise = _noise_rms(ctx, surfaces)
    return not beyond_noise(np.sqrt(squares / taken), noise, taken) or (each and _each_at_noise(ctx, surfaces, model))


def _each_at_noise(ctx: Context, surfaces: list, model) -> bool:
    """Whether each of ``surfaces`` is at the noise of its own distances (its mean squared
    distance in units of that noise within the chi-square bound) or, beyond it, within the
    range noise of its pixels and no farther from them in units of their distance noise than
    the curved ``model`` was. Pooled, a long pipe's flanks seen at grazing incidence (the
    noise of their distances small, a model's bias large in its units) drown a cap that fits
    at its noise; the pipe that keeps its pixels must still be at the range noise, the bound
    a curved model's fit is held to (a cylinder bent over a crease of a quantising camera's
    scene is many times its range noise off its pixels, and the plane piece the cap split
    cuts from it is no end cap)."""
    for idx, surface in surfaces:
        points, sigma = rows_at(ctx.xyz, idx), ctx.sigma[idx]
        ratio = _mean_squared_sigmas(surface, points, sigma)
        if not beyond_noise(np.sqrt(ratio), 1.0, idx.size):
            continue
        if model is None or ratio > _mean_squared_sigmas(model, points, sigma):
            return False
        rms = float(np.sqrt(np.mean(surface.distances(points) ** 2)))
        if beyond_noise(rms, float(np.sqrt(np.mean(sigma * sigma))), idx.size):
            return False
    return True


def _mean_squared_sigmas(model, points: np.ndarray, sigma: np.ndarray) -> float:
    # the mean squared distance of ``points`` to ``model``, each in units of its distance noise
    noise = np.maximum(distance_noise(model, points, sigma), 1e-12)
    return float(np.mean((model.distances(points) / noise) ** 2))


def cap_split(ctx: Context, model, idx: np.ndarray, distances: np.ndarray | None, *, closes=None) -> list:
    """A cylinder's region split into the cylinder and its end cap (``[(pixels, model)]``,
    empty when it holds no cap).

    A pipe's end cap is a disc across the axis at one end of it: its pixels share one
    axial coordinate (within the noise of the range along the axis, ``sigma |ray . axis|``),
    so they pile up in one bin of the axial histogram, and near the rim they are within the
    noise of the cylinder too (on a far or noisy sensor the whole cap is), where the
    distance tests of :func:`_holds_another` see nothing. The pixels of the fullest bin's
    plane (within CHI_SQUARE_SIGMAS of its noise) that are nearer to it than to the
    cylinder, each distance in units of its own noise (along the axis for the plane, across
    the cylinder's surface for it: the cap faces the sensor, the pipe's flanks graze it, so
    a rim pixel a centimetre off the cylinder is many of its noise sigmas off while within
    one of the plane's), cut to their largest connected piece, are the cap when that plane lowers
    their squared distances by more than noise would (the F-test of
    :func:`rangeseg_o3d.fitting.robust.curvature_resolved`, the plane's three parameters
    against the cylinder's none on those pixels) and it lies on more than one row and column
    of the grid (:func:`_off_one_grid_line`); the cylinder is refitted to the rest.
    ``distances``: the cylinder's distances to the region's pixels (None: computed here when
    needed). ``closes`` (optional): the caller's test that a cap closes the pipe,
    ``closes(rest, piece, model, plane)``; then only a cap at one end of the region is looked
    for (the fullest bin's band must have none of the region's pixels beyond it on both
    sides, :func:`_pixels_beyond_both_sides`, asked in place of the band's size screen), and
    the first piece found, with its plane and the region's own ``model``, must pass the test
    before the refit and the second cut, the split's costliest steps.
    """
    if not isinstance(model, Cylinder) or idx.size < 2 * ctx.min_size:
        return []
    if closes is None and _no_cap_band(ctx, model, idx):
        return []
    points = rows_at(ctx.xyz, idx)
    along = (points - model.point) @ model.axis
    noise = axial_noise(points, ctx.sigma[idx], model.axis)
    width = 2.0 * median(noise)
    if not width > 0:
        return []
    bins = np.floor((along - along.min()) / width).astype(np.int64)
    counts = np.bincount(bins)
    fullest = int(np.argmax(counts))
    offset = median(along[bins == fullest])
    off_plane = np.abs(along - offset)
    if closes is not None and _pixels_beyond_both_sides(along, noise, offset, off_plane):
        return []
    if distances is None:
        distances = model.distances(points)
    sigma = ctx.sigma[idx]
    piece = _likelier_on_plane(ctx, idx, off_plane, noise, distances, model, points, sigma)
    if piece is None:
        return []
    plane = fit_plane(rows_at(ctx.xyz, piece))
    if not plane or not _off_one_grid_line(ctx, piece):
        return []
    on_piece = np.searchsorted(idx, piece)
    plane_squares = squared_distances(plane, rows_at(ctx.xyz, piece))
    cylinder_squares = float(np.sum(distances[on_piece] ** 2))
    # the cap plane must resolve what the cylinder leaves over its pixels (3 parameters more)
    if not curvature_resolved(cylinder_squares, plane_squares, piece.size, 3):
        return []
    if closes is not None and not closes(without(idx, piece), piece, model, plane):
        return []
    cylinder = ctx.fitter.refit(ctx.fitter.points(ctx.xyz, without(idx, piece)), model)
    if not cylinder or cylinder.kind != model.kind:
        return []
    # once more with the two fitted models: the rim pixels the cylinder fitted over the cap
    # still explained go to the cap, the pipe's pixels it took at the junction come back
    again = _likelier_on_plane(ctx, idx, np.abs(plane.distances(points)), distance_noise(plane, points, sigma),
                               cylinder.distances(points), cylinder, points, sigma)
    split = [(without(idx, piece), cylinder), (piece, plane)]
    if again is not None and not np.array_equal(again, piece):
        cap = fit_plane(rows_at(ctx.xyz, again))
        pipe = ctx.fitter.refit(ctx.fitter.points(ctx.xyz, without(idx, again)), cylinder)
        if cap and pipe and pipe.kind == model.kind and _off_one_grid_line(ctx, again):
            # kept when likelier: fewer squared noise sigmas over the region
            other = [(without(idx, again), pipe), (again, cap)]
            if _squared_sigmas(ctx, other) < _squared_sigmas(ctx, split):
                split = other
    return split


def axial_noise(points: np.ndarray, sigma: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The noise of the coordinates of ``points`` (N, 3) along ``axis``: their range noise
    ``sigma`` times the cosine between each one's ray (from the origin) and the axis."""
    rays = points / np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-12)
    return sigma * np.abs(rays @ axis)


def _pixels_beyond_both_sides(along: np.ndarray, noise: np.ndarray, offset: float, off_plane: np.ndarray) -> bool:
    """Whether pixels of a cylinder region (axial coordinates ``along``, their noise along the
    axis ``noise``) lie beyond the plane across the axis at ``offset`` on both sides, each by
    more than CHI_SQUARE_SIGMAS of its noise past the farthest reach of that plane's band
    (the pixels within CHI_SQUARE_SIGMAS of their noise of it, ``off_plane`` their
    distances): then no piece of the band is a cap that closes the pipe at either end
    (:func:`rangeseg_o3d.end_caps.closes_the_pipe`: its plane sits at its pixels' median
    axial coordinate, within the band). True also when the band is empty."""
    noise = np.maximum(noise, 1e-12)
    band = off_plane <= CHI_SQUARE_SIGMAS * noise
    if not band.any():
        return True
    reach = CHI_SQUARE_SIGMAS * float(noise[band].max())
    margin = CHI_SQUARE_SIGMAS * noise
    return bool(np.any(along - margin > offset + reach) and np.any(along + margin < offset - reach))


def _no_cap_band(ctx: Context, model, idx: np.ndarray) -> bool:
    """Whether no plane across the cylinder ``model``'s axis, at any axial coordinate, holds
    ``ctx.min_size`` of the region's pixels ``idx`` within CHI_SQUARE_SIGMAS of their noise
    along the axis, so that :func:`cap_split`'s first band (at the offset its histogram
    picks, whichever) is under the size floor and the split finds no cap.

    One compiled call (:func:`rangeseg_o3d.kernels.cap_band_most`, each pixel's band widened
    by SCREEN_SLACK: it only says no where numpy's band is surely under the floor) instead
    of the split's histogram, medians and distances, which on the LMS200 suite's cylinders
    (none holds a cap) were about half of the step's cost."""
    most = kernels.cap_band_most(ctx.xyz, ctx.sigma, np.ascontiguousarray(idx, dtype=np.int64), model.axis,
                                 model.point, CHI_SQUARE_SIGMAS, SCREEN_SLACK)
    return most < ctx.min_size


def _off_one_grid_line(ctx: Context, piece: np.ndarray) -> bool:
    """Whether the pixels ``piece`` lie on more than one row and more than one column of
    the grid. A sensor's rays fan out in planes (a nodding laser's scan row sweeps one
    through its mirror, a camera's image row or column one through its centre), and range
    noise moves each return along its ray: the returns of one row or column lie in the plane
    of its rays whatever surface they are on, and across a column's axis that plane is a
    disc at one axial coordinate, rms 0 (nodding_0.25deg seeds 23 and 71: a 20-px row of
    a vertical 24 cm column whose scan plane is level, cut off as its "end cap", then grown
    to 86-89 px: the column over-segmented). Such a piece tells no plane of its own. A
    real cap may be seen near grazing all the same: stereo_1280x720 seed 89 scan 0, a pipe's
    end cap of 14 tile means on several rows at median incidence cosine 0.15 (below
    scales.GRAZING_COSINE, which refused it and left it to the pipe)."""
    return not on_one_grid_line(piece, ctx.width)


def _squared_sigmas(ctx: Context, surfaces: list) -> float:
    # the sum of squared distances of the surfaces' pixels, each in units of its noise
    total = 0.0
    for idx, model in surfaces:
        points = rows_at(ctx.xyz, idx)
        noise = np.maximum(distance_noise(model, points, ctx.sigma[idx]), 1e-12)
        total += float(np.sum((model.distances(points) / noise) ** 2))
    return total


def _likelier_on_plane(ctx: Context, idx: np.ndarray, off_plane: np.ndarray, plane_noise: np.ndarray,
                       off_cylinder: np.ndarray, cylinder, points: np.ndarray, sigma: np.ndarray) -> np.ndarray | None:
    # The largest connected piece of the pixels ``idx`` (``points``, range noise ``sigma``)
    # within CHI_SQUARE_SIGMAS of the plane's noise and fewer noise sigmas off the plane
    # than off ``cylinder`` (None when it, or what it leaves, is under the size floor).
    plane_noise = np.maximum(plane_noise, 1e-12)
    band = np.flatnonzero(off_plane <= CHI_SQUARE_SIGMAS * plane_noise)
    if band.size < ctx.min_size:
        return None
    cylinder_noise = np.maximum(distance_noise(cylinder, points[band], sigma[band]), 1e-12)
    near = band[off_plane[band] / plane_noise[band] < np.abs(off_cylinder[band]) / cylinder_noise]
    if near.size < ctx.min_size:
        return None
    piece = np.sort(ctx.largest_piece(idx[near]))
    if piece.size < ctx.min_size or idx.size - piece.size < ctx.min_size:
        return None
    return piece

