"""The tile grid brought back to the sensor grid: labels, statistics, leftovers, stage images.

A depth camera's frame is segmented on ``tile x tile`` means
(:meth:`rangeseg_o3d.OrganizedCloud.tile_means`); this module does the per-pixel work
that follows, each piece only where it is needed:

- :func:`label_pixels`: every pixel tested against the models of its tile's region and
  the regions around it, listed once per tile (a pixel inside a region costs one
  distance); the same distances give each region's inlier count and squared sum, so
  :meth:`rangeseg_o3d.Pipeline.run` makes no second pass over the pixels for them.
- :func:`leftover_blob_labels`: the blobs of pixels no tile model explains (surfaces
  thinner than the tile grid sees, small faces between creases it could not see);
  nothing is done past one pass when no pixel is left over.
- :class:`ExpandedStages`: stage images of the tile grid, expanded to the sensor grid
  when someone asks for them.
- :class:`PixelStats` and :func:`region_stats`: the statistics, kept for the regions the
  recovery of thin surfaces did not touch and recomputed for those it did.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from ._numeric import unique_ints
from . import kernels  # the package: its names load on first use (no compiler at import)
from .fitting.primitives import squared_distances, with_statistics
from .fitting.region_fitter import fresh_label, model_table, other_curved_decision
from .scales import GRAZING_TAN, MIN_PIXELS, RELIEF_STEPS, with_derived_refinement

__all__ = ["ExpandedStages", "PixelStats", "expand", "label_pixels", "recover_thin_surfaces",
           "region_stats", "stats_with_moved", "stats_after_moves",
           "leftover_blob_labels", "with_pixel_rms", "planes_for_unresolved", "resolved_refit", "other_curved_kind",
           "grow_into_free",
           "merge_touching_planes", "refit_planes_to_pixels", "drop_unresolvable_curves", "settle_creases", "settle_caps",
           "settle_plane_borders",
           "recovered_region_floor", "free_untold_regions", "recover_freed_pixels"]


def expand(image: np.ndarray, tile: int, shape: tuple[int, int]) -> np.ndarray:
    """Nearest-neighbour upsampling of a tile-grid image to the sensor grid of ``shape``."""
    return np.repeat(np.repeat(image, tile, axis=0), tile, axis=1)[: shape[0], : shape[1]]


class ExpandedStages(Mapping):
    """Stage images of the tile grid, each expanded to the sensor grid on first access.

    A camera loop that never looks at them pays nothing for them (0.4-0.5 ms per VGA
    frame otherwise); ``dict(stages)`` expands them all.
    """

    def __init__(self, images: Mapping, tile: int, shape: tuple[int, int]):
        self._images = dict(images)
        self._tile = int(tile)
        self._shape = (int(shape[0]), int(shape[1]))
        self._expanded: dict[str, np.ndarray] = {}

    def __getitem__(self, name: str) -> np.ndarray:
        image = self._expanded.get(name)
        if image is None:
            image = expand(self._images[name], self._tile, self._shape)
            self._expanded[name] = image
        return image

    def __iter__(self):
        return iter(self._images)

    def __len__(self) -> int:
        return len(self._images)

    def __repr__(self) -> str:
        return f"ExpandedStages({sorted(self._images)}, tile={self._tile}, shape={self._shape})"


@dataclass
class PixelStats:
    """Per label of the full-resolution labels: pixels within ``INLIER_SIGMAS`` sigma of the
    model (``inliers``), sum of squared distances (``squares``), pixels with a finite
    distance (``counts``), each over the region's pixels in raster order."""

    inliers: np.ndarray
    squares: np.ndarray
    counts: np.ndarray

    def rms(self, label: int) -> float | None:
        """The rms distance of label ``label``'s pixels from its model; None when it has no
        pixel with a finite distance (or is beyond the table)."""
        if not 0 <= label < self.counts.size or self.counts[label] <= 0:
            return None
        return float(np.sqrt(self.squares[label] / self.counts[label]))


def label_pixels(cloud, tile_labels: np.ndarray, fits: dict, *, tile: int, sigma: np.ndarray,
                 k_sigma: float, inlier_factor: float, with_blocks: bool = False,
                 creases_from=None, min_angle_deg: float = 0.0):
    """Label every pixel of ``cloud`` by the models of its tile's region and the 8 around it.

    A pixel joins, of the models within ``k_sigma`` of it in units of ``max(sigma, rms)``, the
    one it is fewest sigmas of its distance's noise off (see
    :func:`rangeseg_o3d.kernels.label_pixels`). Returns the ``(H, W)`` int32 labels
    (in the tile labels' numbering) and the :class:`PixelStats` of those labels; with
    ``with_blocks`` also the sums per tile and label the same pass gathered, for
    :func:`rangeseg_o3d.off_model.recover_off_model`.

    With ``creases_from`` (the tile means the tile labels label, an OrganizedCloud), a pixel
    two planes turned by more than ``min_angle_deg`` both explain goes to the face its ray
    meets at their crease, as :func:`settle_creases` moves it, instead of the nearer plane's:
    where the range noise grows with the range, a far crease's band of pixels lies within
    the noise of both planes and the noise picks the side.
    """
    from .kernels import label_pixels as kernel

    kinds, params, rms = model_table(fits, int(tile_labels.max(initial=0)) + 1)
    if creases_from is None:
        tile_xyz = np.zeros((0, 3))
    elif creases_from.shape != tile_labels.shape:
        raise ValueError(f"label_pixels: creases_from must be the tile means of the {tile_labels.shape} tile labels, "
                         f"got a cloud of shape {creases_from.shape}")
    else:
        tile_xyz = _flat_points(creases_from)
    labels, inliers, squares, counts, blocks = kernel(
        _flat_points(cloud), cloud.shape[0], cloud.shape[1],
        np.ascontiguousarray(tile_labels, dtype=np.int32), int(tile), kinds, params, rms,
        np.ascontiguousarray(sigma, dtype=np.float64).ravel(), float(k_sigma), float(inlier_factor),
        tile_xyz, float(np.cos(np.radians(min_angle_deg))), float(np.sin(np.arctan(GRAZING_TAN))))
    if with_blocks:
        return labels, PixelStats(inliers, squares, counts), blocks
    return labels, PixelStats(inliers, squares, counts)


def region_stats(xyz: np.ndarray, labels: np.ndarray, fits: dict, sigma: np.ndarray,
                 inlier_factor: float, *, known: PixelStats | None = None,
                 stale=()) -> PixelStats:
    """The :class:`PixelStats` of every label of ``labels`` under its model in ``fits``.

    With ``known`` (statistics of these labels measured earlier), only the labels in
    ``stale`` (whose pixels or model changed since) are measured again.
    """
    n = int(labels.max(initial=0)) + 1
    kinds, params, rms = model_table(fits, n)
    if known is not None:
        measure = np.zeros(n, bool)
        measure[[k for k in stale if 0 < k < n]] = True
        kinds = np.where(measure, kinds, 0).astype(kinds.dtype)
    inliers, squares, counts = kernels.distance_stats(
        np.ascontiguousarray(xyz.reshape(-1, 3)), np.ascontiguousarray(labels).ravel(), kinds,
        params, np.zeros_like(rms), np.ascontiguousarray(sigma, dtype=np.float64).ravel(),
        float(inlier_factor))
    if known is None:
        return PixelStats(inliers, squares, counts)
    merged = PixelStats(*(np.zeros(n, a.dtype) for a in (inliers, squares, counts)))
    for mine, theirs, fresh in zip((merged.inliers, merged.squares, merged.counts),
                                   (known.inliers, known.squares, known.counts),
                                   (inliers, squares, counts)):
        m = min(n, theirs.size)
        mine[:m] = theirs[:m]
        mine[measure] = fresh[measure]
    return merged


def stats_with_moved(stats: PixelStats, xyz: np.ndarray, sigma: np.ndarray, before: np.ndarray,
                     after: np.ndarray, table: tuple, changed: np.ndarray, inlier_factor: float) -> PixelStats:
    """``stats`` (of the labels ``before``) made those of the labels ``after`` where only the
    flat pixels ``changed`` moved: their share taken from their old labels and given to their
    new ones, with no pass over the frame. The models of the regions they left or joined must
    be unchanged; ``table`` (:func:`rangeseg_o3d.fitting.region_fitter.model_table`) holds
    every model of ``after``. ``xyz`` (N, 3) and ``sigma`` (N,) are flat."""
    kinds, params, rms = table
    n = kinds.size
    points, noise = xyz[changed], sigma[changed]
    old = np.ascontiguousarray(before.ravel()[changed], dtype=np.int32)
    new = np.ascontiguousarray(after.ravel()[changed], dtype=np.int32)
    lost = kernels.distance_stats(points, old, kinds, params, np.zeros_like(rms), noise, float(inlier_factor))
    won = kernels.distance_stats(points, new, kinds, params, np.zeros_like(rms), noise, float(inlier_factor))
    merged = []
    for known, minus, plus in zip((stats.inliers, stats.squares, stats.counts), lost, won):
        grown = np.zeros(n, known.dtype)
        m = min(n, known.size)
        grown[:m] = known[:m]
        grown = grown - minus.astype(known.dtype) + plus.astype(known.dtype)
        merged.append(np.maximum(grown, 0))
    return PixelStats(*merged)


