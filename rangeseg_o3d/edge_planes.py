"""Plane regions that are strips of a pipe the frame's edge cuts, settled by the range noise
of a camera whose noise exceeds its grid's footprint (a Kinect's).

A pipe the frame's edge cuts is seen as a band a few to a few dozen pixels wide. The tile
grid's partial, mixed tiles there (640 = 106 x 6 + 4) see none of it, or only its middle,
and what the full-resolution pass recovers of the rest (a blob, a strip along its flank or
along the edge) is a plane: across a band a few footprints wide, the Kinect's range noise
(centimetres at 3-5 m, several pixel footprints) spreads the pixels farther along their
rays than the band bends, and the recovery asks a blob's plane only to hold it within the
range noise. The pipe is then split (its cylinder region and a plane strip beside it:
kinect study seeds 3, 13, fresh 1024, 1028, 1035, the strip 157-730 px, on the pipe's
flank or at the edge) or, when no cylinder region was found, fitted as a plane (seeds 29,
1034): on the kinect study and fresh seeds every curved split and every false fitting
cylinder -> plane touched the frame's edge (kinect8's classification).

The sensor model settles the split. A strip of a curved region's surface lies within the
noise of its distances to that region's model (or to that model refitted with it): it joins
the region. A real plane beside a pipe (a wall cut by the edge) lies off the pipe's model by
more than its noise: it stays. (A plane alone at the frame's edge fitted curved when its
pixels resolve a bend was tried and left out: on kinect fresh seed 1014 it turned a small
wall mixed with another face's pixels into a cylinder.) Every change is held to :func:`rangeseg_o3d.fullres.planes_for_unresolved`'s later tests, so that none
turns a split into a false fitting.

A curved surface's piece recovered as a curved region of its own is settled the same way
(``curved_pieces``): the leftover pixels beside a ball's sphere region, or a ball the tile grid
missed whole, are split into surfaces one after the other, and the rest of the ball after its
sphere comes out as a cylinder (kinect_640x480 study seed 1154 scan 0: a ball of 1826 px as a
sphere of 1461 and a cylinder of 364); it joins the sphere when the sphere's model explains it
as it explains a strip. Where the noise errs together over a matching window (a stereo
camera's) the step runs too: a pipe's flank the frame's edge cuts leaves plane strips there as
well (stereo study seed 1102 scan 1: 242 px at 60 degrees from head-on, beside a cylinder
region of 22578 px).
"""

from __future__ import annotations

import numpy as np

from . import kernels
from .fitting.primitives import squared_distances

__all__ = ["edge_planes_to_curved"]


