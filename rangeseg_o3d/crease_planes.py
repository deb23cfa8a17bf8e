"""Cylinders bent over a crease become the planes of their two sides.

A cylinder fitted to tile means can bend over the crease where two faces of a box meet
along its axis: both faces then lie within the noise of one curved model. This module
finds the angle about the axis that cuts the region into two sides whose planes explain
its pixels clearly better (:func:`planes_for_creases`), refuses the cut where the two
"sides" are only range noise spread along the viewing rays (a thin pipe far away), and
lets the pixels near the new planes move between them and their neighbours.
"""

from __future__ import annotations

import numpy as np

from ._numeric import unique_ints
from .fitting.region_fitter import fresh_label
from .fullres import PixelStats, LabelBoxes, pixel_box, region_sample, region_stats

__all__ = ["planes_for_creases"]


#: How many times lower the rms of a cylinder region's two planes, split along its axis,
#: must be for the planes to replace it (:func:`planes_for_creases`). Not an F-test: on
#: thousands of pixels a sensor's systematic error resolves two planes' four extra
#: parameters over a true cylinder too; those planes gain at most a few percent there.
CREASE_RMS_FACTOR = 1.5
#: Equal-count cuts by angle about a cylinder's axis tried for the planes of its two sides.
CREASE_CUTS = 33
#: Least share of a cylinder region's pixels on either side of a cut.
CREASE_SIDE_SHARE = 0.1


def planes_for_creases(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *, sigma: np.ndarray,
                       k_sigma: float, inlier_factor: float, min_size: int, tile_labels: np.ndarray | None = None,
                       tile: int = 1, fitter=None, depth_step: float = 0.0) -> tuple[np.ndarray, dict, PixelStats]:
    """Each cylinder bent over a crease (two faces of a box meeting along its axis) becomes
    the two planes of its sides.

    On an even subsample of the region (:func:`region_sample`) the pixels are cut at one
    angle about the axis (the best of ``CREASE_CUTS`` equal-count cuts, each side at least
    ``min_size`` and ``CREASE_SIDE_SHARE`` of the region's pixels: the least squared
    distances to the two sides' least-squares planes); when that rms is
    ``CREASE_RMS_FACTOR`` times lower than the cylinder's (on a sensor reporting depth in
    steps of ``depth_step`` > 0: or lower at all where the cylinder's rms is beyond the
    noise of its own distances, :func:`_cylinder_beyond_its_noise`), and within the noise (facets of
    a curved surface are not), and than the cylinder ``fitter`` (when given) refits to the
    sample (a model left off a true cylinder), every pixel of the region goes
    to its side of the cut, the first side keeps the label, the other takes a new one, each
    with its side's plane, and the pixels of the region's box that another plane there fits
    clearly closer move to it (:func:`_exchange_with_neighbours`). Returns ``(labels, fits,
    stats)``, the inputs when no cylinder is replaced (always when there is none).
    """
    from .fitting.primitives import Cylinder
    from .fitting.robust import beyond_noise

    cylinders = [k for k, m in fits.items()
                 if isinstance(m, Cylinder) and m and 0 < k < stats.counts.size and stats.counts[k] > 0]
    if not cylinders:
        return labels, fits, stats
    boxes, replaced, next_label = LabelBoxes(labels), [], fresh_label(labels, fits)
    tile_boxes = None if tile_labels is None else LabelBoxes(tile_labels)
    for k in cylinders:
        box = pixel_box(boxes, k, tile_boxes, tile)
        sample = region_sample(cloud, labels, k, box)
        # each side of the cut holds min_size of the region's pixels: its share of the sample
        min_side = max(int(np.ceil(min_size * len(sample) / stats.counts[k])), 3)
        cut = _crease_cut(sample, fits[k], min_side)
        if cut is None:
            continue  # no crease: its noise is not needed
        if not (cut[3] or depth_step > 0):
            continue  # planes closer, but not by the factor: the region's noise is not needed
        noise = float(np.median(sigma[box][labels[box] == k]))
        if not (cut[3] or _cylinder_beyond_its_noise(sample, fits[k], noise)):
            continue  # over depth steps, planes closer but the cylinder within its distances' noise
        if beyond_noise(cut[2], noise, len(sample)):
            continue  # planes beyond the noise: facets of a curved surface
        if _sides_along_rays(sample, fits[k], cut, noise):
            continue  # two noise-long streaks along the rays: a pipe's range spread, not two faces
        if fitter is not None and _refit_rms(fitter, sample, fits[k]) < CREASE_RMS_FACTOR * cut[2]:
            continue  # the model was off a true cylinder, which its refit finds
        if not replaced:
            labels, fits = labels.copy(), dict(fits)
        window = labels[box]
        rows, cols = np.nonzero(window == k)
        points = cloud.xyz[box][rows, cols]
        finite = np.isfinite(points).all(axis=1)
        far = np.zeros(rows.size, bool)
        far[finite] = _angles(points[finite], fits[k], cut[1]) > cut[0]
        near_plane, far_plane = (_plane_of(points[finite & side]) for side in (~far, far))
        if not (near_plane and far_plane):
            continue
        window[rows[far], cols[far]] = next_label
        fits[k], fits[next_label] = near_plane, far_plane
        replaced += [k, next_label] + _exchange_with_neighbours(cloud, labels, fits, box, (k, next_label),
                                                                 sigma=sigma, k_sigma=k_sigma)
        next_label += 1
    if not replaced:
        return labels, fits, stats
    return labels, fits, region_stats(cloud.xyz, labels, fits, sigma, inlier_factor, known=stats, stale=replaced)