def smallest_region(config, sensor, cloud) -> int:
    """The fewest pixels of a full-resolution region: the refinement's ``min_region_size``
    (derived from the sensor when the preset leaves it), at least 10.

    A grazing face a few pixels wide (a box side) is no larger. The bands of other surfaces
    a blob this small may hold fit the plane along their viewing rays within the range
    noise; recover_pixels holds a recovered plane to the noise of its distances, which
    refuses them (a doubled floor kept them out, and those faces too)."""
    return max(int(with_derived_refinement(config, sensor, cloud).min_region_size), 10)


def without_regions(labels: np.ndarray, fits: dict, drop: list) -> tuple[np.ndarray, dict]:
    """``(labels, fits)`` with the regions in ``drop`` unlabelled and their models gone; the
    inputs themselves when ``drop`` is empty."""
    if not drop:
        return labels, fits
    keep = np.arange(max(int(labels.max(initial=0)), max(drop)) + 1, dtype=labels.dtype)
    keep[drop] = 0
    return keep[labels], {k: m for k, m in fits.items() if k not in drop}


def free_untold_regions(tile_labels: np.ndarray, labels: np.ndarray, fits: dict,
                        stats: PixelStats) -> tuple[np.ndarray, dict, PixelStats]:
    """Tile regions no model was fitted to: their pixels (``labels``, in the tile labels'
    numbering) become unlabelled, left to the full-resolution steps, which recover them as
    a blob (split into the surfaces they hold, searched pixel by pixel) or grow a neighbour
    that explains them into them.

    Eight 6 x 6 tiles of a stereo frame's floor beside a box at the frame's edge pass the
    tile grid's smallest region (``scales.MIN_CELLS``) but not the primitive fitter's ten
    points; kept, they were a 288-px unfitted region inside the floor's pixels, and the floor
    counted as over-segmented. A larger region the fitter refused and the tile grid's split
    found nothing in holds surfaces the tile means blur: a Kinect's far box, its three faces
    3-4 m away in 102 tiles, stayed one unfitted region and all three were missed
    (kinect_real_640x480 seed 1168 scan 5); its pixels' split finds the largest face. What the
    recovery cannot explain stays in no region. Returns ``(labels, fits, stats)``, the
    statistics of the freed labels set to none; the inputs themselves when none is freed.
    """
    tile_counts = np.bincount(tile_labels.ravel())
    untold = [k for k in range(1, tile_counts.size) if tile_counts[k] > 0 and not fits.get(k)]
    if not untold:
        return labels, fits, stats
    labels, fits = without_regions(labels, fits, untold)
    arrays = [values.copy() for values in (stats.inliers, stats.squares, stats.counts)]
    for values in arrays:
        values[[k for k in untold if k < values.size]] = 0
    return labels, fits, PixelStats(*arrays)


def drop_small_regions(labels: np.ndarray, fits: dict, stats: PixelStats, *,
                       min_size: int, recovered_from: int | None = None,
                       recovered_min_size: int | None = None) -> tuple[np.ndarray, dict]:
    """Regions left with fewer than ``min_size`` pixels are no surfaces: their pixels
    become unlabelled and their models go.

    A tile model can take only a pixel or two of the frame (the pixels of its tiles lie
    nearer other models); such a region is no surface any step creates, and one stray
    pixel inside another surface makes that surface over-segmented. Regions numbered from
    ``recovered_from`` on were found at full resolution, their models fitted to their
    pixels (:func:`recover_thin_surfaces`,
    :func:`rangeseg_o3d.crease_planes.planes_for_creases`): they are held to ``recovered_min_size``, the floor they were recovered under
    (:func:`recovered_region_floor`), not to a floor that counts tile means they never had
    (a 125-pixel box face recovered whole on a 4-pixel tile grid, whose floor is 128).
    Returns ``(labels, fits)``, the inputs themselves when nothing is dropped; ``stats``
    hold the labels' pixel counts.
    """
    counts = stats.counts
    first = np.iinfo(np.int64).max if recovered_from is None else int(recovered_from)
    floor_recovered = min_size if recovered_min_size is None else int(recovered_min_size)
    drop = [k for k in fits if 0 < k < counts.size
            and 0 < counts[k] < (floor_recovered if k >= first else min_size)]
    return without_regions(labels, fits, drop)


def recovered_region_floor(config, min_size: int, correlation_px: int = 1) -> int:
    """The fewest pixels of a region recovered at full resolution: the fewest returns that
    tell a plane (``scales.MIN_PIXELS``), counted in independent returns (a sensor whose
    noise errs together over ``correlation_px`` x ``correlation_px`` pixels, a stereo
    camera's matching window, needs that many times more pixels), at most ``min_size``: the
    thin strips of a face seen edge-on are recovered from there on every sensor, and what
    the recovery finds is fitted to pixels, not to the tile means the tile floor ``min_size``
    counts. (``config`` is kept for the callers; the surfaces split out of a cored blob have
    their own floor: :func:`_split_floor`.)"""
    return min(MIN_PIXELS * int(correlation_px) ** 2, min_size)


def _split_floor(config, min_size: int, correlation_px: int = 1) -> int:
    # The fewest pixels of a surface recover_pixels splits out of a blob with a 3x3 core. With
    # close_gaps (ABW) the recovered floor; on the real-time presets the blob floor: with the
    # recovered floor there, a cylinder's 15-px-wide strip clipped by the image border was
    # split out as a plane (kinect seed 71 scan 2, a new false fitting).
    return recovered_region_floor(config, min_size, correlation_px) if config.close_gaps else min_size


def recover_thin_surfaces(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *, fitter,
                          config, sensor, ranges: np.ndarray, sigma: np.ndarray,
                          inlier_factor: float, released: np.ndarray | None = None,
                          blobs: tuple | None = None, strips: bool = True):
    """Surfaces the tile grid lost (thinner than it sees, or small faces between creases it
    could not see), recovered from the pixels no tile model took.

    Returns ``(labels, fits, stats)``. When no such blob is left over (most frames), the
    inputs come back untouched at the cost of one pass over the labels; otherwise
    :func:`rangeseg_o3d.refinement.recover.recover_pixels` fits the blobs and the statistics of
    the regions whose pixels or models changed are measured again. ``released``: the
    labels of pixels :func:`off_model_blocks` freed (0 elsewhere), or None;
    ``blobs``: ``(candidates, boxes, first_thin)`` of :func:`leftover_blob_labels` to recover instead
    of all of them; ``strips`` (without ``blobs``): the strips too thin for a blob are recovered
    too (else only the blobs: :func:`rangeseg_o3d.strips.recover_strips` takes the strips later).
    """
    from .refinement.recover import recover_pixels
    config = with_derived_refinement(config, sensor, cloud)  # values left to the sensor
    min_size = smallest_region(config, sensor, cloud)
    # Every leftover blob, thin or not: besides surfaces thinner than the tile grid's 3x3
    # window, small faces between creases it could not see, and faces the split left
    # over, are lost whole; recover_pixels splits each blob into the surfaces it holds.
    # A face seen edge-on is a strip two or three pixels across: no 3x3 core, so it comes
    # as a thin blob, whose floor is the fewest returns that tell a plane (the tile floor
    # counts tile means, which never held it). On every preset: their pixels on a plane
    # region's surface join it first (recover_pixels' claim_on_distance_noise: the edge
    # bands of a face), and what is left is one plane or none (split_blobs' thin path: the
    # fitter's plane, held to the noise of its distances).
    first = fresh_label(labels, fits)
    correlation_px = sensor.noise.correlation_px
    thin = recovered_region_floor(config, min_size, correlation_px) if strips else 0
    found = blobs if blobs is not None else leftover_blob_labels(labels, cloud.valid, min_size=min_size,
                                                                 first_label=first, thin_min_size=thin, with_free=True)
    if found is None:
        return labels, fits, stats
    candidates, boxes, first_thin = found[:3]
    free = found[3] if len(found) > 3 else None  # (the free pixels of ``labels``: the pass listed them)
    # The tile models carry the rms of the tile means (a tile of t x t returns averages
    # the range noise down by up to t); from here on they are compared with models fitted
    # to pixels (the merge's rms test, the claim's noise floor), so they carry the rms of
    # their pixels, as the Result reports it.
    fits = with_pixel_rms(fits, stats)
    before, fits_before = labels, fits  # recover_pixels changes a copy of the labels, not them
    # the blobs are at least min_size, the surfaces found in them are fitted to pixels: they
    # are held to the floor of a recovered region (a box side beside the table's plane in one
    # blob, fewer pixels than the tile grid's floor, is a surface all the same)
    changes = {}
    labels, fits = recover_pixels(cloud, labels, dict(fits), fitter=fitter, config=config,
                                  sensor=sensor, ranges=ranges, sigma=sigma, candidates=candidates,
                                  min_size=_split_floor(config, min_size, correlation_px), boxes=boxes,
                                  thin_from=first_thin, released=released, changes=changes, free=free)
    # the statistics follow the pixels that moved, not a pass over the regions they moved between
    after = np.ascontiguousarray(labels, dtype=before.dtype)
    moved = _moved_pixels(before, after, changes.get("where"), changes.get("claimed_at"))
    refitted = {k for k, model in fits.items() if fits_before.get(k) is not model}
    stats = stats_after_moves(cloud.xyz, sigma, before, after, fits, stats, moved, refitted,
                              inlier_factor=inlier_factor, first_new=first)
    return labels, fits, stats