def edge_planes_to_curved(cloud, labels: np.ndarray, fits: dict, stats, *, sigma: np.ndarray, fitter=None,
                          inlier_factor: float, tile_labels: np.ndarray | None = None, tile: int = 1,
                          near_sigmas: float | None = None, curved_pieces: bool = False,
                          hosts: set | None = None):
    """Plane regions given to the curved surface the sensor's noise says they are strips of.
    Returns ``(labels, fits, stats)``, the inputs when nothing changed.

    Each plane region that touches (4-neighbours) a cylinder or sphere region of at least its
    size joins the one whose model explains its pixels within the noise of their distances to it
      (:func:`_within_distance_noise`: range noise times the incidence cosine, chi-square
      bound over its pixels), the one of least rms; else, with ``fitter``, the one whose model
      refitted to an even sample of its own pixels and the strip's explains both within that
      noise (that refit its model: a tile model of a far pipe's means lies off a grazing
      flank strip by more than the strip's small distance noise).

    Every test runs on an even sample of about ``HOST_SAMPLE`` of a region's pixels.

    A join (a curved model) is kept only when the curved model stays curved over the union (the region) by the tests
    :func:`rangeseg_o3d.fullres.planes_for_unresolved` applies later, on the same sample
    (``tile_labels``, ``tile``: the tile grid, as there): else that step makes the union a
    plane, a false fitting where the two apart were a split.

    ``curved_pieces``: cylinder and sphere regions are asked too, as a plane region is, about
    the curved regions of at least their size they touch (a piece of a ball recovered as a
    cylinder joins the ball's sphere; the union keeps the host's kind).

    ``near_sigmas``: a curved region is asked about a plane only when its model lies within
    that many range-noise sigmas of the plane's pixels at the median, and refitted only when
    its model explains its own pixels within the noise of their distances (cheap necessary
    conditions: :func:`_curved_host`); None asks every one.

    ``sigma``: the range noise per pixel (the grid's shape). ``hosts`` (optional): only these
    curved regions are offered the pieces beside them.
    """
    from .fullres import LabelBoxes, region_stats

    labels = np.asarray(labels)
    if labels.ndim != 2 or np.shape(sigma) != labels.shape:
        raise ValueError(f"edge_planes_to_curved: expected labels and sigma of one (H, W) shape; "
                         f"got {labels.shape} and {np.shape(sigma)}")
    if fitter is not None and "noise_floor" not in getattr(fitter, "params", {}):
        fitter = None  # (refit's curvature_gain: a keyword of the primitives fitter alone)
    counts = stats.counts
    n = counts.size  # (region_stats counts every label; a pass over the grid for its largest costs 0.1 ms)
    curved = {k for k, m in fits.items()
              if m and m.kind != "plane" and 0 < k < n and (hosts is None or k in hosts)}
    pieces = [k for k, m in fits.items() if m and (m.kind == "plane" or curved_pieces) and 0 < k < n
              and k < counts.size and counts[k] > 0]
    if not pieces or not curved:
        return labels, fits, stats
    boxes = LabelBoxes(labels, n)
    tile_boxes = None if tile_labels is None else LabelBoxes(tile_labels)
    # the pieces that may be strips of a curved region's surface: those touching one, no
    # larger than it (a wall beside a pipe is tested too when smaller; its noise decides)
    beside = _touching_pairs(labels, boxes, sorted(curved), pieces, counts)
    asked = sorted(beside)
    if not asked:
        return labels, fits, stats
    xyz = cloud.xyz
    # the pairs whose curved model lies within near_sigmas of the plane at the median, all in
    # one compiled pass on the grid (against the models as they stand now: a region that took
    # a strip since is asked again in numpy); only the planes with such a neighbour are sampled
    near = None if near_sigmas is None else _near_pairs(labels, xyz, sigma, boxes, beside, fits, float(near_sigmas))
    out, fits_out, changed = None, None, []
    host_samples = {}  # (a curved region's sample serves every strip beside it until one joins it)
    for k in asked:
        r0, r1, c0, c1 = boxes.bounds(k)
        hosts = beside.get(k, ())
        current = fits if fits_out is None else fits_out
        # (a curved piece that joined another host is gone; one that took a piece stays: its
        # pixels reach past the box it had)
        hosts = [c for c in hosts if current.get(c)]
        if not hosts or k in changed:
            continue
        if near is not None:
            hosts = [c for c in hosts if near.get((k, c), -1) != 0 or current.get(c) is not fits.get(c)]
            if not hosts:
                continue
        # every test on an even sample of about HOST_SAMPLE of its pixels (a floor at the frame's
        # edge holds 10^5: taken whole, the real frames' edge planes cost tens of milliseconds)
        points, noise = _strip_sample(labels if out is None else out, xyz, sigma, boxes.bounds(k), k)
        if len(points) < 6:
            continue
        if near is not None:
            hosts = [c for c in hosts if (near.get((k, c)) == 1 and current.get(c) is fits.get(c))
                     or _near(current.get(c), points, noise, float(near_sigmas))]
            if not hosts:
                continue
        host, refit = _curved_host(cloud, labels if out is None else out, boxes, hosts, current,
                                   points, noise, fitter, sigma, host_samples)
        if host is not None:
            if out is None:
                out = np.array(labels, copy=True)
            mine = out[r0:r1, c0:c1] == k
            out[r0:r1, c0:c1][mine] = host
            model = refit if refit is not None else current[host]
            if not _union_stays_curved(cloud, out, host, model, sigma, tile_boxes, tile):
                out[r0:r1, c0:c1][mine] = k  # (a split is better than a false fitting)
                continue
            host_samples.pop(host, None)  # (its pixels changed)
            fits_out = dict(fits) if fits_out is None else fits_out
            del fits_out[k]
            if refit is not None:
                fits_out[host] = refit
            changed.append(host)
    if not changed:
        return labels, fits, stats
    labels_out = labels if out is None else out
    stats = region_stats(xyz, labels_out, fits_out, sigma, inlier_factor, known=stats,
                         stale=sorted(set(changed) | (set(fits) - set(fits_out))))
    return labels_out, fits_out, stats


