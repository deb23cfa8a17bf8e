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

from .fitting.region_fitter import model_table

__all__ = ["ExpandedStages", "PixelStats", "expand", "label_pixels", "recover_thin_surfaces",
           "region_stats", "leftover_blob_labels", "with_pixel_rms", "planes_for_unresolved"]


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
                 k_sigma: float, inlier_factor: float) -> tuple[np.ndarray, PixelStats]:
    """Label every pixel of ``cloud`` by the models of its tile's region and the 8 around it.

    A pixel joins the nearest model in units of ``max(sigma, rms)`` if within ``k_sigma``
    (see :func:`rangeseg_o3d.kernels.label_pixels`). Returns the ``(H, W)`` int32 labels
    (in the tile labels' numbering) and the :class:`PixelStats` of those labels.
    """
    from .kernels import label_pixels as kernel

    kinds, params, rms = model_table(fits, int(tile_labels.max(initial=0)) + 1)
    labels, inliers, squares, counts = kernel(
        _flat_points(cloud), cloud.shape[0], cloud.shape[1],
        np.ascontiguousarray(tile_labels, dtype=np.int32), int(tile), kinds, params, rms,
        np.ascontiguousarray(sigma, dtype=np.float64).ravel(), float(k_sigma), float(inlier_factor))
    return labels, PixelStats(inliers, squares, counts)