def recover_freed_pixels(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, freed: np.ndarray, *,
                         fitter, config, sensor, ranges: np.ndarray, sigma: np.ndarray, inlier_factor: float):
    """The surfaces the pixels a step just freed hold, recovered as :func:`recover_thin_surfaces`
    recovers the leftover blobs, but from the blobs of those pixels only.

    A step that gives a region's pixels to a neighbour whose plane explains them frees the
    rest; when that region held more than the neighbour's piece (a stereo camera's cylinder
    over a far wall and the front and side of a box before it: the wall's pixels went back to
    the wall and the box's 6255 were left in no region), those pixels are surfaces the
    recovery never saw, as they were labelled when it ran. ``freed``: their flat indices
    (unlabelled in ``labels``). Returns ``(labels, fits, stats)``; the inputs when they make no
    blob of the smallest region's size.
    """
    config = with_derived_refinement(config, sensor, cloud)
    min_size = smallest_region(config, sensor, cloud)
    if freed.size < min_size:
        return labels, fits, stats
    mask = np.zeros(labels.size, bool)
    mask[freed] = True
    mask &= np.asarray(cloud.valid).reshape(-1)
    found = leftover_blob_labels(labels, mask.reshape(labels.shape), min_size=min_size,
                                 first_label=fresh_label(labels, fits))
    if found is None:
        return labels, fits, stats
    return recover_thin_surfaces(cloud, labels, fits, stats, fitter=fitter, config=config, sensor=sensor,
                                 ranges=ranges, sigma=sigma, inlier_factor=inlier_factor, blobs=found)


def _moved_pixels(before: np.ndarray, after: np.ndarray, where=None, claimed_at=None) -> np.ndarray:
    """Flat indices (increasing) of the pixels whose label differs between ``before`` and
    ``after``, compared only in ``where`` (a ``(row0, row1, col0, col1)`` box or a ``(K, 4)``
    array of them; None: the whole grid) which must hold every such pixel but those of
    ``claimed_at`` (flat indices): the recovery changes its blobs and the rings around them,
    and the free pixels its last claim took, not the frame."""
    from .refinement.recover import differing_pixels

    moved = differing_pixels(before, after, where)
    if claimed_at is not None and len(claimed_at):
        moved = unique_ints(np.concatenate([moved, np.asarray(claimed_at, dtype=np.int64)]))
    return moved


def stats_after_moves(xyz: np.ndarray, sigma: np.ndarray, before: np.ndarray, after: np.ndarray, fits: dict,
                      stats: PixelStats, moved: np.ndarray, refitted, *, inlier_factor: float,
                      first_new: int | None = None) -> PixelStats:
    """The :class:`PixelStats` of the labels ``after`` under ``fits``, from ``stats`` (those
    of ``before``) and the flat pixels ``moved`` (increasing), which must hold every pixel
    whose label differs: :func:`region_stats` of the labels ``after`` with the labels the
    moves touched and those of ``refitted`` (a new or refitted model) measured again.

    Labels numbered from ``first_new`` on lie above every label of ``before``: all their
    pixels moved. When every label of ``refitted`` is such a label, no pass over the frame is
    made: a label whose model is the one ``stats`` were measured with gives and takes the
    moved pixels' shares (:func:`stats_with_moved`: the same counts, the squared sum to its
    last digits, as the order of the sum differs), a label left without a model has none,
    and a refitted one is measured over the moved pixels in raster order, as
    :func:`region_stats` measures it. A refitted region ``before`` had (its pixels lie
    anywhere) is measured over the frame with every label the moves touched, by one
    :func:`region_stats`. ``xyz`` (H, W, 3) or (N, 3); ``sigma`` one value per pixel.
    """
    moved = np.asarray(moved, dtype=np.int64)
    if moved.ndim != 1 or (moved.size and (moved.min() < 0 or moved.max() >= after.size)):
        raise ValueError(f"stats_after_moves: moved must be flat indices of the {after.shape} labels, "
                         f"got shape {moved.shape}" + (f", {int(moved.min())}..{int(moved.max())}" if moved.size else ""))
    touched = unique_ints(np.concatenate([before.ravel()[moved], after.ravel()[moved]]).astype(np.int64)).tolist()
    n = int(after.max(initial=0)) + 1
    first = n if first_new is None else int(first_new)
    # (a label the known statistics do not cover is measured too)
    anew = {k for k in refitted if k > 0} | {k for k in touched if k >= stats.counts.size}
    if any(k < first for k in anew):  # its pixels lie anywhere: one pass over the frame for all
        return region_stats(xyz, after, fits, sigma, inlier_factor, known=stats, stale=set(touched) | anew)
    flat_xyz = np.ascontiguousarray(xyz.reshape(-1, 3))
    noise = np.ascontiguousarray(sigma, dtype=np.float64).ravel()
    table = model_table(fits, n)
    kinds = table[0]
    out = stats_with_moved(stats, flat_xyz, noise, before, after, table, moved, inlier_factor)
    new = sorted(k for k in anew if k < n)
    if new:  # every pixel of a new region moved to it: the raster order of its pixels
        measure = np.zeros(n, bool)
        measure[new] = True
        inliers, squares, counts = kernels.distance_stats(
            flat_xyz[moved], np.ascontiguousarray(after.ravel()[moved], dtype=np.int32),
            np.where(measure, kinds, 0).astype(kinds.dtype), table[1], np.zeros(n), noise[moved], float(inlier_factor))
        out.inliers[new], out.squares[new], out.counts[new] = inliers[new], squares[new], counts[new]
    for k in touched:  # (region_stats gives a label without a model nothing)
        if 0 < k < n and kinds[k] == 0:
            out.inliers[k], out.squares[k], out.counts[k] = 0, 0.0, 0
    return out


def with_pixel_rms(fits: dict, stats: PixelStats) -> dict:
    """``fits`` with each model's rms replaced by the rms distance of its region's pixels
    (``stats``, in the same labels); a model whose region has no pixel keeps its own."""
    out = dict(fits)
    for k, model in fits.items():
        rms = stats.rms(k) if model else None
        if rms is not None:
            out[k] = with_statistics(model, rms=rms)
    return out


#: Pixels of a region on which :func:`planes_for_unresolved` tests its curvature (an even
#: subsample: a resolved curvature shows on a thousand pixels by orders of magnitude).
UNRESOLVED_TEST_PIXELS = 1024


