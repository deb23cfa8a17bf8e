"""Step 8, ``polish``: spheres and cylinders are refitted once on their final pixels.

Planes are refitted from moments whenever they change, which costs nothing; the other
kinds keep the parameters of the points they were fitted to until here. A curved model
must also still earn its curvature on its final pixels: a cylinder fitted over a crease
keeps its region once the settle step has handed the crease's far face back to its own
plane, and on the face alone it is two parameters of noise (:func:`_still_flat`). A plane
must still be one on its final pixels: its kind was decided on the pixels it had then (a
pipe's flat middle piece, before growth gave it the flanks), :func:`_curved_planes`. For
a laser's single returns, whose noise is along their rays, a plane must also be within what
that noise gives its distances, or a cylinder fitted in range residuals takes it where it
is (a pipe's limb seen at grazing incidence), :func:`_planes_off_rays`; a cylinder or
sphere whose bend only the mixed returns at its border carry, and beside which the rays
see through it, is the plane of its inner pixels (:func:`_bent_by_border`); and a bend that
rests on the returns of one border grid line or of two opposite ones is none
(:func:`bent_at_border_lines`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np

from .._numeric import median, rows_at
from .. import kernels  # the package: its names load on first use (no compiler at import)
from ..kernels.linalg import CHI_SQUARE_SIGMAS, NOISE_CHI2_SIGMAS, noise_rms_bound
from ..fitting._compiled import arc_around_axis
from ..fitting.classify import MIN_ARC_DEG
from ..fitting.primitives import Cylinder, Plane, Sphere, front_along_rays, squared_distances
from ..fitting.region_fitter import label_sizes, model_table, other_curved_decision, region_indices
from ..fitting.plane import fit_plane
from ..fitting.robust import beyond_noise, curvature_resolved, distance_noise
from .context import SCREEN_SLACK, TRIM_SIGMAS, Context

__all__ = ["polish_models"]

#: Parameters of each curved kind beyond a plane's three (what the curvature test weighs).
EXTRA_PARAMETERS = {"cylinder": 2, "sphere": 1}


def polish_models(ctx: Context, labels: np.ndarray, fits: dict, *, decide_planes: bool = True,
                  resolve_bends: float = 0.0, along_rays: bool = False) -> dict:
    """``fits`` with the models moments cannot refit (spheres, cylinders) refitted on the
    pixels of ``labels``, and those that no longer resolve a curvature there replaced by
    the plane the fitter's decision gives their pixels; planes whose pixels the fitter now
    calls curved replaced by that model (:func:`_curved_planes`; with ``decide_planes``;
    ``resolve_bends``, the independent samples each pixel carries, 0 for not asked: also
    the planes whose quadric resolves a bend under the noise over those samples, and curved
    models only a neighbour's pixels bend are planes, :func:`_unbent`). With ``along_rays``
    (single returns, whose noise is along their rays only) also the planes whose distances
    that noise does not explain, where a curved model's does (:func:`_planes_off_rays`, with
    ``decide_planes``), and, with or without ``decide_planes``, the curved models a laser's
    mixed returns at jump edges bent replaced by the plane of their inner pixels
    (:func:`_bent_by_border`, after :func:`_unbent`; the planes either gives are not
    decided again by :func:`_curved_planes` or :func:`_planes_off_rays`), then, after the
    decision, every region whose model is curved (its own or the decision's) judged once on
    its pixels less the border lines off the rest (:func:`bent_at_border_lines`: a curved
    region becomes that plane, a plane the decision bent keeps its own); and
    :func:`_curved_planes` leaves the planes seen near grazing as they are
    (:func:`_seen_near_grazing`).

    Refitted only where the region outgrew the points the model was fitted to by more than
    20 % (a model's ``inliers`` counts those): a few more pixels move nothing. Such a region
    takes the other curved kind where the fitter's decision on its pixels gives it, closer
    than its own kind refitted (:func:`_other_kind_decided`).
    """
    fits = dict(fits)
    pixels = _Pixels(labels)  # the labels do not change here: their pixels are grouped once
    curved = [k for k, m in fits.items() if m and not isinstance(m, Plane)]
    grown = []
    if curved:  # (the labels' sizes: a pass over the grid, asked for the curved regions only)
        sizes = label_sizes(labels, minlength=max(fits, default=0) + 1)
        grown = [k for k in curved if sizes[k] > 1.2 * max(fits[k].inliers, 1)]
    refused = []  # grown regions their own kind no longer fits
    for k, refit in ctx.fitter.refit_regions(ctx.xyz, labels, fits, grown, from_moments=False,
                                             regions=pixels.every if grown else None).items():
        if refit and refit.kind == fits[k].kind:
            fits[k] = _other_kind_decided(ctx, pixels.every[k], refit) or refit
        elif not refit:
            refused.append(k)
    sums = None
    if curved:
        sums = _curved_sums(ctx, labels, fits, curved)
        # A grown region whose own kind the fitter now refuses is asked afresh as well: the
        # model kept from its smaller pixel set says nothing about the pixels it has now
        # (spinning_32x1024 seed 1023 scan 3: a box face at 3 cm noise, split off as a
        # 0.37 m cylinder with a few pixels of the faces beside it, kept that cylinder once
        # grown, where the fitter gives its pixels a plane of smaller rms).
        flat = _still_flat(ctx, labels, fits, curved, sums=sums)
        flat = sorted({k for k, idx in pixels.of(flat).items() if not _bent_but_for_strays(ctx, idx, fits[k])}
                      | set(refused))
        for k, idx in pixels.of(flat).items():
            decided = ctx.fitter.fit(ctx.fitter.points(ctx.xyz, idx))
            if isinstance(decided, Plane):
                fits[k] = decided
    # (the models of the regions still curved are those the sums measured: refitted above only)
    unbent = (_unbent(ctx, labels, [k for k in curved if not isinstance(fits[k], Plane)], resolve_bends,
                      pixels=pixels, sums=sums) if resolve_bends else {})
    fits.update(unbent)
    if along_rays:  # a laser's mixed returns at jump edges are no bend
        unbent.update(_bent_by_border(ctx, labels, fits, [k for k in curved if not isinstance(fits[k], Plane)],
                                      pixels=pixels, sums=sums))
        fits.update(unbent)
    bent = {}
    if decide_planes:  # (not the planes just found: the decision's marginal path would bend them again)
        bent = _curved_planes(ctx, labels, {k: m for k, m in fits.items() if k not in unbent}, resolve_bends,
                              pixels=pixels, grazing_flat=along_rays, refused_planes=along_rays)
        if resolve_bends and bent:
            # a plane the decision now bends is held to the test the curved models met above: a
            # bend only a neighbour's pixels carry is none (the batch leaves the decision the
            # planes beyond the noise's chi-square, and a few such pixels put a wall there)
            refused = _unbent(ctx, labels, list(bent), resolve_bends, pixels=pixels)
            bent = {k: m for k, m in bent.items() if k not in refused}
    if along_rays:  # nor are a laser's mixed returns along one or two sides of a region
        now = {k: bent.get(k, m) for k, m in fits.items() if k not in unbent}
        for k, plane in bent_at_border_lines(ctx, labels, {k: m for k, m in now.items()
                                                           if m and not isinstance(m, Plane)},
                                             resolve_bends, kept=set(bent), pixels=pixels).items():
            if bent.pop(k, None) is None:  # (a plane the decision bent keeps the plane it had)
                unbent[k] = fits[k] = plane
    fits.update(bent)
    if decide_planes and along_rays:
        fits.update(_planes_off_rays(ctx, labels, {k: m for k, m in fits.items() if k not in unbent}, pixels=pixels))
    return fits


def _other_kind_decided(ctx: Context, idx: np.ndarray, refit):
    """The fitter's decision on the flat pixels ``idx`` of a grown curved region when it is the
    other curved kind and leaves a smaller rms than ``refit`` (the region's model of its own
    kind refitted to them), else None.

    The kind was decided on the fewer pixels the model was fitted to, the refit keeps it: a
    ball fitted as a cylinder on 29 returns (nodding_1deg study seed 1488 scan 0: r 0.25 m at
    2.8 m under 5 mm of noise) refitted as a cylinder on the 48 it grew to (4.5 mm rms), where
    the decision on those gives a sphere of r 0.251 m at 3.5 mm. As at the other steps that
    turn one curved kind into the other (``refinement.facets``, ``fullres.other_curved_kind``),
    the other kind stands only where it fits closer than the model's own kind fitted anew."""
    decided = other_curved_decision(ctx.fitter, ctx.fitter.points(ctx.xyz, idx), refit.kind)
    return decided if decided is not None and decided.rms < refit.rms else None


class _Pixels:
    """The flat pixels of the labels of one label image, grouped on first use
    (:func:`rangeseg_o3d.fitting.region_fitter.region_indices`) and shared by the steps of
    polish, which read the same labels: one grouping instead of one per step."""

    def __init__(self, labels: np.ndarray):
        self.labels = labels
        self._every = None

    @property
    def every(self) -> dict:
        """``region_indices(labels)``: every positive label with pixels."""
        if self._every is None:
            self._every = region_indices(self.labels)
        return self._every

    @property
    def grouped(self) -> bool:
        """Whether the pixels are grouped already (:attr:`every` costs nothing more)."""
        return self._every is not None

    def of(self, keys) -> dict:
        """``region_indices(labels, only=keys)``: those of ``keys`` with pixels, by label."""
        if not keys:
            return {}
        every = self.every
        return {k: every[k] for k in sorted(set(keys)) if k in every}


def _unbent(ctx: Context, labels: np.ndarray, curved: list, samples: float = 1.0, *,
            pixels: _Pixels | None = None, sums: _CurvedSums | None = None) -> dict:
    """The planes of the regions among ``curved`` whose pixels' plane is within the
    fitter's plane threshold and whose bend does not outlive the pixels beyond 2 plane rms
    (:func:`rangeseg_o3d.fitting._decide.bend_resolved`): a curved model a plane just over
    the noise took only for a few pixels of a neighbouring face (noise_20mm seed 37 scan
    7: a 4-column wall strip with 26 px of its neighbours, rms 20.4 mm over 20 mm noise,
    a 0.53 m cylinder). The plane of the pixels that test keeps must be within the noise
    (:func:`_near_plane_within_noise`): the middle of a column loses its bend with its flanks,
    the pixels beyond 2 plane rms, but not its misfit to a plane (spinning_64x1024 study seed
    1392 scan 1: r 0.23 m at 6 m, its plane 29 mm rms over 15 mm of noise, within the
    fitter's threshold). Asked with ``resolve_bends``; ``samples`` per pixel as there; ``pixels``
    (optional) the labels' grouped pixels; ``sums`` (optional, :func:`_curved_sums` of these
    labels and models): a region whose pixels' plane by their moments is over the threshold
    by more than their rounding could move it is not fitted (its plane is no answer)."""
    from ..fitting import fit_plane
    from ..fitting._decide import bend_resolved
    from ..fitting.classify import INLIER_FACTOR, plane_threshold

    p = ctx.fitter.params
    if not curved or not {"plane_rms", "noise_floor", "rms_per_range2"} <= set(p):  # another plugin
        return {}
    out = {}
    for k, idx in (pixels or _Pixels(labels)).of(curved).items():
        if sums is not None and _plane_surely_over(ctx, sums, k, idx.size):
            continue
        pts = ctx.fitter.points(ctx.xyz, idx)
        centroid = pts.mean(axis=0)
        tolerance = plane_threshold(len(pts), centroid, plane_rms=p["plane_rms"], noise_floor=p["noise_floor"],
                                    rms_per_range2=p["rms_per_range2"])
        plane = fit_plane(pts, inlier_distance=INLIER_FACTOR * tolerance)
        if plane and plane.rms <= tolerance and _near_plane_within_noise(ctx, idx, pts, plane) and not bend_resolved(
                np.ascontiguousarray(pts - centroid), np.ascontiguousarray(plane.normal), plane.rms, float(samples)):
            out[k] = plane
    return out


def _near_plane_within_noise(ctx: Context, idx: np.ndarray, points: np.ndarray, plane: Plane) -> bool:
    """Whether the least-squares plane of the ``points`` of the pixels ``idx`` (the fitter's
    sample of them) within ``BEND_TRIM`` times ``plane``'s rms of it leaves them within the
    noise (:func:`beyond_noise` at the pixels' median range noise). The trim of
    :func:`_unbent`'s bend test, measured from ``plane`` itself (the bend test measures from the
    plane of that normal through the points' centroid, which a plane fitted to its inliers
    need not pass through)."""
    from ..fitting._decide import BEND_TRIM

    near = np.abs(plane.distances(points)) <= BEND_TRIM * plane.rms
    count = int(np.count_nonzero(near))
    inner = fit_plane(points[near]) if count > 3 else None
    return bool(inner) and not beyond_noise(float(inner.rms), median(ctx.sigma[idx]), count)


def _four_neighbours(grid: np.ndarray, wrap_columns: bool, off_grid) -> tuple:
    """``(above, below, left, right)``: each pixel's 4-neighbours' values in ``grid`` (H, W),
    views of one padded copy; across the seam on a 360-degree grid, ``off_grid`` beyond the
    grid's other edges."""
    padded = np.pad(grid, ((1, 1), (0, 0)), constant_values=off_grid)
    if wrap_columns:
        padded = np.pad(padded, ((0, 0), (1, 1)), mode="wrap")
    else:
        padded = np.pad(padded, ((0, 0), (1, 1)), constant_values=off_grid)
    return padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]


def _interior(labels: np.ndarray, wrap_columns: bool) -> np.ndarray:
    """``(H, W)`` whether each pixel's four neighbours on the grid carry its label (across
    the seam on a 360-degree grid; off the grid's other edges, not)."""
    inside = labels > 0
    for neighbour in _four_neighbours(labels, wrap_columns, 0):  # (off the grid: 0, no label)
        inside &= labels == neighbour
    return inside


def _bent_by_border(ctx: Context, labels: np.ndarray, fits: dict, curved: list, *,
                    pixels: _Pixels | None = None, sums: _CurvedSums | None = None) -> dict:
    """The planes of the curved regions among ``curved`` that a laser's mixed returns bent:
    the model is beyond the range noise (``ctx.sigma``, the chi-square bound); over the
    pixels whose four neighbours are in the region (one grid step in from its border, the
    reach of the beam's footprint) it resolves no curvature over their least-squares plane
    (the F-test), which is within the fitter's plane threshold and becomes the model; and
    the pixels beside the region see through it (:func:`_seen_through`): of those whose ray
    meets the model within its span and returns no nearer, more than half return from
    beyond it by ``CHI_SQUARE_SIGMAS`` range sigmas.

    A return whose footprint a jump edge crosses is mixed, lying along its ray between the
    two surfaces: a face a few columns wide with a column of them on either side bends
    like a cylinder's limbs (nodding_1deg seed 23 scan 5: a box face 4 columns wide at
    3.2 m with 36 mixed returns, a 0.285 m cylinder at 1.4 range sigmas rms, a false
    fitting). A cylinder or sphere has no edge across its axis: seen from outside, its
    pixels end where its limb turns from the rays or where a nearer surface hides it, so
    the rays beside it miss it or return in front of it. Beside that face 22 of the 22
    rays the cylinder claims return from beyond it (the wall behind); beside a
    pipe of 0.29 m on five columns that took 17 mixed returns (same scan set, seed 0
    scan 2), 3 of 11. That last test does not tell on its own: beside most pipes and
    balls fitted right the rays it counts are the ring of mixed returns their edge band
    left out, behind the model too (on the laser rows of the studied seeds, 487 of 776
    cylinders and 285 of 415 spheres would pass it); it only follows the F-test on the
    inner pixels, which two regions of those rows reached (that face and that pipe).
    The inner pixels must lie on two grid lines both ways (:func:`lines_beside`, line by line):
    on one, a pipe's middle column, every plane through that line fits them, whatever the bend
    (nodding_1deg study seed 1490 scan 0: a pipe of r 0.14 m at 5.6 m on three columns, 64
    returns, became the plane of the 14 of its middle column, a false fitting).

    ``sums`` (optional, :func:`_curved_sums` of these labels and of the models of ``fits``):
    a region whose model's rms by those sums is within the noise by more than their rounding
    could move it is not measured again (it is not beyond the noise)."""
    from ..fitting.classify import INLIER_FACTOR, plane_threshold

    p = ctx.fitter.params
    if not curved or not {"plane_rms", "noise_floor", "rms_per_range2"} <= set(p):  # another plugin
        return {}
    inside, width = None, labels.shape[1]
    out = {}
    for k, idx in (pixels or _Pixels(labels)).of(curved).items():
        sigma = ctx.sigma[idx]
        # (the rms noise is no less than the least noise, but for the rounding of its mean:
        # within that noise less SCREEN_SLACK the model is within its own, without the mean)
        if sums is not None and _model_surely_within(sums, k, idx.size, float(sigma.min()) * (1.0 - SCREEN_SLACK)):
            continue
        noise = float(np.sqrt(np.mean(sigma ** 2)))
        if sums is not None and _model_surely_within(sums, k, idx.size, noise):
            continue
        model, points = fits[k], rows_at(ctx.xyz, idx)
        squares = model.distances(points) ** 2
        if not beyond_noise(float(np.sqrt(np.mean(squares))), noise, idx.size):
            continue
        if inside is None:  # (one pass over the grid, only where a curved model is beyond the noise)
            inside = _interior(labels, ctx.wrap_columns).ravel()
        inner = inside[idx]
        n = int(np.count_nonzero(inner))
        if n < max(int(p.get("min_points", 10)), 10):
            continue
        if min(lines_beside(idx[inner], width, True), lines_beside(idx[inner], width, False)) < 2:
            continue  # the inner pixels on one grid line: any plane through that line fits them
        centroid = points[inner].mean(axis=0)
        tolerance = plane_threshold(n, centroid, plane_rms=p["plane_rms"], noise_floor=p["noise_floor"],
                                    rms_per_range2=p["rms_per_range2"])
        plane = fit_plane(points[inner], inlier_distance=INLIER_FACTOR * tolerance)
        if not plane or plane.rms > tolerance:
            continue
        if curvature_resolved(squared_distances(plane, points[inner]), float(np.sum(squares[inner])), n,
                              EXTRA_PARAMETERS[model.kind]):
            continue
        claimed, through = _seen_through(ctx, labels, k, idx, model)
        if 2 * through > claimed:
            out[k] = plane
    return out


def under_range_noise(sigma: float, n: int) -> float:
    """The rms under which a plane's ``n`` returns of range noise ``sigma`` are surely not
    facing the sensor: ``sigma`` times the square root of the chi-square law's lower bound,
    ``NOISE_CHI2_SIGMAS`` deviations under its mean (``1 - 3 sqrt(2 / (n - 3))``; 0 when that is
    not positive). A return errs along its ray, so its distance to its plane carries the range
    noise times the incidence cosine: below this rms the returns lie on a plane seen obliquely
    (or over fewer independent samples than ``n``)."""
    if sigma < 0 or n < 0:
        raise ValueError(f"sigma and n must be non-negative; got sigma={sigma}, n={n}")
    low = 1.0 - NOISE_CHI2_SIGMAS * np.sqrt(2.0 / max(n - 3.0, 1.0))
    return float(sigma * np.sqrt(low)) if low > 0.0 else 0.0


#: The fewest grid lines across, line by line (:func:`lines_beside`), on which returns show a
#: bend: two lines of returns along a column's axis are parallel, so two lines fit a plane
#: whatever the surface's curvature (:func:`bent_at_border_lines`).
BEND_LINES = 3


def border_sides(labels: np.ndarray, idx: np.ndarray, wrap_columns: bool) -> np.ndarray:
    """``(4, len(idx))`` for the pixels ``idx`` (flat, one region's) of ``labels`` (H, W):
    whether the neighbour above, below, left and right of each is outside their region
    (off the grid counts as outside; across the seam on a 360-degree grid it does not).
    The region's label is that of ``idx[0]``. Each row of the answer is one side's border."""
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise ValueError(f"labels must be (H, W); got shape {labels.shape}")
    idx = np.asarray(idx, dtype=np.int64)
    if idx.ndim != 1 or idx.size == 0:
        raise ValueError(f"idx must be a non-empty 1-D array of flat pixel indices; got shape {idx.shape}")
    h, w = labels.shape
    flat = labels.ravel()
    own = flat[idx[0]]
    r, c = np.divmod(idx, w)
    out = np.ones((4, idx.size), dtype=bool)
    steps = ((r - 1, c, r > 0), (r + 1, c, r < h - 1))
    if wrap_columns:
        steps += ((r, (c - 1) % w, np.ones(idx.size, bool)), (r, (c + 1) % w, np.ones(idx.size, bool)))
    else:
        steps += ((r, c - 1, c > 0), (r, c + 1, c < w - 1))
    for side, (rr, cc, on_grid) in enumerate(steps):
        out[side, on_grid] = flat[rr[on_grid] * w + cc[on_grid]] != own
    return out


#: The margin by which :func:`_one_side_flat`'s moments pass a rest: their rounding differs from
#: the points' by far less (``SUMS_MARGIN``), and the points decide.
ONE_SIDE_MARGIN = 1.01


def _one_side_flat(ctx: Context, labels: np.ndarray, curved: list, minimum: int) -> set:
    """The regions among ``curved`` of which the region less one side (:func:`border_sides`)
    of at least ``minimum`` pixels leaves its least-squares plane an rms within what the largest
    range noise gives a plane (``noise_rms_bound`` at ``NOISE_CHI2_SIGMAS``, within
    ``ONE_SIDE_MARGIN``), by one compiled pass over the label image (``kernels.side_rest_planes``):
    a rest's noise along its rays is at most that, so :func:`bent_at_border_lines` frees no
    other region by one side and gathers the points of those alone."""
    if not curved:
        return set()
    wanted = np.zeros(max(curved) + 1, bool)
    wanted[list(curved)] = True
    counts, rms = kernels.side_rest_planes(ctx.xyz, np.ascontiguousarray(labels.ravel()),
                                           labels.shape[1], wanted, bool(ctx.wrap_columns))
    largest = _largest_finite(ctx.sigma)  # (no noise where no return)
    if largest is None:
        return set()
    counts, rms = counts[curved], rms[curved]
    bound = noise_rms_bound.py_func(largest, counts - 3.0, NOISE_CHI2_SIGMAS)
    flat = ((counts >= minimum) & (rms <= ONE_SIDE_MARGIN * bound)).any(axis=1).tolist()
    return {int(k) for k, one in zip(curved, flat) if one}


def _largest_finite(values: np.ndarray):
    """The largest finite value of ``values`` (1-D float), None when there is none: their
    maximum where it is finite (no NaN and no infinity is larger), without the mask of the
    finite ones (a laser's noise has no NaN)."""
    if values.size == 0:
        return None
    top = float(values.max())
    if np.isfinite(top):
        return top
    finite = values[np.isfinite(values)]
    return float(finite.max()) if finite.size else None


#: The widest arc around its axis (radians) a cylinder bounded by two jump edges may show and its
#: bend still be taken for mixed returns along both (:func:`bent_at_border_lines`): a convex
#: cylinder seen from outside shows the sensor about half a turn between its limbs, so a region of
#: a pipe whose two sides are its limbs spans far more than half of that.
TWO_SIDES_ARC = 0.5 * np.pi


def bent_at_border_lines(ctx: Context, labels: np.ndarray, curved: dict, samples: float = 0.0, *,
                         kept=(), pixels: _Pixels | None = None) -> dict:
    """The planes of the regions of ``curved`` (label -> a curved model: the region's, or the one
    the fitter's decision gives a plane region) whose bend rests on the returns of border grid
    lines alone, on a laser's single returns. A side is one grid line's returns along the
    region's border (:func:`border_sides`: above, below, left, right). The decision is the
    fitter's, once, on the region less the sides whose returns lie off the rest's plane beyond
    their range noise: one side, or two opposite ones. For a candidate (each side, each opposite
    pair; the flattest rest first) the rest must span at least ``BEND_LINES`` grid lines both
    ways, line by line (:func:`lines_beside`); its least-squares plane must be within the
    fitter's plane threshold and leave it no more than its range noise along its rays gives a
    plane (:func:`_ray_noise`, up to the noise floor's ``NOISE_CHI2_SIGMAS`` chi-square
    deviations); each dropped side's returns must lie off that plane by more than their range
    noise explains (:func:`beyond_noise`); and the fitter's decision on the rest
    (``resolve_bends=samples``) must be a plane, which becomes the answer. A pipe's two limbs lie
    off the plane of its front as mixed returns do, so a bend on one side is one side's only
    when the opposite side's returns do not lie off the plane of the returns between the two
    (where those span ``BEND_LINES`` lines both ways; where they do not, on a curved region's own
    model, when the rest's plane leaves it under :func:`under_range_noise`: seen obliquely, as a
    pipe's front is not), and a
    bend on two sides is theirs only on a cylinder spanning less than ``TWO_SIDES_ARC`` around
    its axis (``arc_around_axis``). A curved region whose own plane is over the plane threshold is
    asked so; one whose plane is within it (:func:`_unbent`'s question, which keeps it curved where
    its bend is resolved) is asked one side only (two, pipes of 0.1-0.16 m seen on five rows
    across their axis, whose fits leave a shallow arc, were freed: nodding_1deg seeds 37, 1015,
    1016), and only where its cylinder spans less than ``TWO_SIDES_ARC`` or the side's returns,
    most of them, lie behind the model's own front along their rays (:func:`behind_own_front`):
    pipes of 0.09-0.1 m facing the sensor under 20-30 mm of noise span 164-168 degrees with every
    return on their near half (noise_20mm seed 0 scan 7, spinning_32x1024 seed 0 scan 0: freed on
    one side without that test), while a face's row of mixed returns bends a shallow arc
    (nodding_0.5deg seed 37 scan 5: 12 returns 3.5 sigmas behind a face at 4.4 m, a 0.29 m
    cylinder over 52 degrees) or lands on a far half (spinning_64x1024 seed 709 scan 2: the top
    row, 6 returns of the face above, on the far half of a 0.09 m cylinder). A curved region
    freed becomes the rest's plane. The regions of ``kept``
    (plane regions the decision bends, whose plane polish keeps) are asked one side only: the arc
    of the decision's cylinder on a region found a plane tells no pipe from a face (noise_10mm
    seed 17 scan 0, a 0.22 m pipe on 10 rows, 24 columns, its cylinder shallow).

    A return whose footprint a jump edge crosses is mixed, lying along its ray between the face
    and what lies beyond its edge, many range sigmas off both: a column of them bends a face a
    few columns wide like a cylinder that explains it within the range noise, on one side
    (noise_10mm seed 17 scan 3: a face 3 columns wide at 5.2 m seen at 57 degrees, 20 mixed
    returns 6-8 sigmas behind it, a 1.26 m cylinder at 6.1 mm rms; noise_20mm seed 1014 scan 1:
    a face 6 columns wide whose plane is within the noise, bent by the decision's bend test) or
    on both (noise_20mm seed 1021 scan 3: a face at cos 0.51 between columns 1 and 3.6 sigmas
    behind it, a 2.5 m cylinder over 31 degrees). A pipe's bend is in the returns between its
    limbs too, which the fitter's decision and the ray-noise bound see; where the noise hides
    it there (a 0.1-0.2 m pipe under 10-20 mm noise) the far limb's offset, or on two sides the
    arc, tells: a pipe whose two sides are its limbs spans about half a turn (118-278 degrees
    on noise_20mm seeds 1001-1040), a face's mixed returns bend a wide cylinder over a shallow
    arc (31-102 degrees for five of seven such faces there). Two lines of returns along a
    column's axis are parallel and fit a plane whatever the bend, hence ``BEND_LINES``
    (noise_20mm seed 17 scan 5: a 0.13 m column seen on two columns).

    ``pixels`` (optional) the labels' grouped pixels. Cost per region: its arc when a cylinder
    (a compiled pass over every fourth return first), its sides and six rest-plane rms by one
    batch of scatter matrices; a plane fit, a ray-noise bound and a decision per passing
    candidate."""
    from ..fitting.classify import INLIER_FACTOR, plane_threshold

    p = ctx.fitter.params
    if not curved or not {"plane_rms", "noise_floor", "rms_per_range2"} <= set(p):  # another plugin
        return {}
    minimum = max(int(p.get("min_points", 10)), 10)
    bends = {"resolve_bends": float(samples)} if samples else {}
    width = labels.shape[1]

    def threshold(n, centroid):
        return plane_threshold(n, centroid, plane_rms=p["plane_rms"], noise_floor=p["noise_floor"],
                               rms_per_range2=p["rms_per_range2"])

    def spans(rest):  # grid lines both ways, line by line
        return min(lines_beside(rest, width, True), lines_beside(rest, width, False)) >= BEND_LINES

    def off(plane, points, idx, side):  # the side's returns off the plane beyond their range noise
        return side.sum() >= 3 and beyond_noise(float(np.sqrt(np.mean(plane.distances(points[side]) ** 2))),
                                                 float(np.sqrt(np.mean(ctx.sigma[idx[side]] ** 2))), int(side.sum()))

    one_side = _one_side_flat(ctx, labels, list(curved), minimum)
    out = {}
    for k, idx in (pixels or _Pixels(labels)).of(list(curved)).items():
        if idx.size < 2 * minimum:
            continue
        model = curved[k]
        # two sides only on a shallow cylinder of the region's own (every fourth return first: a
        # subset's largest gap is no narrower, so its arc is no wider than all the returns')
        shallow = isinstance(model, Cylinder) and k not in kept and arc_around_axis(
            rows_at(ctx.xyz, idx[::4]), model.axis, model.point) < TWO_SIDES_ARC
        if not (shallow or k in one_side):
            continue  # no candidate could pass
        points = rows_at(ctx.xyz, idx)
        if shallow:
            shallow = arc_around_axis(points, model.axis, model.point) < TWO_SIDES_ARC
        centroid = points.mean(axis=0)
        sides = border_sides(labels, idx, ctx.wrap_columns)
        # candidates 0-3 one side each, 4-5 two opposite ones (a pixel on both: the first)
        dropped = np.vstack([sides, sides[0] | sides[1], sides[2] | sides[3]])
        _, sizes, means, rms = _plane_rms_without_each_side(points - centroid, dropped)
        hidden = None  # (a region whose plane is within the threshold: which returns its model's front hides)
        if k not in kept and rms[0] <= threshold(idx.size, centroid):
            # _unbent's question, answered for the region, unless one border line carries the bend:
            # one side only, where the model is a shallow arc or hides the side's returns behind its front
            if k not in one_side:
                continue
            hidden = behind_own_front(ctx, idx, points, model)
            if not (shallow or hidden.any()):
                continue
        for c in np.argsort(rms[1:]):  # the flattest rest first
            n, rest = int(sizes[c + 1]), ~dropped[c]
            if n < minimum or not (shallow and hidden is None if c >= 4 else k in one_side) or not spans(idx[rest]):
                continue
            if hidden is not None and not (shallow or 2 * np.count_nonzero(hidden & dropped[c]) > dropped[c].sum()):
                continue  # a pipe's limb is on its near half: within the threshold, its bend is _unbent's
            tolerance = threshold(n, centroid + means[c + 1])
            if rms[c + 1] > tolerance:
                continue
            plane = fit_plane(points[rest], inlier_distance=INLIER_FACTOR * tolerance)
            if not plane or plane.rms > tolerance:
                continue
            first = c if c < 4 else 2 * (c - 4)  # (the side dropped, or the first of the two)
            near, far = sides[first], sides[first ^ 1] & ~sides[first]
            if not off(plane, points, idx, near):
                continue
            if c >= 4:
                if not off(plane, points, idx, far):
                    continue  # the bend is not on both sides
            else:
                middle = rest & ~far
                if middle.sum() >= minimum and spans(idx[middle]):
                    # the far side against the plane between the two sides: a plane through it as
                    # well leans to it (a pipe seen head-on: its far limb on that plane)
                    between = fit_plane(points[middle], inlier_distance=INLIER_FACTOR * tolerance)
                    if not between or off(between, points, idx, far):
                        continue  # the bend is not that side's alone
                elif k in kept or not rms[c + 1] < under_range_noise(float(np.sqrt(np.mean(ctx.sigma[idx[rest]] ** 2))), n):
                    continue  # too few lines between to tell, and the bend the decision's (noise_20mm seed 13
                    # scan 0: a 0.12 m pipe seen head-on) or the rest facing the sensor as a pipe's front
            _, noise, _ = _ray_noise(points[rest], ctx.sigma[idx[rest]], plane, ctx.viewing_rays(idx[rest]))
            if plane.rms > noise_rms_bound.py_func(noise, n - 3.0, NOISE_CHI2_SIGMAS):
                continue  # more than its returns' range noise leaves a plane (its noise floor): a bent arc's
            if isinstance(ctx.fitter.fit(points[rest], **bends), Plane):
                out[int(k)] = plane
                break
    return out


def lines_beside(idx: np.ndarray, width: int, rows: bool) -> float:
    """The median count of the flat pixels ``idx`` (of a grid ``width`` wide) on each grid column
    that holds any (``rows``: how many rows deep the region is, across a side above or below
    it) or on each grid row (how many columns wide, across a side left or right of it): the
    grid lines across the region beside that side, line by line. A band crossing the grid
    diagonally spans many columns but is as wide as its rows' runs (noise_20mm seed 1020 scan 5:
    a 0.29 m pipe's band 2-3 pixels wide drifting over 6 columns)."""
    line = idx % width if rows else idx // width
    _, counts = np.unique(line, return_counts=True)
    return float(np.median(counts)) if counts.size else 0.0


def _plane_rms_without_each_side(centred: np.ndarray, sides: np.ndarray) -> tuple:
    """``(weights, sizes, means, rms)`` of the region's points (``centred`` on its centroid;
    row 0) and of each rest, the region less one of the four ``sides`` (rows 1-4: above, below,
    left, right): the rests' means about the centroid and their least-squares plane rms, from
    one batch of scatter matrices rather than a fit per rest."""
    weights = np.vstack([np.ones((1, centred.shape[0])), ~sides]).astype(np.float64)
    sizes = weights.sum(axis=1)
    means = (weights @ centred) / np.maximum(sizes, 1.0)[:, None]
    scatter = np.einsum("sn,ni,nj->sij", weights, centred, centred) - sizes[:, None, None] * (
        means[:, :, None] * means[:, None, :])
    rms = np.sqrt(np.maximum(np.linalg.eigvalsh(scatter)[:, 0], 0.0) / np.maximum(sizes, 1.0))
    return weights, sizes, means, rms


def _seen_through(ctx: Context, labels: np.ndarray, k: int, idx: np.ndarray, model) -> tuple[int, int]:
    """``(claimed, through)``: of the valid pixels beside region ``k`` (4-neighbours outside
    it, across the seam on a 360-degree grid), those whose ray (from where the sensor's
    rays start, :meth:`Context.ray_origins`) meets ``model`` (a cylinder: within the axial
    span of the region's pixels, an end being an edge) and returns no nearer than
    ``CHI_SQUARE_SIGMAS`` range sigmas in front of it, and how many of them return from
    that far beyond it."""
    mine = labels == k
    near = mine.copy()
    for neighbour in _four_neighbours(mine, ctx.wrap_columns, False):
        near |= neighbour
    flat_valid = np.isfinite(ctx.xyz).all(axis=1)
    beside = np.flatnonzero(near.ravel() & ~mine.ravel() & flat_valid)
    if beside.size == 0:
        return 0, 0
    start, rays, ranges, front, hit = _front_meeting(ctx, beside, rows_at(ctx.xyz, beside), model)
    if isinstance(model, Cylinder):
        along = (start + front[:, None] * rays - model.point) @ model.axis
        own = (ctx.xyz[idx] - model.point) @ model.axis
        hit &= (along >= own.min()) & (along <= own.max())
    margin = CHI_SQUARE_SIGMAS * ctx.sigma[beside]
    through = hit & (ranges - front > margin)
    claimed = hit & ~(front - ranges > margin)  # (a nearer surface in front of it tells nothing)
    return int(np.count_nonzero(claimed)), int(np.count_nonzero(through))


def _front_meeting(ctx: Context, idx: np.ndarray, points: np.ndarray, model) -> tuple:
    """``(start, rays, ranges, front, hit)`` for the returns ``points`` of the flat pixels
    ``idx``: where their rays start (:meth:`Context.ray_origins`, else the origin), and
    :func:`rangeseg_o3d.fitting.primitives.front_along_rays` from there."""
    origins = ctx.ray_origins(idx)
    start = np.zeros((idx.size, 3)) if origins is None else origins
    return (start, *front_along_rays(model, points, start))


def behind_own_front(ctx: Context, idx: np.ndarray, points: np.ndarray, model) -> np.ndarray:
    """Per return of the flat pixels ``idx`` (``points`` their rows of ``ctx.xyz``), whether
    its ray, from a start outside the cylinder or sphere ``model``, first meets the model more
    than ``CHI_SQUARE_SIGMAS`` range sigmas (``ctx.sigma``) nearer than the return: the
    model's own near half stands in front of it along the ray, so an opaque surface of that
    shape returns the ray there and not at the return. A model that put such returns on its
    far half took returns of something else (spinning_64x1024 seed 709 scan 2: a face's
    cylinder whose top row, 6 returns of the face above, lies on its far half)."""
    idx = np.asarray(idx, dtype=np.int64)
    points = np.asarray(points, dtype=np.float64)
    if points.shape != (idx.size, 3):
        raise ValueError(f"points must be (len(idx), 3) = ({idx.size}, 3); got shape {points.shape}")
    if not isinstance(model, (Cylinder, Sphere)):
        raise ValueError(f"model must be a Cylinder or a Sphere; got {type(model).__name__}")
    _, _, ranges, front, hit = _front_meeting(ctx, idx, points, model)
    return hit & (ranges - front > CHI_SQUARE_SIGMAS * ctx.sigma[idx])


def _curved_planes(ctx: Context, labels: np.ndarray, fits: dict, resolve_bends: float = 0.0, *,
                   pixels: _Pixels | None = None, grazing_flat: bool = False,
                   refused_planes: bool = False) -> dict:
    """The curved models the fitter's decision gives the plane regions of ``labels`` whose
    final pixels it no longer settles as a plane.

    A region's kind is decided once, on the pixels it had then (a split's trimmed piece, a
    region before growth, the larger of two pieces a join put together); planes are refitted
    from moments as their regions change, keeping their kind. On the final pixels the
    batch plane test (:meth:`RegionFitter.fit_batch`: the fitter's own plane tolerance and
    quadric curvature test, one pass) settles almost every plane again; only the others
    are decided anew, and a curved answer replaces the plane (a pipe whose first piece was
    flat within the noise, grown to its whole width). With ``resolve_bends`` (the
    independent samples each pixel carries) a plane within the noise is also decided anew
    where its quadric resolves a bend over them all the same (a pipe seen on a narrow arc,
    its bend under the noise over hundreds of pixels), and so is one beyond what the noise
    gives its pixels (the decision's marginal plane: a pipe's plane over a camera's noise
    but under the preset's plane_rms); earlier decisions, on pieces and unsettled
    regions, do not ask it. ``pixels`` (optional): the labels' grouped pixels. With
    ``grazing_flat`` (a laser's single returns) a plane seen near grazing is not decided anew
    (:func:`_seen_near_grazing`). With ``refused_planes`` (a laser's single returns) a
    region whose plane the decision refuses with its curved models gets the curved model
    within the noise that resolves its curvature (:func:`_curved_over_refused_plane`)."""
    planes = [k for k, m in fits.items() if isinstance(m, Plane)]
    if not planes or ctx.fitter.plugin.fit_batch is None:  # a plugin without the batch test: as decided
        return {}
    bends = {"resolve_bends": float(resolve_bends)} if resolve_bends else {}  # a keyword of the primitives fitter
    settled = ctx.fitter.fit_batch(ctx.xyz, labels, **bends)
    unsettled = [k for k in planes if k not in settled]
    out = {}
    for k, idx in (pixels or _Pixels(labels)).of(unsettled).items():
        if grazing_flat and _seen_near_grazing(ctx, fits[k], idx):
            continue
        decided = ctx.fitter.fit(ctx.fitter.points(ctx.xyz, idx), **bends)
        if not decided and refused_planes:  # (no model: the region would keep its plane)
            decided = _curved_over_refused_plane(ctx, idx, bends)
        if decided and not isinstance(decided, Plane):
            out[k] = decided
    return out


def _curved_over_refused_plane(ctx: Context, idx: np.ndarray, bends: dict):
    """The curved model of a laser's returns ``idx`` whose plane the fitter's decision
    refuses (over its threshold) and whose curved models it refuses only for a gain under
    ``curvature_gain``, when the model is within the range noise and resolves its curvature
    over the plane (the F-test, one sample a return); else None.

    ``curvature_gain`` asks a curved model to beat an acceptable plane by a margin; where
    the plane is no answer the decision leaves the region no model at all and it keeps the
    plane it had, over its threshold (spinning_32x1024 seed 709 scan 3: a 0.15 m pipe at
    3.5 m, plane 34.8 mm over its 33.7 mm threshold, cylinder r 0.126 m at 24.2 mm under the
    30 mm noise, gain 1.44)."""
    if "curvature_gain" not in ctx.fitter.params:  # another plugin
        return None
    pts = ctx.fitter.points(ctx.xyz, idx)
    model = ctx.fitter.fit(pts, curvature_gain=1.0, **bends)
    if not model or isinstance(model, Plane):
        return None
    n = len(pts)
    plane = fit_plane(pts)
    if beyond_noise(float(model.rms), float(np.median(ctx.sigma[idx])), n):
        return None
    extra = 2 if model.kind == "cylinder" else 1
    if not curvature_resolved(n * float(plane.rms) ** 2, n * float(model.rms) ** 2, n, extra):
        return None
    return model


#: A laser's plane whose rms is under this share of the range noise is seen near grazing
#: (:func:`_seen_near_grazing`).
GRAZING_RMS_SHARE = 0.5


def _seen_near_grazing(ctx: Context, plane: Plane, idx: np.ndarray) -> bool:
    """Whether the plane of the laser returns ``idx`` leaves them an rms (``plane.rms``: the
    one of its fit, which the callers make on these returns or most of them) under
    ``GRAZING_RMS_SHARE`` of their median range noise, and so far under it that the noise of
    returns facing the sensor could not (under the ``CHI_SQUARE_SIGMAS`` lower bound of the
    chi-square spread of that many pixels' mean square). A return errs along its ray, so its
    distance to its plane carries the range noise times the incidence cosine: such a plane
    is seen more than 60 degrees from head-on (a floor or ceiling of a nodding laser's scan).
    :func:`_curved_planes` does not decide it anew: the batch left it to the decision for
    its quadric over hundreds to thousands of samples, and the decision gave a plane
    (on the laser rows of the studied seeds, 276 of the 527 decisions asked, all planes), while
    the curved surfaces the decision found there left their plane 0.7 of the noise or more
    where they had the 60 pixels this bound needs (three of 23-31 pixels left it 0.26-0.41).
    Costs a median of the noise; the decision it spares costs the curved models' fits."""
    n = idx.size
    low = 1.0 - CHI_SQUARE_SIGMAS * np.sqrt(2.0 / max(n - 3.0, 1.0))  # the mean square's lower bound
    if low <= GRAZING_RMS_SHARE * GRAZING_RMS_SHARE:
        return False
    rms, sigma = float(plane.rms), ctx.sigma[idx]
    # the median lies between the least and the largest noise (a laser's is one value): those
    # answer without the partition where they agree (NaN in the noise fails both, as it fails
    # the median's comparison)
    if rms < GRAZING_RMS_SHARE * float(sigma.min()):
        return True
    if rms >= GRAZING_RMS_SHARE * float(sigma.max()):
        return False
    return rms < GRAZING_RMS_SHARE * median(sigma)


class _CurvedSums(NamedTuple):
    """One pass over the grid for the curved regions of polish's labels (:func:`_curved_sums`):
    per label, its pixels with a finite distance to its model (``counts``) and the sum of
    their squared distances (``squares``); per row of ``rows`` (the curved labels, in the
    order given) its pixels' least-squares plane by their moments: ``count``, ``centroid``,
    ``variance`` (the smallest eigenvalue of their covariance)."""

    counts: np.ndarray
    squares: np.ndarray
    rows: dict
    count: np.ndarray
    centroid: np.ndarray
    variance: np.ndarray


def _curved_sums(ctx: Context, labels: np.ndarray, fits: dict, curved: list) -> _CurvedSums:
    """The :class:`_CurvedSums` of the curved regions ``curved`` of ``labels`` under their
    models in ``fits``: two compiled passes, the models' distances and the label-wise moments."""
    n = max(curved) + 1
    flat_labels = np.ascontiguousarray(labels.ravel(), dtype=np.int32)
    kinds, params, rms = model_table({k: fits[k] for k in curved}, n)
    _, squares, counts = kernels.distance_stats(ctx.xyz, flat_labels, kinds, params, rms,
                                                np.ascontiguousarray(ctx.sigma, dtype=np.float64), 3.0)
    members = np.zeros(n, np.bool_)
    members[curved] = True
    moments = kernels.member_moments(ctx.xyz, flat_labels, members)[curved]  # (label_moments' rows, the curved alone)
    centroid, _, _, eigvals, _, _ = kernels.planes_from_moment_rows(moments)
    return _CurvedSums(counts, squares, {k: i for i, k in enumerate(curved)}, moments[:, 0], centroid,
                       eigvals[:, 0])


def _still_flat(ctx: Context, labels: np.ndarray, fits: dict, curved: list, *,
                sums: _CurvedSums | None = None) -> list:
    """The curved regions among ``curved`` whose model does not lower their pixels' least-
    squares plane's sum of squared distances by more than noise would (the F-test of
    :func:`rangeseg_o3d.fitting.robust.curvature_resolved`), from :func:`_curved_sums` (``sums``
    when the caller has them)."""
    sums = _curved_sums(ctx, labels, fits, curved) if sums is None else sums
    counts, curved_squares = sums.counts, sums.squares
    return [k for k, plane_variance in zip(curved, sums.variance) if counts[k] > 3 and not curvature_resolved(
        plane_variance * counts[k], curved_squares[k], int(counts[k]), EXTRA_PARAMETERS[fits[k].kind])]


#: How far (relative) a plane's rms or a model's, measured from sums over a region's pixels
#: (moments, a compiled pass's squared distances), must clear a threshold for a pre-test to
#: answer for the fit on the gathered points: their roundings differ by under 1e-8
#: relative (the moments' covariance cancels at most range^2 / variance, 6e-8 at 80 m for
#: a 5 mm rms); the regions nearer their threshold are measured as before.
SUMS_MARGIN = 1e-4


#: The largest share of a curved region's pixels that may lie off its model (beyond
#: ``TRIM_SIGMAS`` of their noise) and be left out of :func:`_bent_but_for_strays`' F-test.
STRAY_SHARE = 0.05


def _bent_but_for_strays(ctx: Context, idx: np.ndarray, model) -> bool:
    """Whether ``model`` resolves a curvature over the pixels ``idx`` of its region (the F-test
    of :func:`_still_flat`) once the few pixels it leaves beyond ``TRIM_SIGMAS`` noise sigmas
    are left out (at most ``STRAY_SHARE`` of them, at least one); False when there are none
    or more.

    One stray pixel of a neighbouring surface far off the curved model outweighs the plane
    the F-test weighs it against: spinning_64x1024 study seed 1392 scan 1, a column of r
    0.23 m at 6 m, its cylinder r 0.226 m at 14.6 mm rms (the fit's 398 inliers), its region of
    404 px holding two ceiling returns in its top row, 0.08 and 0.82 m off it: the squares
    over all 404 are 0.77 for the cylinder, 0.34 for the plane, and the column became a plane."""
    points = rows_at(ctx.xyz, idx)
    distances = model.distances(points)
    near = np.abs(distances) <= TRIM_SIGMAS * ctx.sigma[idx]
    kept = int(np.count_nonzero(near))
    if kept == idx.size or idx.size - kept > STRAY_SHARE * idx.size or kept <= 3:
        return False
    plane = fit_plane(points[near])
    if not plane:
        return False
    plane_squares = squared_distances(plane, points[near])
    return curvature_resolved(plane_squares, float(np.sum(distances[near] ** 2)), kept, EXTRA_PARAMETERS[model.kind])


def _plane_surely_over(ctx: Context, sums: _CurvedSums, k: int, size: int) -> bool:
    """Whether the least-squares plane of region ``k``'s ``size`` pixels is over the fitter's
    plane threshold by more than ``SUMS_MARGIN``, by its moments (:func:`_unbent`'s test,
    without gathering the points); False when the fitter would subsample them or the sums do
    not hold all of them."""
    from ..fitting.classify import plane_threshold

    row = sums.rows.get(k)
    if row is None or sums.count[row] != size or ctx.fitter.kept(size, size) != size:
        return False
    p = ctx.fitter.params
    tolerance = plane_threshold(size, sums.centroid[row], plane_rms=p["plane_rms"], noise_floor=p["noise_floor"],
                                rms_per_range2=p["rms_per_range2"])
    return bool(float(np.sqrt(sums.variance[row])) > (1.0 + SUMS_MARGIN) * tolerance)


def _model_surely_within(sums: _CurvedSums, k: int, size: int, noise: float) -> bool:
    """Whether region ``k``'s model leaves its ``size`` pixels an rms under the noise bound
    of :func:`rangeseg_o3d.fitting.robust.beyond_noise` by more than ``SUMS_MARGIN``, by the
    compiled sums of their squared distances (:func:`_bent_by_border`'s first test); False
    when the sums do not hold all of them."""
    if k not in sums.rows or sums.counts[k] != size or size == 0:
        return False
    rms = float(np.sqrt(sums.squares[k] / size))
    return bool(rms < (1.0 - SUMS_MARGIN) * noise_rms_bound.py_func(noise, float(size), CHI_SQUARE_SIGMAS))


#: Chi-square deviations beyond which a plane's distances are not its range noise along the
#: rays (:func:`_planes_off_rays`; the decision's CHI_SQUARE_SIGMAS), and within which a
#: curved model's are (its NOISE_CHI2_SIGMAS, as a plane's noise floor).
OFF_RAYS_SIGMAS = 4.0
WITHIN_RAYS_SIGMAS = 3.0


#: The least incidence cosine a distance's noise is taken at (a ray grazing the surface:
#: there the first-order noise sigma x cosine is no bound).
RAY_COS_FLOOR = 0.1


def _ray_noise(points: np.ndarray, sigma: np.ndarray, model, rays: np.ndarray, each: bool = False) -> tuple:
    """``(rms, noise, chi)``: the rms distance of ``points`` to ``model``, the rms distance a
    range noise ``sigma`` (per point) along the viewing ``rays`` gives them about that surface
    (:func:`rangeseg_o3d.fitting.robust.distance_noise`, floored at ``RAY_COS_FLOOR``), and
    the mean square of each distance over its own noise (``each``: those squares, per point)."""
    distances, noise = model.distances(points), distance_noise(model, points, sigma, rays)
    noise = np.maximum(noise, RAY_COS_FLOOR * sigma)
    chi = (distances / noise) ** 2
    chi = chi if each else float(np.mean(chi))
    return float(np.sqrt(np.mean(distances * distances))), float(np.sqrt(np.mean(noise * noise))), chi


def _planes_off_rays(ctx: Context, labels: np.ndarray, fits: dict, *, pixels: _Pixels | None = None) -> dict:
    """The curved models of the plane regions of ``labels`` whose distances are beyond what
    the range noise along the rays (``ctx.sigma``) gives a plane, ``OFF_RAYS_SIGMAS`` up its
    chi-square and bulging towards the sensor about the plane of their points within that
    noise (:func:`_bent_off_rays`), where the fitter's curved model (its plane refused), a cylinder refitted in range residuals
    (:func:`_cylinder_along_rays`, its arc then held to the fitter's ``min_arc_deg``), is
    within what that noise gives that surface, ``WITHIN_RAYS_SIGMAS`` up, and resolves its
    curvature over the plane that noise fits best (:func:`_plane_along_ray_noise`).
    Streaks of range noise (:func:`_streak_along_rays`) are not asked.

    The fitter judges a plane by its rms against the range noise itself; a plane seen
    obliquely keeps most of that noise within itself, and least squares lays a plane along
    the rays through a pipe's limb, whose range noise then hides its bend (spinning_128x2048
    seed 89 scan 0: a 25 cm pipe at 3.4 m seen on 5 columns, plane rms 4.4 mm where its
    1 cm noise gives 3.2 and the fitter's cylinder spans 25 degrees, under its 30; along the
    rays 20-26 cm over 33-39 degrees; spinning_32x1024 seed 89 scan 3: an 18 cm pipe at
    4.2 m on 6 columns under 3 cm noise). The 16 cm pipe of its scan 1, seen on 3 columns,
    stays a plane: its sagitta across them, 2 mm, is no bend that noise resolves. A floor
    seen at grazing incidence whose pixels hold a few mixed returns is over its noise too,
    but shows no such bulge, and is not searched (09d5a01 searched it, and cost the LMS200
    half again its time). Only
    planes within the range noise itself are asked: over it the fitter's decision has tried
    the curved models against the plane already (its marginal plane). ``pixels`` (optional):
    the labels' pixels, read where grouped already."""
    p = ctx.fitter.params
    if not {"plane_rms", "noise_floor", "curvature_gain"} <= set(p):  # another plugin
        return {}
    suspects = _planes_over_rays(ctx, labels, fits, max(int(p.get("min_points", 10)), 10))
    if not suspects:
        return {}
    refused_plane = {**p, "plane_rms": 0.0, "noise_floor": 0.0, "curvature_gain": 1.0}
    # the arc is judged on the model fitted along the rays (below): least squares in plain
    # distances bends a pipe's limb seen at grazing incidence wider and flatter than it is
    open_arc = {**refused_plane, "min_arc_deg": ARC_SEARCH_DEG}
    min_arc = np.radians(float(p.get("min_arc_deg", MIN_ARC_DEG)))
    out = {}
    flat = labels.ravel()
    grouped = pixels.every if pixels is not None and pixels.grouped else None
    for k in suspects:  # (a few: polish's grouping where made, else one comparison over the grid each)
        idx = grouped[k] if grouped is not None else np.flatnonzero(flat == k)  # (the same, increasing)
        if not _bent_off_rays(ctx, idx):
            continue
        points, sigma, rays = rows_at(ctx.xyz, idx), ctx.sigma[idx], ctx.viewing_rays(idx)
        if _streak_along_rays(points, sigma, rays):
            continue
        curved = ctx.fitter.plugin.run(ctx.fitter.points(ctx.xyz, idx), **open_arc)
        if not curved or isinstance(curved, Plane):
            continue
        if isinstance(curved, Cylinder):
            curved, chi_c = _cylinder_along_rays(points, sigma, curved, ctx.ray_origins(idx))
            if curved is None or curved.radius > float(p.get("max_radius", np.inf)) or not (
                    arc_around_axis(points, curved.axis, curved.point) >= min_arc):
                continue
        else:  # a sphere: its cap as the fitter judges it
            curved = ctx.fitter.plugin.run(ctx.fitter.points(ctx.xyz, idx), **refused_plane)
            if not isinstance(curved, Sphere):
                continue
            rms, noise, chi_c = _ray_noise(points, sigma, curved, rays)
        extra = EXTRA_PARAMETERS[curved.kind]
        if np.sqrt(chi_c) > noise_rms_bound.py_func(1.0, idx.size - 3.0 - extra, WITHIN_RAYS_SIGMAS):
            continue
        # the curvature must be resolved over the plane the noise along the rays fits best,
        # not only over the least-squares plane (chi-squares in that noise, an F-test of
        # known variance)
        _, _, chi_p = _ray_noise(points, sigma, _plane_along_ray_noise(points, sigma, fits[k], rays), rays)
        drop = idx.size * (chi_p - chi_c)
        if drop > extra + OFF_RAYS_SIGMAS * np.sqrt(2.0 * extra):
            out[k] = curved
    return out


#: Times the plane of a suspect's pixels is refitted to those within ``TRIM_SIGMAS`` of
#: it (:func:`_bent_off_rays`).
TRIM_REFITS = 3


def _bent_off_rays(ctx: Context, idx: np.ndarray) -> bool:
    """Whether the pixels ``idx`` bulge towards the sensor beyond the range noise along
    their rays (``ctx.sigma``; the rays from where the sensor's start): about the plane
    refitted ``TRIM_REFITS`` times to the pixels within ``TRIM_SIGMAS`` of that noise (per
    pixel, times its incidence cosine), their distances grow with the square of their
    coordinate across the pixels' narrow direction by more than ``OFF_RAYS_SIGMAS``
    standard errors (:func:`rangeseg_o3d.kernels.band_bend`); or fewer than half of them
    lie within the band.

    A pipe's limb seen from outside at grazing incidence bends in every point, its middle
    nearer the sensor than its sides (spinning_128x2048 seed 89 scan 0: 14.6 standard
    errors; spinning_32x1024 seed 89 scan 3: 4.8; the synthetic limb of
    tests/refinement/test_polish.py 6-10). A laser's mixed returns where a jump edge or a
    crease crosses its beam footprint lie along their rays between the plane and the nearer
    surface: near grazing, where a floor's distance noise is a millimetre, the 5-30 % of
    them along its edges put its least-squares plane off that noise (LMS200 suite: every
    floor and ceiling, cosine 0.2-0.4, mean squares 1.7-13 in their noise, which is what
    cost 09d5a01 its time), but about the band's plane a floor shows no bend (-3 to 1.4
    standard errors, seeds 0 and 1) and a ceiling lined by a row of them an edge nearer
    than its middle (-7 to -10). Flat strips of a spinning lidar under 3 cm of noise: -1.8
    to 1.7. A few compiled passes over the pixels and a 4 x 4 solve: cheap beside the
    curved models' search, which it spares the planes of a laser's scan."""
    kept, _, bend = kernels.band_bend(
        ctx.xyz, np.ascontiguousarray(idx, dtype=np.int64), np.ascontiguousarray(ctx.sigma, dtype=np.float64),
        _origin_rows(ctx), ctx.width, TRIM_REFITS, TRIM_SIGMAS, RAY_COS_FLOOR)
    # (fewer than half of them within the band: not a plane in its noise, asked)
    return 2 * kept < idx.size or bend > OFF_RAYS_SIGMAS


#: The least arc (degrees) the fitter's cylinder may span to be refitted along the rays,
#: whose arc is then held to the fitter's own min_arc_deg: half of MIN_ARC_DEG (a pipe's
#: limb, 25 degrees in plain distances, spans 33-39 along the rays; a wall's cylinder of
#: 2.7 m spans a few, and its fit along the rays crept for a second).
ARC_SEARCH_DEG = MIN_ARC_DEG / 2.0


def _front_ranges(points: np.ndarray, axis: np.ndarray, point: np.ndarray, radius: float,
                  origins: np.ndarray | None = None) -> np.ndarray:
    """Per point, its range less the range at which its ray (from the sensor at the origin,
    or from its row of ``origins``, ``(N, 3)``) first meets the cylinder (``axis`` unit,
    through ``point``); a ray that misses it counts the range of its closest approach and
    ten times the gap (continuous at the tangent)."""
    seen = points if origins is None else points - origins
    ranges = np.maximum(np.linalg.norm(seen, axis=1), 1e-12)
    rays = seen / ranges[:, None]
    d = rays - np.outer(rays @ axis, axis)
    a = np.maximum(np.einsum("ij,ij->i", d, d), 1e-24)
    # e: from the axis to each ray's origin, across the axis (one vector for rays from the origin)
    if origins is None:
        e = -point + (point @ axis) * axis
        b, ee = d @ e, e @ e
    else:
        start = origins - point
        e = start - np.outer(start @ axis, axis)
        b, ee = np.einsum("ij,ij->i", d, e), np.einsum("ij,ij->i", e, e)
    disc = b * b - a * (ee - radius * radius)
    root = np.sqrt(np.maximum(disc, 0.0))
    near, far = (-b - root) / a, (-b + root) / a
    front = np.where(near > 0.0, near, far)
    closest = -b / a
    gap = np.sqrt(np.maximum(ee - b * b / a, 0.0)) - radius  # the ray's closest approach to the surface
    miss = np.sign(ranges - closest) * np.hypot(ranges - closest, MISS_GAP_WEIGHT * gap)
    return np.where((disc >= 0.0) & (front > 0.0), ranges - front, miss)


#: How much a ray's gap to a cylinder it misses counts against its range residual.
MISS_GAP_WEIGHT = 10.0

#: The most residual evaluations of a fit along the rays (a start far from any cylinder,
#: a wall's 2.7 m one, crept for a second and more without them; a pipe's converges in tens).
LM_EVALUATIONS = 200


def _cylinder_along_rays(points: np.ndarray, sigma: np.ndarray, start, origins: np.ndarray | None = None):
    """``(cylinder, chi)``: the cylinder whose range residuals (:func:`_front_ranges`) in the
    range noise ``sigma`` are smallest, by least squares from ``start``, and their mean
    square; ``(None, inf)`` when the fit fails. A laser's noise moves its returns along
    their rays: on a pipe's limb, seen at grazing incidence, plain distances take that noise
    for curvature and bend the fit flatter than the pipe (spinning_128x2048 seed 89 scan 0:
    a 25 cm pipe at 3.4 m seen on 5 columns; the fitter's cylinder 36 cm over 25 degrees,
    this one 20-26 cm over more than 30, range residuals 1.0 times the noise where the plane's
    are 1.3). The rays start at the origin, or at ``origins`` (per point, a nodding
    laser's mirror off its tilt axis)."""
    from scipy.optimize import least_squares

    def residuals(x):
        axis = x[:3] / max(float(np.linalg.norm(x[:3])), 1e-12)
        return _front_ranges(points, axis, x[3:6], abs(x[6]), origins) / sigma

    fit = least_squares(residuals, np.r_[start.axis, start.point, start.radius], max_nfev=LM_EVALUATIONS)
    if not fit.success or not np.all(np.isfinite(fit.x)):
        return None, np.inf
    axis = fit.x[:3] / np.linalg.norm(fit.x[:3])
    point = fit.x[3:6] + ((points.mean(axis=0) - fit.x[3:6]) @ axis) * axis  # nearest the centroid
    cylinder = Cylinder(axis=axis, point=point, radius=abs(float(fit.x[6])), rms=0.0, inliers=len(points))
    rms = float(np.sqrt(np.mean(cylinder.distances(points) ** 2)))
    return replace(cylinder, rms=rms), float(np.mean(fit.fun ** 2))


#: A streak's spread along the rays, in range noise rms: up to this, the noise's own.
STREAK_NOISE = 2.0


def _streak_along_rays(points: np.ndarray, sigma: np.ndarray, rays: np.ndarray) -> bool:
    """Whether ``points`` spread farther along their mean viewing ray than across it (the
    narrower of their two extents across the ray), and along it by no more than
    ``STREAK_NOISE`` times their range noise ``sigma`` (rms): a strip of a few columns
    under range noise as large as it is wide, a streak of that noise whatever its surface.
    A cylinder of a few centimetres wraps such a streak within its noise as well as a 16 cm
    pipe's (flat strips of 3 columns of a spinning_32x1024, 4.2 m away under 3 cm noise,
    took cylinders in 28 draws of 30 without this test)."""
    centred = points - points.mean(axis=0)
    ray = rays.mean(axis=0)
    ray = ray / max(float(np.linalg.norm(ray)), 1e-12)
    along = centred @ ray
    across = centred - np.outer(along, ray)
    width = np.sqrt(max(float(np.linalg.eigvalsh(across.T @ across / len(points))[1]), 0.0))
    spread = float(np.sqrt(np.mean(along * along)))
    # (a pipe's limb seen at grazing incidence spreads along the rays by its own depth, far
    # beyond the noise: spinning_128x2048 seed 89 scan 0, 4 cm under 1 cm noise)
    return width < spread <= STREAK_NOISE * float(np.sqrt(np.mean(sigma * sigma)))


def _plane_along_ray_noise(points: np.ndarray, sigma: np.ndarray, start: Plane, rays: np.ndarray) -> Plane:
    """The plane of ``points`` whose residuals along their unit ``rays`` are smallest in the
    range noise ``sigma`` (each a distance over ``sigma`` times the incidence cosine), by
    Levenberg-Marquardt from ``start`` and from the plane facing the points' mean ray.
    Least squares in plain distances lays the plane of a narrow strip along the rays, where
    the range noise spreads the points wider than the strip is: in that plane the points
    are far beyond their noise, in this one they need not be."""
    from scipy.optimize import least_squares

    def residuals(x):  # x: an unnormalised normal and the offset along it
        normal = x[:3] / np.linalg.norm(x[:3])
        return (points @ normal - x[3]) / np.maximum(sigma * np.abs(rays @ normal), 1e-3 * sigma)

    centroid = points.mean(axis=0)
    facing = rays.mean(axis=0)
    facing = facing / max(float(np.linalg.norm(facing)), 1e-12)
    best, best_cost = start, float(np.sum(residuals(np.r_[start.normal, start.d]) ** 2))
    for normal in (np.asarray(start.normal, dtype=float), facing):
        fit = least_squares(residuals, np.r_[normal, normal @ centroid], method="lm", max_nfev=LM_EVALUATIONS)
        if fit.success and 2.0 * fit.cost < best_cost:
            normal = fit.x[:3] / np.linalg.norm(fit.x[:3])
            best = Plane(normal=normal, d=float(fit.x[3]), rms=0.0, inliers=len(points))
            best_cost = 2.0 * fit.cost
    return best


def _planes_over_rays(ctx: Context, labels: np.ndarray, fits: dict, minimum: int) -> list:
    """The plane regions of ``labels`` (``minimum`` pixels or more) whose rms distance is
    within the range noise (``ctx.sigma``) yet beyond what that noise along the rays gives
    their plane, ``OFF_RAYS_SIGMAS`` up its chi-square (:func:`_planes_off_rays`): one
    compiled pass over the grid, sums by label (:func:`rangeseg_o3d.kernels.plane_ray_sums`),
    the rays from where the sensor's start (:attr:`Context.row_origins`)."""
    planes = [k for k, m in fits.items() if isinstance(m, Plane) and k > 0]
    if not planes:
        return []
    n = max(planes) + 1
    normals, offsets = np.zeros((n, 3)), np.zeros(n)
    for k in planes:
        normals[k], offsets[k] = fits[k].normal, fits[k].d
    counts, squares, ray_noise, range_noise = kernels.plane_ray_sums(
        ctx.xyz, np.ascontiguousarray(labels.ravel()), normals, offsets, np.ascontiguousarray(ctx.sigma, dtype=np.float64),
        _origin_rows(ctx), ctx.width)
    dof = np.maximum(counts - 3.0, 1.0)
    rms, noise = np.sqrt(squares / np.maximum(counts, 1.0)), np.sqrt(ray_noise / np.maximum(counts, 1.0))
    over = ((counts >= minimum) & (squares <= range_noise)  # (over it the decision tried the curved models)
            & (rms > noise_rms_bound.py_func(noise, dof, OFF_RAYS_SIGMAS)))
    return [k for k in planes if over[k]]


def _origin_rows(ctx: Context) -> np.ndarray:
    # the kernels' table of ray origins by row: none (0 rows) where the rays start at the origin
    return np.ascontiguousarray(ctx.row_origins if ctx.row_origins is not None else np.zeros((0, 3)), dtype=np.float64)