#: A crease side whose spread along its viewing ray is within this many range noise
#: sigmas has no depth of its own (:func:`_sides_along_rays`).
RAY_SPREAD_SIGMAS = 1.5


def _sides_along_rays(points: np.ndarray, cylinder, cut: tuple, noise: float) -> bool:
    """Whether both sides of ``cut`` (:func:`_crease_cut`) are streaks of range noise along
    the viewing rays rather than faces: each side's spread along its mean ray within
    ``RAY_SPREAD_SIGMAS`` times the range noise ``noise`` and longer than the side is wide
    across the rays, and its plane's normal across the rays within the angle that streak
    leaves (``|n . ray| <`` width / spread). A thin pipe far away under large range noise
    is such a pair of streaks; least squares lays each side's plane along the rays, so its
    two planes beat the cylinder without a crease between them. Two faces of a box are
    never both seen edge-on but from along their crease."""
    far = _angles(points, cylinder, cut[1]) > cut[0]
    for side in (~far, far):
        side_points = points[side]
        plane = _plane_of(side_points)
        if plane is None:
            return False
        ray = side_points.mean(axis=0)
        ray = ray / max(float(np.linalg.norm(ray)), 1e-12)
        centred = side_points - side_points.mean(axis=0)
        along = centred @ ray
        spread = float(np.sqrt(np.mean(along ** 2)))
        across = centred - np.outer(along, ray)
        # the narrower of the side's two extents across the ray: its width across the streak
        width = float(np.sqrt(max(np.linalg.eigvalsh(across.T @ across / len(side_points))[1], 0.0)))
        if not (spread <= RAY_SPREAD_SIGMAS * noise and width < spread
                and abs(float(np.asarray(plane.normal) @ ray)) * spread < width):
            return False
    return True


def _exchange_with_neighbours(cloud, labels: np.ndarray, fits: dict, box: tuple[slice, slice], new: tuple,
                              *, sigma: np.ndarray, k_sigma: float) -> list:
    """The pixels of ``box`` in plane regions that another plane there (one of them a crease's
    ``new`` planes) meets ``CREASE_RMS_FACTOR`` times closer along their ray than their own,
    and within ``k_sigma`` range noise ``sigma``, move to it (``labels`` changed in place);
    returns the labels whose pixels changed. The cylinder's region held pixels of the
    surfaces beside it, and they held pixels of its faces: where the sensor's noise is
    larger than the faces' own scatter, each was within it of the other model."""
    from .fitting.primitives import Plane

    window = labels[box]
    planes = [int(k) for k in unique_ints(window.ravel()) if k > 0 and isinstance(fits.get(int(k)), Plane)]
    if len(planes) < 2:
        return []
    column = np.full(int(window.max()) + 1, -1, np.int64)
    column[planes] = np.arange(len(planes))
    rows, cols = np.nonzero(column[window] >= 0)
    points = cloud.xyz[box][rows, cols]
    finite = np.isfinite(points).all(axis=1)
    rows, cols, points = rows[finite], cols[finite], points[finite]
    # along each ray (the range noise's direction): a plane seen edge-on nears the wall
    # behind it only at grazing incidence, where its distance along the ray is far
    rays = points / np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-12)
    distances = np.stack([np.abs(fits[k].distances(points)) / np.maximum(np.abs(rays @ np.asarray(fits[k].normal)),
                                                                         1e-6) for k in planes], axis=1)
    own_column = column[window[rows, cols]]
    own = distances[np.arange(rows.size), own_column]
    best = np.argmin(distances, axis=1)
    nearest = distances[np.arange(rows.size), best]
    to = np.array(planes)[best]
    scale = sigma[box][rows, cols]
    involved = np.isin(to, new) | np.isin(window[rows, cols], new)
    move = (best != own_column) & (CREASE_RMS_FACTOR * nearest < own) & (nearest <= k_sigma * scale) & involved
    if not move.any():
        return []
    changed = set(unique_ints(window[rows[move], cols[move]]).tolist()) | set(unique_ints(to[move]).tolist())
    window[rows[move], cols[move]] = to[move]
    return sorted(changed)