def planes_for_unresolved(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *,
                          sigma: np.ndarray, inlier_factor: float, tile_labels: np.ndarray | None = None,
                          tile: int = 1, by_distance_noise: bool = False, fitter=None,
                          samples: float = 1.0) -> tuple[dict, PixelStats]:
    """Each cylinder or sphere whose curvature its pixels do not resolve becomes their plane.

    A curved model fitted to tile means can follow means that straddle an edge (a tile
    half on a plane, half on the surface behind), bending over a flat face; its pixels
    then show no curvature: their plane explains them as well, or better, than the curved
    model (:func:`rangeseg_o3d.fitting.robust.curvature_resolved`, the F-test of the drop
    in squared distances against the curved model's own residuals), on an even subsample
    of at most ``UNRESOLVED_TEST_PIXELS`` of the region's pixels, over the independent
    samples they carry (``samples`` each pixel, each point of the sample counting those of
    the ``sample_step`` x ``sample_step`` pixels it stands for, at most one; a sample that
    leaves no degree of freedom resolves nothing). Counted one a pixel, the returns of a
    camera that err together over 9 x 9 pixels resolved a sphere of r 2.9 m over a region
    of 1365, 1300 on one plane and 65 on its neighbours (kinect_real study seed 1442 scan
    4: the plane 7.95 mm rms over the region, the sphere 7.26; a false fitting); over
    their independent samples the drop is noise. Returns ``(fits, stats)``,
    the statistics of replaced models measured again; untouched when no model is curved.
    With ``tile_labels`` (the tile grid the models came from, ``tile`` pixels a side) a
    region's pixels are looked for in its tiles' box grown by a tile (pixels take only the
    models of their tile and the 8 around it), not in the whole frame.

    ``by_distance_noise`` (where the range noise exceeds the grid's footprint, a Kinect's): a
    curved model that explains the region's pixels within the noise of their distances is kept
    when their plane does not: there a pipe a few dozen pixels across spreads farther along its
    rays than across them, and their plane, turned towards the rays, leaves fewer squared
    distances than the true cylinder (kinect fresh seed 1018 scan 0: 10.3 against 12.5 mm)
    while lying beyond the noise of its distances (9.1 mm), which the cylinder's (14.2 mm)
    holds.

    With ``fitter`` (a :class:`rangeseg_o3d.fitting.region_fitter.RegionFitter` of pixels),
    the model's kind is first refitted to those pixels from the tile model
    (:func:`resolved_refit`, over the same independent samples): the tile means of a far
    pipe bend a cylinder whose radius or axis the pixels do not share, so its own residuals
    resolve nothing, while the pipe's pixels resolve the cylinder refitted to them; that
    one replaces it, and only a region whose refit resolves no curvature either becomes
    its plane. A region whose curvature its pixels resolve takes the other curved kind
    where the fitter's decision on the sample gives it (:func:`other_curved_kind`).
    """
    from .fitting.plane import fit_plane
    from .fitting.primitives import Plane
    from .fitting.robust import curvature_resolved

    curved = [k for k, m in fits.items()
              if m and not isinstance(m, Plane) and 0 < k < stats.counts.size and stats.counts[k] > 0]
    if not curved:
        return fits, stats
    fits, replaced, boxes = dict(fits), [], LabelBoxes(labels)
    tile_boxes = None if tile_labels is None else LabelBoxes(tile_labels)
    for k in curved:
        box = pixel_box(boxes, k, tile_boxes, tile)
        points = region_sample(cloud, labels, k, box)
        plane = fit_plane(points) if len(points) >= 6 else None
        if not plane:
            continue
        squares = squared_distances(fits[k], points)
        # the sample's points lie sample_step pixels apart: each carries step^2 pixels' share of
        # independent samples, at most one (a step as wide as a stereo camera's window: one each)
        share = min(1.0, samples * sample_step(labels[box].size) ** 2)
        independent = int(len(points) * share)
        # (no more independent samples than a plane's 3 parameters and the test's 2 more: no
        # noise left to test a curvature against, and the refit below decides)
        if independent > 3 + 2 and curvature_resolved(independent * plane.rms ** 2,
                                                      independent / len(points) * squares, independent):
            other = None if fitter is None else other_curved_kind(fitter, points, fits[k], squares)
            if other is not None:
                fits[k] = replace(other, inliers=int(stats.counts[k]))
                replaced.append(k)
            continue
        if by_distance_noise and only_curved_within_noise(fits[k], cloud.xyz, sigma, labels, k, box):
            continue
        refit = None if fitter is None else resolved_refit(fitter, points, fits[k], plane.rms, share)
        fits[k] = replace(refit if refit is not None else plane, inliers=int(stats.counts[k]))
        replaced.append(k)
    if replaced:
        stats = region_stats(cloud.xyz, labels, fits, sigma, inlier_factor, known=stats, stale=replaced)
    return fits, stats


def other_curved_kind(fitter, points: np.ndarray, model, squares: float):
    """The fitter's model of ``points`` when it is a cylinder where ``model`` is a sphere
    or a sphere where it is a cylinder, and leaves fewer squared distances than ``model``'s
    ``squares`` there and than ``model``'s kind refitted to them; else None.

    The kind was decided on tile means: a short piece of a pipe the frame's edge cuts (its
    visible length under its diameter) gives means that a sphere fits as well as its
    cylinder, while its pixels do not (kinect_real seed 1079 scan 1: a pipe of r 0.12 m at
    2 m, 0.21 m of it seen at the frame's left edge, was a sphere of r 0.15 m at 6.6 mm rms
    over the region's sample, where its cylinder leaves 4.4 mm; a false fitting). The
    fitter's own decision on the pixels judges the kinds; a plane it gives is left to the
    curvature test (:func:`planes_for_unresolved`)."""
    from .fitting.primitives import Plane

    if isinstance(model, Plane) or not model:
        return None
    decided = other_curved_decision(fitter, points, model.kind)
    if decided is None:
        return None
    other = squared_distances(decided, points)
    if other >= squares:
        return None
    # against the model's kind refitted to the same points: the decision fitted the other
    # kind there, and a tile model held beside it loses by its fit alone (kinect study seed
    # 1478 scan 0: a ball cut by the frame's edge, a sample of 509 of its pixels; the
    # decision's cylinder 9.14 mm rms, the tile sphere 9.15, the sphere refitted there 9.12)
    own = fitter.refit(points, model)
    if own and own.kind == model.kind and squared_distances(own, points) <= other:
        return None
    return decided


def resolved_refit(fitter, points: np.ndarray, model, plane_rms: float, samples: float = 1.0):
    """``model``'s kind refitted to ``points`` from ``model`` when it resolves its curvature
    there, else None.

    The refit (``fitter.refit``, Levenberg-Marquardt from ``model``) is held to the kind's
    own thresholds (rms, radius, arc) but not to the fitter's curvature gain: the points'
    plane (rms ``plane_rms``) was within the noise, where the decision asks a curved model
    only to beat it by more than noise would (an F-test over the independent samples,
    ``samples`` per point: a stereo camera's pixels err together over its matching window,
    :meth:`rangeseg_o3d.sensor.NoiseModel.independent_share`), as for a plane whose quadric
    resolves a bend (``fit_primitive(resolve_bends=...)``). A kinect pipe at 5.4 m, 0.17 m
    across: its tile cylinder left its pixels 25.9 mm off against their plane's 23.6, the
    cylinder refitted to them 22.3 mm, resolved over 420 pixels by 50 noise variances.
    """
    from .fitting.primitives import Plane
    from .fitting.robust import curvature_resolved

    if not samples > 0:
        raise ValueError(f"samples must be > 0; got {samples}")
    if isinstance(model, Plane) or not model:
        return None
    refit = fitter.refit(points, model, curvature_gain=1.0)
    if not refit or isinstance(refit, Plane):
        return None
    m = len(points) * float(samples)
    squares = float(np.mean(refit.distances(points) ** 2))
    extra = 2 if refit.kind == "cylinder" else 1  # the parameters a cylinder, a sphere adds to a plane
    if not curvature_resolved(m * plane_rms ** 2, m * squares, max(int(m), 1), extra):
        return None
    return refit


def drop_unresolvable_curves(labels: np.ndarray, fits: dict, *, depth_step: float) -> tuple[np.ndarray, dict]:
    """Cylinders and spheres whose radius is at most ``RELIEF_STEPS`` depth steps are no
    surfaces: their pixels become unlabelled and their models go.

    A sensor that reports depth in steps of ``depth_step`` shows a curved surface of
    radius ``R`` as at most ``R / depth_step`` terraces (:mod:`rangeseg_o3d.scales`); a
    patch of the camera's error standing a few steps off a flat face makes as many, and a
    cylinder of a few millimetres fits it (ABW: 2-3 mm cylinders of 60-120 pixels inside
    faces). Returns ``(labels, fits)``, the inputs themselves when nothing is dropped (always
    when ``depth_step`` is 0: the depth is not quantised).
    """
    from .fitting.primitives import Plane
    if depth_step <= 0:
        return labels, fits
    limit = RELIEF_STEPS * depth_step
    drop = [k for k, m in fits.items() if m and not isinstance(m, Plane) and m.radius <= limit]
    return without_regions(labels, fits, drop)