def region_stats(xyz: np.ndarray, labels: np.ndarray, fits: dict, sigma: np.ndarray,
                 inlier_factor: float, *, known: PixelStats | None = None,
                 stale=()) -> PixelStats:
    """The :class:`PixelStats` of every label of ``labels`` under its model in ``fits``.

    With ``known`` (statistics of these labels measured earlier), only the labels in
    ``stale`` (whose pixels or model changed since) are measured again.
    """
    from .kernels import distance_stats

    n = int(labels.max(initial=0)) + 1
    kinds, params, rms = model_table(fits, n)
    if known is not None:
        measure = np.zeros(n, bool)
        measure[[k for k in stale if 0 < k < n]] = True
        kinds = np.where(measure, kinds, 0).astype(kinds.dtype)
    inliers, squares, counts = distance_stats(
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


def recover_thin_surfaces(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *, fitter,
                          config, sensor, ranges: np.ndarray, sigma: np.ndarray,
                          inlier_factor: float):
    """Surfaces the tile grid lost (thinner than it sees, or small faces between creases it
    could not see), recovered from the pixels no tile model took.

    Returns ``(labels, fits, stats)``. When no such blob is left over (most frames), the
    inputs come back untouched at the cost of one pass over the labels; otherwise
    :func:`rangeseg_o3d.refinement.recover.recover_pixels` fits the blobs and the statistics of
    the regions whose pixels or models changed are measured again.
    """
    from .refinement.recover import recover_pixels
    from .scales import with_derived_refinement

    config = with_derived_refinement(config, sensor, cloud)  # values left to the sensor
    # Twice the smallest region: a piece of a surface the tiles already have, left over
    # where its model drifts from the noisy far pixels, is smaller; a surface the tiles
    # could not see at all is not.
    min_size = 2 * max(int(config.min_region_size), 10)
    # Every leftover blob, thin or not: besides surfaces thinner than the tile grid's 3x3
    # window, small faces between creases it could not see, and faces the split left
    # over, are lost whole; recover_pixels splits each blob into the surfaces it holds.
    first = int(labels.max(initial=0)) + 1
    found = leftover_blob_labels(labels, cloud.valid, min_size=min_size, first_label=first, with_boxes=True)
    if found is None:
        return labels, fits, stats
    candidates, boxes = found
    # The tile models carry the rms of the tile means (a tile of t x t returns averages
    # the range noise down by up to t); from here on they are compared with models fitted
    # to pixels (the merge's rms test, the claim's noise floor), so they carry the rms of
    # their pixels, as the Result reports it.
    fits = with_pixel_rms(fits, stats)
    before, fits_before = labels.copy(), fits
    labels, fits = recover_pixels(cloud, labels, dict(fits), fitter=fitter, config=config,
                                  sensor=sensor, ranges=ranges, sigma=sigma,
                                  candidates=candidates, min_size=min_size, boxes=boxes)
    moved = before != labels
    stale = set(np.unique(before[moved]).tolist()) | set(np.unique(labels[moved]).tolist())
    stale |= {k for k, model in fits.items() if fits_before.get(k) is not model}
    stats = region_stats(cloud.xyz, labels, fits, sigma, inlier_factor, known=stats, stale=stale)
    return labels, fits, stats


def with_pixel_rms(fits: dict, stats: PixelStats) -> dict:
    """``fits`` with each model's rms replaced by the rms distance of its region's pixels
    (``stats``, in the same labels); a model whose region has no pixel keeps its own."""
    out = dict(fits)
    for k, model in fits.items():
        rms = stats.rms(k) if model else None
        if rms is not None:
            out[k] = replace(model, rms=rms)
    return out


#: Pixels of a region on which :func:`planes_for_unresolved` tests its curvature (an even
#: subsample: a resolved curvature shows on a thousand pixels by orders of magnitude).
UNRESOLVED_TEST_PIXELS = 1024


def planes_for_unresolved(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *,
                          sigma: np.ndarray, inlier_factor: float, tile_labels: np.ndarray | None = None,
                          tile: int = 1) -> tuple[dict, PixelStats]:
    """Each cylinder or sphere whose curvature its pixels do not resolve becomes their plane.

    A curved model fitted to tile means can follow means that straddle an edge (a tile
    half on a plane, half on the surface behind), bending over a flat face; its pixels
    then show no curvature: their plane explains them as well, or better, than the curved
    model (:func:`rangeseg_o3d.fitting.robust.curvature_resolved`, the F-test of the drop
    in squared distances against the curved model's own residuals), on an even subsample
    of at most ``UNRESOLVED_TEST_PIXELS`` of the region's pixels. Returns ``(fits, stats)``,
    the statistics of replaced models measured again; untouched when no model is curved.
    With ``tile_labels`` (the tile grid the models came from, ``tile`` pixels a side) a
    region's pixels are looked for in its tiles' box grown by a tile (pixels take only the
    models of their tile and the 8 around it), not in the whole frame.
    """
    from .fitting.plane import fit_plane
    from .fitting.primitives import Plane
    from .fitting.robust import curvature_resolved

    curved = [k for k, m in fits.items()
              if m and not isinstance(m, Plane) and 0 < k < stats.counts.size and stats.counts[k] > 0]
    if not curved:
        return fits, stats
    fits, replaced = dict(fits), []
    for k in curved:
        points = _region_sample(cloud, labels, k, _pixel_box(labels, k, tile_labels, tile))
        plane = fit_plane(points) if len(points) >= 6 else None
        if not plane:
            continue
        squares = float(np.sum(fits[k].distances(points) ** 2))
        if curvature_resolved(len(points) * plane.rms ** 2, squares, len(points)):
            continue
        fits[k] = replace(plane, inliers=int(stats.counts[k]))
        replaced.append(k)
    if replaced:
        stats = region_stats(cloud.xyz, labels, fits, sigma, inlier_factor, known=stats, stale=replaced)
    return fits, stats


def _pixel_box(labels: np.ndarray, k: int, tile_labels: np.ndarray | None, tile: int) -> tuple[slice, slice]:
    """Rows and columns of the sensor grid holding every pixel of label ``k``."""
    rows, cols = np.nonzero(tile_labels == k) if tile_labels is not None else ((), ())
    if len(rows):
        return (slice(max(int(rows.min()) - 1, 0) * tile, (int(rows.max()) + 2) * tile),
                slice(max(int(cols.min()) - 1, 0) * tile, (int(cols.max()) + 2) * tile))
    rows, cols = np.nonzero(labels == k)  # a region the tiles did not have (recovered pixels)
    return slice(int(rows.min()), int(rows.max()) + 1), slice(int(cols.min()), int(cols.max()) + 1)


def _region_sample(cloud, labels: np.ndarray, k: int, box: tuple[slice, slice]) -> np.ndarray:
    """The valid points of label ``k`` in ``box`` on an even grid of about
    ``UNRESOLVED_TEST_PIXELS`` pixels."""
    window = labels[box]
    step = max(int(np.ceil(np.sqrt(window.size / UNRESOLVED_TEST_PIXELS))), 1)
    points = cloud.xyz[box][::step, ::step][window[::step, ::step] == k]
    return points[np.isfinite(points).all(axis=1)]


def leftover_blob_labels(labels: np.ndarray, valid: np.ndarray, *, min_size: int,
                         first_label: int, with_boxes: bool = False):
    """Every blob of valid unlabelled pixels, numbered from ``first_label``, or None if there
    are none (with ``with_boxes``: ``(candidates, boxes)``, blob ``first_label + j``'s
    bounding box ``(row0, row1, col0, col1)``, half-open, in row ``j``).

    The blobs are those of :func:`rangeseg_o3d.refinement.recover.leftover_candidates` (no
    jump mask), found by one compiled pass that stops as soon as it sees nothing is left over.
    """
    from .kernels import leftover_blobs

    candidates, boxes = leftover_blobs(np.ascontiguousarray(labels), np.ascontiguousarray(valid),
                                       int(min_size), int(first_label))
    if not boxes.shape[0]:
        return None
    return (candidates, boxes) if with_boxes else candidates


def _flat_points(cloud) -> np.ndarray:
    return np.ascontiguousarray(cloud.xyz.reshape(-1, 3))