def _rms_and_noise(model, points: np.ndarray, noise: np.ndarray, distances: np.ndarray | None = None
                   ) -> tuple[float, float]:
    # the model's rms over the points (their ``distances`` to it when known) and the rms of
    # the noise of their distances to it
    from .fitting.robust import distance_noise

    band = distance_noise(model, points, noise)
    distances = model.distances(points) if distances is None else distances
    return float(np.sqrt(np.mean(distances * distances))), float(np.sqrt(np.mean(band * band)))


def _within_distance_noise(model, points: np.ndarray, noise: np.ndarray, distances: np.ndarray | None = None
                           ) -> bool:
    """Whether ``model``'s rms over ``points`` (``distances``: theirs to it, when known) lies
    within the chi-square bound of the noise of their distances to it (range noise ``noise``
    times the incidence cosine).

    Asked first against the largest noise a distance can have (:func:`_noise_ceiling`), which
    needs no normals: an rms beyond that bound is beyond the distances' own (the bound grows
    with the noise), and most of the pairs a frame asks are refused there."""
    from .fitting.robust import beyond_noise

    distances = model.distances(points) if distances is None else distances
    rms = float(np.sqrt(np.mean(distances * distances)))
    if beyond_noise(rms, _noise_ceiling(model, noise), len(points)):
        return False
    rms, band = _rms_and_noise(model, points, noise, distances)
    return not beyond_noise(rms, band, len(points))


def _noise_ceiling(model, noise: np.ndarray) -> float:
    """The rms of the largest noise of a distance to ``model`` range noise ``noise`` can give
    (:func:`rangeseg_o3d.fitting.robust.distance_noise` at its incidence cosine 1 and its
    curved share 1): ``sigma sqrt(1 + 3 sigma**2 / (4 r**2))`` on a cylinder or sphere of
    radius ``r``, ``sigma`` else."""
    square = noise * noise
    radius = float(getattr(model, "radius", 0.0) or 0.0) if model.kind != "plane" else 0.0
    if radius > 0:
        square = square * (1.0 + 0.75 * square / (radius * radius))
    return float(np.sqrt(np.mean(square)))


#: Pixels of a curved region its refit with a strip samples (evenly, as planes_for_unresolved).
HOST_SAMPLE = 1024


def stays_curved(model, points: np.ndarray, noise: np.ndarray) -> bool:
    """Whether the curved ``model`` keeps its kind over ``points`` (range noise ``noise``) by
    the tests :func:`rangeseg_o3d.fullres.planes_for_unresolved` applies later: its
    curvature resolved against their plane (the F-test), or it alone of the two within the
    noise of their distances. A strip joined to a curved region whose union then became a
    plane would trade a split for a false fitting."""
    from .fitting.plane import fit_plane
    from .fitting.robust import curvature_resolved
    from .fullres import curved_alone_within_noise

    if len(points) < 6:
        return False
    plane = fit_plane(points)
    if not plane:
        return True
    squares = squared_distances(model, points)
    if curvature_resolved(len(points) * plane.rms ** 2, squares, len(points)):
        return True
    return curved_alone_within_noise(model, points, noise, plane)


def _union_stays_curved(cloud, labels: np.ndarray, host: int, model, sigma: np.ndarray, tile_boxes, tile: int) -> bool:
    """Whether ``model`` stays curved over region ``host`` of ``labels`` (a strip joined to
    it) by :func:`rangeseg_o3d.fullres.planes_for_unresolved`'s tests on the same even sample
    (its box: :func:`rangeseg_o3d.fullres.pixel_box`; the F-test against their plane, then
    its distance-noise test on all the pixels): else that step makes the union a plane, a
    false fitting where the strip and the region apart were a split."""
    from .fitting.plane import fit_plane
    from .fitting.robust import curvature_resolved
    from .fullres import LabelBoxes, only_curved_within_noise, pixel_box, region_sample

    box = pixel_box(LabelBoxes(labels), host, tile_boxes, tile)
    points = region_sample(cloud, labels, host, box)
    plane = fit_plane(points) if len(points) >= 6 else None
    if not plane:
        return True  # (planes_for_unresolved leaves it)
    squares = squared_distances(model, points)
    if curvature_resolved(len(points) * plane.rms ** 2, squares, len(points)):
        return True
    return only_curved_within_noise(model, cloud.xyz, sigma, labels, host, box)