def settle_plane_borders(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *, sigma: np.ndarray,
                         ranges: np.ndarray, k_sigma: float, jump_ratio: float, jump_min: float, iterations: int,
                         inlier_factor: float, wrap_columns: bool = False):
    """Border pixels of a plane region that a touching plane explains clearly better move
    to it, ring by ring (:func:`rangeseg_o3d.kernels.settle_borders` with the tile grid's
    rule: the neighbour's plane within ``k_sigma`` and nearer than the pixel's own by more
    than ``grow.SETTLE_MARGIN``, both in units of ``max(sigma, rms)``; none across a range
    jump), up to ``iterations`` rings deep. Returns ``(labels, stats)``, the statistics of
    the regions that changed updated with the pixels that moved; the models do not change.

    A face the tile grid did not see (a small block face whose tiles straddled its crease)
    is recovered at full resolution from the pixels the tile models left; its border band,
    within ``k_sigma`` of the neighbour's tile model when :func:`label_pixels` gave it out,
    stays with that neighbour even where the neighbour's plane, refitted to its pixels, leaves
    it many sigmas off (tabletop_abw seed 827 scan 5: a block face lost a band 8-10 pixels
    wide, 1.3-2.7 mm off the table-side plane that held it and 0.2 mm off its own). The
    recovery's claims reach a few rings; the settling the tile grid does between every pair
    of regions is not done at full resolution for two planes otherwise
    (:func:`settle_creases` moves only pixels both planes explain). Curved regions neither
    move nor take here (:func:`settle_curved_into_planes` gives a plane their rims).
    """
    from .refinement.grow import SETTLE_MARGIN

    n = int(labels.max(initial=0)) + 1
    planes = [k for k, m in fits.items() if m and m.kind == "plane" and 0 < k < n]
    if len(planes) < 2 or iterations < 1:
        return labels, stats
    table = model_table(fits, n)
    kinds = np.zeros_like(table[0])
    kinds[planes] = table[0][planes]  # neither moving nor taking: every other region
    settled = np.array(labels, dtype=np.int32, order="C", copy=True)
    xyz = np.ascontiguousarray(_flat_points(cloud), dtype=np.float64)
    noise = np.ascontiguousarray(sigma, dtype=np.float64).ravel()
    moved = kernels.settle_borders(xyz, settled, kinds, table[1], table[2],
                                   noise, np.ascontiguousarray(ranges, dtype=np.float64).ravel(), int(iterations),
                                   float(k_sigma), SETTLE_MARGIN, float(jump_ratio), float(jump_min), SETTLE_MARGIN,
                                   bool(wrap_columns))  # (the kernel's curved-to-plane margin: no curved region here)
    if not moved:
        return labels, stats
    changed = np.flatnonzero(settled.ravel() != np.asarray(labels).ravel())
    return settled, stats_with_moved(stats, xyz, noise, labels, settled, table, changed, inlier_factor)


#: Pixel rings from a crease within which :func:`settle_creases` decides by the rays.
CREASE_RINGS = 3
# the (row, column) steps to the pixels within CREASE_RINGS 4-steps, nearest first
_STEPS = np.array(sorted(((dr, dc) for dr in range(-CREASE_RINGS, CREASE_RINGS + 1)
                          for dc in range(-CREASE_RINGS, CREASE_RINGS + 1) if 0 < abs(dr) + abs(dc) <= CREASE_RINGS),
                         key=lambda step: (abs(step[0]) + abs(step[1]), step)), dtype=np.int64)


def settle_creases(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *, sigma: np.ndarray,
                   k_sigma: float, min_angle_deg: float, inlier_factor: float, along_rays: bool = False):
    """Pixels beside a crease between two planes go to the face their ray meets there.

    Where two faces meet at a crease both planes lie within the noise of the pixels
    beside it, and the nearer model is the noise's choice (ABW: a 123-pixel face losing
    26 border pixels to the table, 0.26 against 0.46 mm). The two planes decide it
    without the noise: along a pixel's ray the visible face is, at a concave crease (each
    region in front of the other's plane, as a block on a table), the plane met first, at
    a convex one (each behind the other's), the plane met last. Within ``CREASE_RINGS``
    4-steps of a plane region its own touches, a pixel of a plane region moves there when the
    rays say so, both planes explain it within ``k_sigma max(sigma, rms)``, the planes are
    turned by more than ``min_angle_deg`` and the ray meets each at least
    ``atan(GRAZING_TAN)`` from grazing (an edge-on face's plane holds the rays near its
    image line: a table beside it would follow). Decisions are taken on the labels as they
    were; the models do not change (:func:`rangeseg_o3d.kernels.crease_moves`, one compiled
    pass). Returns ``(labels, stats)``, the statistics of the regions that changed updated
    with the pixels that moved; the inputs when no pixel moves.

    ``along_rays`` (a stereo camera's noise): each plane explains the pixel when its ray meets
    the plane within ``k_sigma`` range sigmas of its range (or ``k_sigma`` times the plane's rms
    over the ray's incidence cosine), not when the plane passes within that distance of it: a
    range error moves a return along its ray, and a plane seen near grazing passes within
    ``k_sigma`` range sigmas of returns many sigmas off it along their rays (a far box face
    seen at 80 degrees took 352 floor pixels 13 range sigmas off its plane along their rays).
    """
    from .fitting.primitives import Plane
    from .kernels import crease_moves

    n = int(labels.max(initial=0)) + 1
    planes = [k for k, m in fits.items() if isinstance(m, Plane) and 0 < k < n]
    if len(planes) < 2:
        return labels, stats
    normals, offsets, rms, is_plane = np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros(n, bool)
    for k in planes:
        m = fits[k]
        sign = -1.0 if m.d > 0 else 1.0  # the sensor's side of every plane positive
        normals[k], offsets[k], rms[k], is_plane[k] = sign * np.asarray(m.normal), sign * m.d, m.rms, True
    xyz = _flat_points(cloud)
    noise = np.ascontiguousarray(sigma, dtype=np.float64).ravel()
    if noise.size != labels.size or xyz.shape[0] != labels.size:  # the kernel does not check its bounds
        raise ValueError(f"settle_creases: sigma and the cloud need one value a pixel of the {labels.shape} labels, "
                         f"got {noise.size} and {xyz.shape[0]}")
    out, moved = crease_moves(xyz, np.ascontiguousarray(labels, dtype=np.int32), is_plane, normals, offsets, rms,
                              noise, float(k_sigma), float(np.cos(np.radians(min_angle_deg))),
                              float(np.sin(np.arctan(GRAZING_TAN))), _STEPS, CREASE_RINGS, bool(along_rays))
    if not moved.size:
        return labels, stats
    out = out.astype(labels.dtype, copy=False)
    table = model_table(fits, max(n, stats.counts.size))
    return out, stats_with_moved(stats, xyz, noise, labels, out, table, moved, inlier_factor)


#: a plane is a cylinder's end cap only when it faces along the axis within this angle's
#: cosine (45 degrees: a cap's plane fitted to a few hundred stereo pixels turns by several)
CAP_COS = float(np.sqrt(0.5))
#: rounds of :func:`settle_caps`: each moves the border by up to CREASE_RINGS - 1 pixels
CAP_ROUNDS = 4