def _refit_rms(fitter, points: np.ndarray, model) -> float:
    # the rms of ``points`` about the closest of ``model``'s refit and the fitter's own fit
    # of them that keep its kind (infinite when neither does)
    tries = [m for m in (fitter.refit(points, model), fitter.fit(points)) if m and m.kind == model.kind]
    return min((float(np.sqrt(np.mean(m.distances(points) ** 2))) for m in tries), default=np.inf)


def _plane_of(points: np.ndarray):
    from .fitting.plane import fit_plane

    return fit_plane(points) if len(points) >= 3 else None


def _angles(points: np.ndarray, cylinder, reference: np.ndarray) -> np.ndarray:
    # each point's angle about the cylinder's axis from the direction ``reference`` (across it)
    return _radial_angles(_radial(points, cylinder), cylinder, reference)


def _radial(points: np.ndarray, cylinder) -> np.ndarray:
    # each point's offset from the cylinder's axis, across it (the same operations as
    # Cylinder.distances: the same values)
    axis = np.asarray(cylinder.axis, dtype=np.float64)
    radial = points - cylinder.point
    return radial - np.outer(radial @ axis, axis)


def _radial_angles(radial: np.ndarray, cylinder, reference: np.ndarray) -> np.ndarray:
    # :func:`_angles` of the points whose offsets from the axis are ``radial``
    axis = np.asarray(cylinder.axis, dtype=np.float64)
    return np.arctan2(radial @ np.cross(axis, reference), radial @ reference)


def _crease_cut(points: np.ndarray, cylinder, min_side: int):
    """``(angle, reference, rms, by_factor)`` of the cut about ``cylinder``'s axis whose two
    sides' planes fit ``points`` closest (their ``rms``), when they fit them closer than the
    cylinder does; ``by_factor``: ``CREASE_RMS_FACTOR`` times closer. None otherwise.

    One compiled pass (:func:`rangeseg_o3d.kernels.crease_cut`: the offsets, angles, sort,
    running sums and the cuts' smallest eigenvalues; numpy's form, the reference of its tests,
    took ~25 calls and ~0.2 ms a cylinder). Its own rounding: the cut chosen is numpy's but
    where two cuts tie within rounding, ``rms`` within ~1e-9 relative."""
    from .kernels import crease_cut

    n = len(points)
    if n < 2 * min_side:
        return None
    side = max(min_side, int(np.ceil(CREASE_SIDE_SHARE * n)))
    if n < 2 * side:
        return None
    status, angle, reference, planes_squares, cylinder_squares = crease_cut(
        np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(cylinder.axis, dtype=np.float64),
        np.ascontiguousarray(cylinder.point, dtype=np.float64), float(cylinder.radius), int(side), int(CREASE_CUTS))
    if status != 0 or not cylinder_squares > planes_squares:
        return None
    return (float(angle), reference, np.sqrt(planes_squares / n),
            bool(cylinder_squares > CREASE_RMS_FACTOR ** 2 * planes_squares))


def _cylinder_beyond_its_noise(points: np.ndarray, cylinder, noise: float) -> bool:
    """Whether ``cylinder``'s rms over ``points`` is beyond the noise of their distances to
    it (:func:`rangeseg_o3d.fitting.robust.distance_noise` of the range noise ``noise``: the
    incidence cosine and the sagitta of its bend), up the chi-square spread.

    Where the sensor reports depth in steps, the quantisation is most of a face's scatter:
    two faces' planes cannot fit ``CREASE_RMS_FACTOR`` times closer than a cylinder bent over
    their crease, whose rms is then only a little above theirs (the tabletop row: 0.50
    against 0.58 mm on 0.5 mm noise), but that cylinder is beyond what range noise along
    the rays gives its distances, and a true cylinder is not (its rms is that noise).
    Elsewhere a real sensor's systematic error puts true cylinders beyond it too (asked on
    every sensor, it split the mug of the pcl_table_scene_mug frame, 2 m off, into two
    planes, and a 4-pixel strip of the 3dtk_scan000 scan into two interleaved ones), so
    :func:`planes_for_creases` asks it only over depth steps."""
    from .fitting.robust import beyond_noise, distance_noise

    rms = float(np.sqrt(np.mean(cylinder.distances(points) ** 2)))
    expected = distance_noise(cylinder, points, np.full(len(points), noise))
    return beyond_noise(rms, float(np.sqrt(np.mean(expected ** 2))), len(points))