def _curved_host(cloud, labels: np.ndarray, boxes, hosts, fits: dict, points: np.ndarray, noise: np.ndarray,
                 fitter, sigma: np.ndarray, samples: dict | None = None):
    """``(host, refit)``: the curved region of ``hosts`` whose model explains ``points`` (a
    plane region's pixels, range noise ``noise``) within the noise of their distances, the
    least rms (``refit`` None); else, with ``fitter``, the one whose model refitted to an even
    sample of its pixels and ``points`` explains both within that noise (``refit`` that
    model: a tile model of a far pipe's means is off its pixels by more than a grazing strip's
    distance noise); else ``(None, None)``. Either way the model must stay curved over the
    union (:func:`stays_curved`).

    A host is refitted only when its model explains its own sample within the noise of
    their distances (a strip joins a pipe's model; a region its model leaves beyond the
    noise is not that clean surface, and no refit from such a model was kept on the kinect
    study and fresh seeds), a cheap necessary condition that spares a frame whose planes
    beside its curved regions are walls and boxes the refit, the step's cost. Computed once
    per host (``samples``: the hosts' samples and that verdict already taken, filled here)."""
    samples = {} if samples is None else samples
    best, best_rms, found = None, np.inf, None
    refittable = []
    for c in sorted(hosts):
        model = fits.get(c)
        if not model or model.kind == "plane":
            continue
        distances = model.distances(points)
        if _within_distance_noise(model, points, noise, distances):
            own, own_noise, _ = _sample_of(samples, c, cloud, labels, boxes, sigma, model)
            if stays_curved(model, np.concatenate([own, points]), np.concatenate([own_noise, noise])):
                rms = float(np.sqrt(np.mean(distances * distances)))
                if rms < best_rms:
                    best, best_rms = c, rms
                continue
        refittable.append((c, model))
    if best is not None or fitter is None:
        return best, None
    for c, model in refittable:
        own, own_noise, own_within = _sample_of(samples, c, cloud, labels, boxes, sigma, model)
        if len(own) < 6 or not own_within:
            continue
        union = np.concatenate([own, points])
        refit = fitter.refit(union, model, curvature_gain=1.0)
        if (not refit or refit.kind != model.kind or not _within_distance_noise(refit, points, noise)
                or not _within_distance_noise(refit, own, own_noise)
                or not stays_curved(refit, union, np.concatenate([own_noise, noise]))):
            continue
        rms = float(np.sqrt(np.mean(refit.distances(points) ** 2)))
        if rms < best_rms:
            best, best_rms, found = c, rms, refit
    return (best, found) if best is not None else (None, None)


def _near(model, points: np.ndarray, noise: np.ndarray, near_sigmas: float) -> bool:
    """Whether the median of ``points``' distances to ``model`` is within ``near_sigmas``
    times the median of their range noise ``noise`` (merge's pretest before its refit of a
    curved region with a piece: :func:`rangeseg_o3d.refinement.merge.merge_into_curved`)."""
    if not model or model.kind == "plane" or len(points) == 0:
        return False
    return bool(np.median(np.abs(model.distances(points))) <= near_sigmas * np.median(noise))


def _near_pairs(labels: np.ndarray, xyz: np.ndarray, sigma: np.ndarray, boxes, beside: dict, fits: dict,
                near_sigmas: float) -> dict:
    """{(plane, curved): 1 near, 0 not, -1 undecided} for the pairs of ``beside`` ({plane:
    curved labels}) with a curved model in ``fits``: :func:`_near` on the plane's even
    sample (:func:`_strip_sample`) by one compiled pass on the grid over every pair
    (:func:`rangeseg_o3d.kernels.strips_near_models`, merge's verdicts), -1 where rounding
    could decide (numpy's :func:`_near` then answers)."""
    from .fitting.region_fitter import model_row
    from .refinement.merge import NEAR_RELATIVE, NEAR_ROUNDING

    pairs = [(k, c) for k in sorted(beside) for c in sorted(beside[k]) if fits.get(c) and fits[c].kind != "plane"]
    if not pairs:
        return {}
    every = boxes.array()
    grid = np.array([every[k] for k, _ in pairs], np.int64).reshape(-1, 4)
    steps = np.array([_sample_step(every[k]) for k, _ in pairs], np.int64)
    rows = {c: model_row(fits[c]) for c in {c for _, c in pairs}}
    verdict = kernels.strips_near_models(
        np.ascontiguousarray(labels, dtype=np.int32), np.ascontiguousarray(xyz, dtype=np.float64),
        np.ascontiguousarray(sigma, dtype=np.float64), np.array([k for k, _ in pairs], np.int32), grid, steps,
        np.array([rows[c][0] for _, c in pairs], np.int8), np.array([rows[c][1] for _, c in pairs]),
        near_sigmas, NEAR_RELATIVE, NEAR_ROUNDING)
    return dict(zip(pairs, verdict.tolist()))