def settle_caps(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *, sigma: np.ndarray,
                k_sigma: float, inlier_factor: float):
    """Pixels beside the rim of a cylinder's end cap go to the surface their ray enters.

    A stereo camera's range noise spans both the cap and the pipe's side over a band of
    pixels at the rim (at 4-5 m, 0.05-0.08 m a sigma), and the nearer model was the noise's
    choice: a cap seen at 60 degrees kept 74-78 % of its pixels, the pipe's region held the
    rest. Within the noise the models decide instead: the pipe's solid is the intersection of
    the cylinder and the cap's half-space, and a ray shows the one it enters last
    (:func:`rangeseg_o3d.kernels.cap_moves`; a plane is a cap when it faces along the axis
    within ``CAP_COS``, its region's centroid lies inside the cylinder and the cylinder
    region's behind the plane). A pixel moves only when both models explain it within
    ``k_sigma`` times its range noise (or their rms) and its ray meets both at least
    ``atan(GRAZING_TAN)`` from grazing, within ``CREASE_RINGS`` 4-steps of the border, for up
    to ``CAP_ROUNDS`` rounds, cylinder by cylinder in its box grown by the rings the rounds may
    move (the regions' centroids are those of their pixels there; a plane is asked only when
    the cylinder's model point lies behind it). The models do not change. Returns ``(labels,
    stats)``; the inputs when no pixel moves.
    """
    from .fitting.primitives import Cylinder, Plane
    from .kernels import cap_moves, label_boxes

    n = int(labels.max(initial=0)) + 1
    noise = np.ascontiguousarray(sigma, dtype=np.float64)
    if noise.shape != labels.shape or cloud.xyz.shape[:2] != labels.shape:  # the kernel does not check its bounds
        raise ValueError(f"settle_caps: sigma and the cloud need one value a pixel of the {labels.shape} labels, "
                         f"got {noise.shape} and {cloud.xyz.shape[:2]}")
    planes = {k: m for k, m in fits.items() if isinstance(m, Plane) and 0 < k < n}
    cylinders = {k: m for k, m in fits.items() if isinstance(m, Cylinder) and 0 < k < n}
    if not (planes and cylinders):
        return labels, stats
    normals, offsets, axes, points = np.zeros((n, 3)), np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3))
    radii, rms = np.zeros(n), np.zeros(n)
    for k, m in planes.items():
        sign = -1.0 if m.d > 0 else 1.0  # the sensor's side of every plane positive
        normals[k], offsets[k], rms[k] = sign * np.asarray(m.normal), sign * m.d, m.rms
    for k, m in cylinders.items():
        axes[k], points[k], radii[k], rms[k] = m.axis, m.point, m.radius, m.rms
    plane_ids = np.array(sorted(planes), np.int64)
    # the caps the models allow (the kernel checks the regions' centroids): a plane facing along
    # the axis with the cylinder's middle (its model's point, nearest its pixels' centroid) behind it
    candidates = {}
    for q in cylinders:
        facing = np.abs(normals[plane_ids] @ axes[q]) >= CAP_COS
        behind = normals[plane_ids] @ points[q] - offsets[plane_ids] < 0
        if (facing & behind).any():
            candidates[q] = plane_ids[facing & behind]
    if not candidates:
        return labels, stats
    boxes = label_boxes(np.ascontiguousarray(labels, dtype=np.int32), n)
    h, w = labels.shape
    margin = CREASE_RINGS * CAP_ROUNDS + 1  # the rounds move the border by fewer 4-steps than this
    settled = None  # the frame's labels copied at the first move (most frames have none)
    xyz = cloud.xyz
    least_cos = float(np.sin(np.arctan(GRAZING_TAN)))
    changed = []
    # cylinder by cylinder, within its box grown by the rings the rounds may move (a pass over
    # the 1280 x 720 frame per round cost 30-60 ms a stereo scan); there only it and its caps move
    for q, caps in candidates.items():
        r0, r1 = max(boxes[q, 0] - margin, 0), min(boxes[q, 1] + margin, h)
        c0, c1 = max(boxes[q, 2] - margin, 0), min(boxes[q, 3] + margin, w)
        caps = [p for p in caps if boxes[p, 0] < r1 and boxes[p, 1] > r0 and boxes[p, 2] < c1 and boxes[p, 3] > c0]
        if not caps or r1 <= r0 or c1 <= c0:
            continue
        kind = np.zeros(n, np.int8)  # neither moving nor taking: every other region
        kind[caps], kind[q] = 1, 2
        source = labels if settled is None else settled
        crop = np.ascontiguousarray(source[r0:r1, c0:c1], dtype=np.int32)
        out, step = cap_moves(np.ascontiguousarray(xyz[r0:r1, c0:c1].reshape(-1, 3), dtype=np.float64), crop, kind,
                              normals, offsets, axes, points, radii, rms,
                              np.ascontiguousarray(noise[r0:r1, c0:c1]).ravel(), float(k_sigma), least_cos, CAP_COS,
                              _STEPS, CREASE_RINGS, CAP_ROUNDS)
        if not step.size:
            continue
        if settled is None:
            settled = labels.copy()
        settled[r0:r1, c0:c1] = out
        rows, cols = np.nonzero(out != labels[r0:r1, c0:c1])  # a pixel may have moved there and back
        changed.append((rows + r0) * w + cols + c0)
    if settled is None:
        return labels, stats
    changed = np.unique(np.concatenate(changed))  # (crops of two cylinders may overlap)
    if not changed.size:
        return labels, stats
    table = model_table(fits, max(n, stats.counts.size))
    return settled, stats_with_moved(stats, _flat_points(cloud), noise.ravel(), labels, settled, table, changed,
                                     inlier_factor)


def grow_into_free(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *, sigma: np.ndarray,
                   ranges: np.ndarray, k_sigma: float, jump_ratio: float, jump_min: float,
                   inlier_factor: float) -> tuple[np.ndarray, PixelStats, np.ndarray]:
    """Every region grows into the free pixels next to it that its model explains, ring after
    ring until none joins (:func:`rangeseg_o3d.kernels.grow_free`).

    A pixel takes only the models of its tile's region and the 8 around it
    (:func:`label_pixels`): a face a few pixels wide between creases, or where a tile
    straddled an occluding edge, keeps a strip of free pixels farther than a tile from its
    region's tiles, and two pieces of one face the tile grid kept apart stay apart. The test is
    :func:`label_pixels`' (the model within ``k_sigma`` noise sigmas, ``sigma`` the sensor's
    at each pixel, the model's rms the floor) plus the sensor's jump test between the pixel
    and the neighbour it joins, so growth stops at occluding edges and where the surface
    leaves the model; into a plane, a step the plane itself makes between the two rays is no
    jump (a face seen at a grazing angle steps by more than the jump threshold from pixel to
    pixel). ``stats`` take the pixels that join (no second pass).

    Returns ``(labels, stats, touch)``, ``touch`` the (n, n) bool matrix of labels the
    grown pixels made 4-neighbours. ``labels`` (C-contiguous int32) is changed in place.
    """
    from .kernels import grow_free

    if labels.dtype != np.int32 or not labels.flags.c_contiguous or not labels.flags.writeable:
        raise ValueError(f"labels must be a writeable C-contiguous int32 image; got {labels.dtype}, "
                         f"contiguous={labels.flags.c_contiguous}, writeable={labels.flags.writeable}")
    n = max(int(labels.max(initial=0)) + 1, stats.counts.size)
    kinds, params, rms = model_table(fits, n)
    grown = PixelStats(*(np.zeros(n, a.dtype) for a in (stats.inliers, stats.squares, stats.counts)))
    for mine, theirs in zip((grown.inliers, grown.squares, grown.counts),
                            (stats.inliers, stats.squares, stats.counts)):
        mine[:theirs.size] = theirs
    touch = np.zeros((n, n), np.bool_)
    grow_free(_flat_points(cloud), labels, kinds, params, rms,
              np.ascontiguousarray(sigma, dtype=np.float64).ravel(),
              np.ascontiguousarray(ranges, dtype=np.float64).ravel(), float(k_sigma), float(jump_ratio),
              float(jump_min), float(inlier_factor), grown.inliers, grown.squares, grown.counts, touch)
    return labels, grown, touch


def refit_planes_to_pixels(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *, sigma: np.ndarray,
                           rms_factor: float, inlier_factor: float) -> tuple[dict, PixelStats]:
    """Plane regions whose pixels their own least-squares plane fits ``rms_factor`` times
    better than the tile model does take that plane; returns ``(fits, stats)``.

    The tile models are fitted to tile means. Where a face is a few tiles wide and seen at
    a grazing angle, the tiles along its edges average it with what lies beside it, and the
    model can tilt far off the face (a strip 12 pixels wide of a face seen 5 deg from edge-on
    gave a plane through the camera, 2.5 mm off the face's free pixels, pixel rms 0.93 mm
    against 0.035 mm for the pixels' own plane). Growth then judges the face's free pixels
    against the wrong model. The pixels' planes come from one pass of label moments
    (:func:`rangeseg_o3d.fitting.batch_planes.region_moments`); ``rms_factor`` is the one the
    merges judge a worse fit by.
    """
    from .fitting.batch_planes import planes_from_moments, region_moments
    from .fitting.primitives import Plane

    n = min(int(labels.max(initial=0)) + 1, stats.counts.size)
    planes = [k for k, m in fits.items() if isinstance(m, Plane) and 0 < k < n and stats.counts[k] >= 3]
    if not planes:
        return fits, stats
    own = planes_from_moments(region_moments(_flat_points(cloud), labels.ravel(), n))
    better = [k for k in planes if own.ok[k] and stats.rms(k) > rms_factor * own.rms[k]]
    if not better:
        return fits, stats
    fits = dict(fits)
    for k in better:
        fits[k] = replace(fits[k], normal=own.normal[k].copy(), d=float(own.d[k]), rms=float(own.rms[k]))
    return fits, region_stats(cloud.xyz, labels, fits, sigma, inlier_factor, known=stats, stale=set(better))


def merge_touching_planes(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, touch: np.ndarray, *,
                          sigma: np.ndarray, max_angle_deg: float, rms_factor: float, inlier_factor: float,
                          near: np.ndarray | None = None):
    """Planes that meet at full resolution and whose union one plane explains become one region.

    The merge on the tile grid pairs regions whose tiles touch; two pieces of one face the
    tile grid kept apart (a band of tiles straddling a false crease, a narrow stretch of a
    face at a grazing angle) meet only once every pixel is labelled and the regions have
    grown (:func:`grow_into_free`, whose ``touch`` says which labels it made 4-neighbours;
    ``near``, same shape, optional: pairs whose pixels may be, looked for in their box). A
    touching pair of planes whose normals agree within ``max_angle_deg`` (the models', or
    the planes of their pixels: tile models the tiles along a crease turned, tabletop_abw
    seed 1166 scan 3: 4.7 degrees apart where the pixels' planes are 1.5), or whose
    smaller piece's pixels lie on the larger's plane of pixels within ``rms_factor`` times
    the pieces' rms (a strip of 67 px whose own normal is 10 degrees off, seed 1163 scan
    2), merges when the least-squares plane of both pieces' pixels (an even sample of about
    half ``UNRESOLVED_TEST_PIXELS`` of each) has an rms at most ``rms_factor`` times
    the larger of the pieces' own planes' on the same sample: the tile merge's rule, on
    pixels. A region merged already stands for its union in the pairs after (pieces that
    meet pairwise join in a chain). Returns ``(labels, fits, stats)``;
    ``labels`` is changed in place.
    """
    from .fitting.batch_planes import planes_from_moments, region_moments
    from .fitting.plane import fit_plane
    from .fitting.primitives import Plane
    from .kernels import label_boxes, labels_touch

    planes = [k for k, m in fits.items() if isinstance(m, Plane) and 0 < k < touch.shape[0]
              and 0 < k < stats.counts.size and stats.counts[k] > 0]
    if len(planes) < 2:
        return labels, fits, stats
    normals = np.array([fits[k].normal for k in planes])
    cosine = np.cos(np.radians(max_angle_deg)) - 1e-12
    close = np.abs(normals @ normals.T) >= cosine
    maybe = (touch if near is None else touch | near)[np.ix_(planes, planes)]
    # a tile model turned off its face by the tiles along a crease (a face a few tiles wide)
    # is not what its pixels say: their own planes are asked too, and a piece too small for
    # its normal to tell lies on the larger piece's plane within the pieces' rms
    moments = region_moments(_flat_points(cloud), labels.ravel(), touch.shape[0])
    own = planes_from_moments(moments)
    own_normals = own.normal[planes] * own.ok[planes, None]
    close = maybe & (close | (np.abs(own_normals @ own_normals.T) >= cosine)
                     | _smaller_on_larger(moments[planes], own, planes, rms_factor))
    first, second = np.nonzero(np.triu(close, 1))
    if not first.size:
        return labels, fits, stats
    pairs = sorted(((planes[i], planes[j]) for i, j in zip(first.tolist(), second.tolist())),
                   key=lambda ab: (stats.rms(ab[0]) + stats.rms(ab[1]), ab))
    boxes = label_boxes(labels, touch.shape[0])
    fits, box_of, root, count = dict(fits), {}, {}, {}  # (root: the labels merged into another)
    for first_a, first_b in pairs:
        # a piece merged already stands for its union: three or four tile pieces of one face
        # that meet pairwise join in a chain (tabletop_abw study seed 1386 scan 0: a box top
        # of 14390 px left as pieces of 9221 and 4889 px, 0.07 degrees apart)
        a, b = _root(root, first_a), _root(root, first_b)
        if a == b:
            continue
        box_a, box_b = box_of.get(a, _box_slices(boxes[a])), box_of.get(b, _box_slices(boxes[b]))
        box = (slice(min(box_a[0].start, box_b[0].start), max(box_a[0].stop, box_b[0].stop)),
               slice(min(box_a[1].start, box_b[1].start), max(box_a[1].stop, box_b[1].stop)))
        if not touch[first_a, first_b] and not labels_touch(labels, a, b, box[0].start, box[0].stop,
                                                            box[1].start, box[1].stop):
            continue
        sample_a, sample_b = (_even_sample(labels, cloud.xyz, k, count.get(k, int(stats.counts[k])), own)
                              for k, own in ((a, box_a), (b, box_b)))
        if min(len(sample_a), len(sample_b)) < 6:
            continue
        part_a, part_b = fit_plane(sample_a), fit_plane(sample_b)
        union = fit_plane(np.vstack([sample_a, sample_b]))
        if not (part_a and part_b and union) or union.rms > rms_factor * max(part_a.rms, part_b.rms):
            continue
        window = labels[box]
        window[window == b] = a
        count[a] = count.get(a, int(stats.counts[a])) + count.pop(b, int(stats.counts[b]))
        fits[a] = replace(union, inliers=count[a])
        del fits[b]
        root[b] = a
        box_of[a] = box
        box_of.pop(b, None)
    if root:
        stats = PixelStats(*(a.copy() for a in (stats.inliers, stats.squares, stats.counts)))
        for k in root:  # merged into another: no pixels left
            stats.inliers[k], stats.squares[k], stats.counts[k] = 0, 0.0, 0
    for a, box in box_of.items():  # every pixel of a merged region lies in its pair's box
        inside = region_stats(cloud.xyz[box], labels[box], {a: fits[a]}, sigma[box], inlier_factor)
        stats.inliers[a], stats.squares[a], stats.counts[a] = inside.inliers[a], inside.squares[a], inside.counts[a]
    return labels, fits, stats