def _sample_step(bounds) -> int:
    # the grid step of a region's even sample of about HOST_SAMPLE pixels in its box (row0, row1, col0, col1)
    r0, r1, c0, c1 = (int(v) for v in bounds)
    return max(int(np.ceil(np.sqrt((r1 - r0) * (c1 - c0) / HOST_SAMPLE))), 1)


def _strip_sample(labels: np.ndarray, xyz: np.ndarray, sigma: np.ndarray, bounds, k: int):
    """``(points, range noise)`` of region ``k``'s even sample of about ``HOST_SAMPLE``
    pixels in its box ``bounds`` (row0, row1, col0, col1): every :func:`_sample_step`-th row
    and column, the finite ones."""
    r0, r1, c0, c1 = bounds
    spaced = _sample_step(bounds)
    pick = labels[r0:r1:spaced, c0:c1:spaced] == k
    points = xyz[r0:r1:spaced, c0:c1:spaced][pick]
    noise = np.asarray(sigma)[r0:r1:spaced, c0:c1:spaced][pick]
    finite = np.isfinite(points).all(axis=1) & np.isfinite(noise)
    return points[finite], noise[finite]


def _sample_of(samples: dict, c: int, cloud, labels: np.ndarray, boxes, sigma: np.ndarray, model):
    # region c's even sample (:func:`_strip_sample`), its range noise and whether ``model``
    # explains it within the noise of its distances: taken once per call of the step
    if c not in samples:
        own, own_noise = _strip_sample(labels, cloud.xyz, sigma, boxes.bounds(c), c)
        samples[c] = (own, own_noise, len(own) >= 6 and _within_distance_noise(model, own, own_noise))
    return samples[c]


def _touching_pairs(labels: np.ndarray, boxes, curved: list, pieces: list, counts: np.ndarray) -> dict:
    """{piece label: set of curved labels} for each region of ``pieces`` that 4-touches another
    region, a curved one of ``curved``, holding at least its pixels (``counts``): boxes (``boxes``,
    a :class:`rangeseg_o3d.fullres.LabelBoxes` of ``labels``) that overlap grown by a pixel
    first, all pairs at once, then the compiled :func:`rangeseg_o3d.kernels.labels_touch` in
    that overlap."""
    h, w = labels.shape
    if not curved or not pieces:
        return {}
    cs, ps = np.asarray(curved, np.int64), np.asarray(pieces, np.int64)
    every = boxes.array()
    cb, pb = every[cs], every[ps]
    r0 = np.maximum(cb[:, None, 0], pb[None, :, 0]) - 1
    r1 = np.minimum(cb[:, None, 1], pb[None, :, 1]) + 1
    c0 = np.maximum(cb[:, None, 2], pb[None, :, 2]) - 1
    c1 = np.minimum(cb[:, None, 3], pb[None, :, 3]) + 1
    size = np.asarray(counts)
    ok = (r1 - r0 >= 1) & (c1 - c0 >= 1) & (size[ps][None, :] <= size[cs][:, None]) & (cs[:, None] != ps[None, :])
    beside = {}
    if not ok.any():
        return beside
    flat = np.ascontiguousarray(labels, dtype=np.int32)
    for i, j in zip(*np.nonzero(ok)):
        if kernels.labels_touch(flat, int(cs[i]), int(ps[j]), max(int(r0[i, j]), 0), min(int(r1[i, j]), h),
                                max(int(c0[i, j]), 0), min(int(c1[i, j]), w)):
            beside.setdefault(int(ps[j]), set()).add(int(cs[i]))
    return beside