def _even_sample(labels: np.ndarray, xyz: np.ndarray, label: int, pixels: int, box: tuple) -> np.ndarray:
    # the points (``xyz``) of about UNRESOLVED_TEST_PIXELS / 2 of ``label``'s ``pixels``, on
    # an even grid of its own over its ``box`` (row and column slices holding all of them): a
    # piece a hundredth the size of its partner (a strip of the table beside the table) is
    # sampled as densely as that, and only its own box is read
    step = max(int(np.sqrt(pixels / (UNRESOLVED_TEST_PIXELS // 2))), 1)
    rows, cols = slice(box[0].start, box[0].stop, step), slice(box[1].start, box[1].stop, step)
    return xyz[rows, cols][labels[rows, cols] == label]


def _root(root: dict, k: int) -> int:
    # the label a region merged into stands under (itself when it merged into none)
    while k in root:
        k = root[k]
    return k


def _box_slices(box) -> tuple:
    # a (top, bottom, left, right) row of label_boxes as a pair of slices
    return slice(int(box[0]), int(box[1])), slice(int(box[2]), int(box[3]))


def _smaller_on_larger(moments: np.ndarray, own, planes: list, rms_factor: float) -> np.ndarray:
    """(K, K) bool, symmetric: the pixels of the smaller of two planes (``moments`` their
    rows, ``own`` the label-wise planes of the frame, ``planes`` the labels) lie on the
    larger's own plane within ``rms_factor`` times the larger of the two planes' rms."""
    from .refinement.merge import pieces_on_planes

    index = np.asarray(planes)
    ok = own.ok[index]
    normals = own.normal[index] * ok[:, None]
    return pieces_on_planes(normals, own.d[index], np.where(ok, own.rms[index], 0.0), moments, rms_factor) \
        & ok[:, None] & ok[None, :]


class LabelBoxes:
    """Every label's bounding box on the sensor grid, found by one compiled pass on first use
    (:func:`rangeseg_o3d.kernels.label_boxes`): a pass per label costs a full-frame
    comparison and its ``nonzero`` each."""

    def __init__(self, labels: np.ndarray, n: int | None = None):
        # ``n``: the labels' count when the caller knows it (boxes for labels below it only;
        # else the labels' largest plus one, a pass over the grid)
        self.labels = labels
        self._boxes = None
        self._n = n

    def __call__(self, k: int) -> tuple[slice, slice]:
        """Rows and columns holding every pixel of label ``k`` (which has pixels)."""
        row0, row1, col0, col1 = self.bounds(k)
        return slice(row0, row1), slice(col0, col1)

    def array(self) -> np.ndarray:
        """Every label's ``(row0, row1, col0, col1)`` (half-open), label ``k`` in row ``k``:
        ``(h, 0, w, 0)`` for a label without pixels (and for label 0). Not to be written."""
        if self._boxes is None:
            from .kernels import label_boxes

            labels = np.ascontiguousarray(self.labels, dtype=np.int32)
            n = int(labels.max(initial=0)) + 1 if self._n is None else int(self._n)
            self._boxes = label_boxes(labels, n)
        return self._boxes

    def bounds(self, k: int) -> tuple[int, int, int, int]:
        """``(row0, row1, col0, col1)`` (half-open) of label ``k``; ``(h, 0, w, 0)`` when it
        has no pixels."""
        self.array()
        if not 0 < k < self._boxes.shape[0]:
            h, w = self.labels.shape
            return h, 0, w, 0
        return tuple(self._boxes[k].tolist())


def pixel_box(boxes: LabelBoxes, k: int, tile_boxes: LabelBoxes | None, tile: int) -> tuple[slice, slice]:
    """Rows and columns of the sensor grid holding every pixel of label ``k``: its tiles' box
    (``tile_boxes``, the boxes of the tile grid's labels, ``tile`` pixels a side) grown by a
    tile, or, for a region the tiles did not have, its own box (``boxes``: the labels'
    boxes on the sensor grid)."""
    row0, row1, col0, col1 = tile_boxes.bounds(k) if tile_boxes is not None else (0, 0, 0, 0)
    if row1 > row0:  # (one compiled pass over the tile grid for every region, not a comparison each)
        return slice(max(row0 - 1, 0) * tile, (row1 + 1) * tile), slice(max(col0 - 1, 0) * tile, (col1 + 1) * tile)
    return boxes(k)  # a region the tiles did not have (recovered pixels)


def sample_step(size: int) -> int:
    """The grid step of :func:`region_sample` in a box of ``size`` pixels."""
    return max(int(np.ceil(np.sqrt(size / UNRESOLVED_TEST_PIXELS))), 1)


def region_sample(cloud, labels: np.ndarray, k: int, box: tuple[slice, slice]) -> np.ndarray:
    """The valid points of label ``k`` in ``box`` on an even grid of about
    ``UNRESOLVED_TEST_PIXELS`` pixels (every :func:`sample_step`-th row and column)."""
    h, w = labels.shape
    (row0, row1, _), (col0, col1, _) = box[0].indices(h), box[1].indices(w)  # numpy's clipping
    step = sample_step(max(row1 - row0, 0) * max(col1 - col0, 0))
    # one compiled pass (the same points in the same order as numpy's slices, mask and
    # finite test, which cost ~30 microseconds a region in small-array calls)
    return kernels.label_sample(cloud.xyz, labels, int(k), row0, row1, col0, col1, step)


def only_curved_within_noise(curved, xyz: np.ndarray, sigma: np.ndarray, labels: np.ndarray, k: int,
                             box: tuple[slice, slice]) -> bool:
    """:func:`curved_alone_within_noise` on all of region ``k``'s pixels (in ``box``), as the
    chi-square bound of a few hundred sampled ones lets a plane along the rays pass."""
    mine = labels[box] == k
    points, noise = xyz[box][mine], np.asarray(sigma)[box][mine]
    finite = np.isfinite(points).all(axis=1)
    return curved_alone_within_noise(curved, points[finite], noise[finite])


def curved_alone_within_noise(curved, points: np.ndarray, noise: np.ndarray, plane=None) -> bool:
    """Whether the ``curved`` model explains ``points`` (range noise ``noise``) within the
    noise of their distances to it (range noise times the incidence cosine; chi-square bound)
    and their least-squares ``plane`` (fitted here when not given) does not."""
    from .fitting.plane import fit_plane
    from .fitting.robust import beyond_noise, distance_noise

    n = len(points)
    if plane is None:
        plane = fit_plane(points) if n >= 6 else None
    if not plane:
        return False
    curved_rms = float(np.sqrt(np.mean(curved.distances(points) ** 2)))
    curved_noise, plane_noise = distance_noise(curved, points, noise), distance_noise(plane, points, noise)
    return (not beyond_noise(curved_rms, float(np.sqrt(np.mean(curved_noise ** 2))), n)
            and beyond_noise(float(plane.rms), float(np.sqrt(np.mean(plane_noise ** 2))), n))


def leftover_blob_labels(labels: np.ndarray, valid: np.ndarray, *, min_size: int, first_label: int,
                         thin_min_size: int = 0, with_free: bool = False):
    """Every blob of valid unlabelled pixels, numbered from ``first_label``, with its box:
    ``(candidates, boxes, first_thin)``, blob ``first_label + j``'s bounding box ``(row0, row1,
    col0, col1)``, half-open, in row ``j``; None if there are none.

    The blobs are those of :func:`rangeseg_o3d.refinement.recover.leftover_candidates` (no
    jump mask), found by one compiled pass that stops as soon as it sees nothing is left over.
    With ``thin_min_size``, the 4-connected pieces of at least that many leftover pixels that
    no such blob took (strips too thin for a 3x3 core) follow them, numbered from ``first_thin``
    (:func:`rangeseg_o3d.kernels.leftover_blobs`; without, ``first_thin`` is past the last blob).
    With ``with_free``, the flat indices (increasing) of every valid unlabelled pixel, which
    the pass lists, follow as a fourth item (:func:`recover_thin_surfaces` hands them to the
    recovery's last claim of free pixels, which then scans only where the recovery worked).
    """
    candidates, boxes, n_cored, free = kernels.leftover_blobs(np.ascontiguousarray(labels), np.ascontiguousarray(valid),
                                                              int(min_size), int(first_label), int(thin_min_size))
    if not boxes.shape[0]:
        return None
    found = candidates, boxes, int(first_label) + int(n_cored)
    return (*found, free) if with_free else found


def _flat_points(cloud) -> np.ndarray:
    return np.ascontiguousarray(cloud.xyz.reshape(-1, 3))


def settle_curved_into_planes(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *, sigma: np.ndarray,
                              ranges: np.ndarray, config, sensor, recovered_from: int, inlier_factor: float,
                              iterations: int = 8):
    """The border pixels of curved regions that a touching plane found at full resolution
    (labels ``>= recovered_from``) explains nearer, within ``config.k_sigma`` noise sigmas,
    move to it, ring by ring (:func:`rangeseg_o3d.kernels.settle_borders` with the
    refinement's curved-to-plane rule, ``grow.PLANE_MARGIN``; no other move, none across a
    range jump), plane by plane within its box grown by ``iterations + 1`` pixels (no
    seam of a 360-degree grid). Returns ``(labels, fits, stats)``; the inputs when nothing
    moved.

    A pipe's end cap seen near edge-on is a few pixels wide: the tile means straddle it,
    so the pipe's tile model took its pixels within the noise, and the plane recovered from
    the pixels left off that model (:func:`rangeseg_o3d.off_model.recover_off_model`)
    claims only a few rings back. The cap's pixels lie on its plane far within the noise
    of their distances, and on the cylinder a sigma or more off it: the tile grid's settle
    step, run again here with the cap's plane, gives them back. The models do not change.
    """
    from .kernels import label_boxes
    from .refinement.grow import PLANE_MARGIN

    n = int(labels.max(initial=0)) + 1
    curved = [k for k, m in fits.items() if m and m.kind != "plane" and 0 < k < n]
    planes = [k for k, m in fits.items() if m and m.kind == "plane" and recovered_from <= k < n]
    if not (curved and planes):
        return labels, fits, stats

    table = model_table(fits, n)
    config = with_derived_refinement(config, sensor, cloud)
    h, w = labels.shape
    boxes = label_boxes(np.ascontiguousarray(labels, dtype=np.int32), n)
    reach = int(iterations) + 1
    settled = np.array(labels, dtype=np.int32, order="C", copy=True)
    xyz = cloud.xyz
    moved = 0
    # plane by plane, in its box grown by the rings it may take (a pass over the frame per
    # ring cost 9-13 ms on the real frames that have curved regions): only that plane and the
    # curved regions move or take there, and only where a curved region's box meets it
    for k in planes:
        r0, r1 = max(boxes[k, 0] - reach, 0), min(boxes[k, 1] + reach, h)
        c0, c1 = max(boxes[k, 2] - reach, 0), min(boxes[k, 3] + reach, w)
        near = [j for j in curved if boxes[j, 0] < r1 and boxes[j, 1] > r0 and boxes[j, 2] < c1 and boxes[j, 3] > c0]
        if not near or r1 <= r0 or c1 <= c0:
            continue
        kinds = np.zeros_like(table[0])
        kinds[[k] + near] = table[0][[k] + near]  # neither moving nor taking: every other region
        crop = np.ascontiguousarray(settled[r0:r1, c0:c1])
        step = kernels.settle_borders(
            np.ascontiguousarray(xyz[r0:r1, c0:c1].reshape(-1, 3), dtype=np.float64), crop, kinds, table[1], table[2],
            np.ascontiguousarray(sigma[r0:r1, c0:c1], dtype=np.float64).ravel(),
            np.ascontiguousarray(ranges[r0:r1, c0:c1], dtype=np.float64).ravel(), int(iterations),
            float(config.k_sigma), np.inf, float(config.jump_ratio), float(config.jump_min), PLANE_MARGIN,
            False)  # (a crop's first and last columns are no seam)
        if step:
            settled[r0:r1, c0:c1] = crop
            moved += step
    if not moved:
        return labels, fits, stats
    xyz = np.ascontiguousarray(cloud.xyz.reshape(-1, 3), dtype=np.float64)
    noise = np.ascontiguousarray(sigma, dtype=np.float64).ravel()
    changed = np.flatnonzero(settled.ravel() != labels.ravel())
    return settled, fits, stats_with_moved(stats, xyz, noise, labels, settled, table, changed, inlier_factor)
