"""Pixels a tile model took one by one that lie off it as a group, freed and recovered.

:func:`rangeseg_o3d.fullres.label_pixels` judges each pixel alone, within the noise of a
model; at a depth camera's noise that lets a model take a strip of the surface beside it
(a wall cut by the image's edge next to the wall it meets, a pipe's end cap). As a group
such pixels stand off the model:

- :func:`off_model_blocks`: the tiles whose pixels of a label lie, on the mean, beyond the
  noise of that mean off the label's model (from the sums ``label_pixels`` gathered in its
  own pass), kept only in groups turned from that model, freed;
- :func:`recover_off_model`: the leftover blobs those freed pixels make, recovered as
  surfaces of their own (:func:`rangeseg_o3d.fullres.recover_thin_surfaces`); what no
  surface takes goes back to the region it was freed from.
"""

from __future__ import annotations

import numpy as np

from .fitting.region_fitter import fresh_label, model_table
from .fullres import PixelStats, leftover_blob_labels, recover_thin_surfaces, smallest_region

__all__ = ["OFF_MODEL_MARGIN", "off_model_blocks", "recover_off_model"]


#: The bound of :func:`off_model_blocks` over ``CHI_SQUARE_SIGMAS`` noises of a tile's mean:
#: sqrt(pi / 2), the noise of a median of many values over that of their mean. The test was
#: first made on tile medians; on the mean's own noise it also freed a wall corner of a real
#: frame (pcl_milk_cartoon) 6 degrees off its plane, which the recovery then gave back (3 ms
#: for nothing), and won no simulated surface more (kinect_640x480 seeds 0 and 11 alike).
OFF_MODEL_MARGIN = float(np.sqrt(np.pi / 2.0))


def off_model_blocks(labels: np.ndarray, blocks: tuple, fits: dict, tile_fits: dict, *, tile: int,
                     spread: float = 1.0, depth_step: float = 0.0, xyz: np.ndarray | None = None,
                     max_angle_deg: float | None = None, min_pixels: int = 3):
    """Pixels that lie, tile by tile, on one side of the model that took them, freed.

    :func:`label_pixels` judges each pixel alone, within ``k_sigma`` noises of a model. At
    a depth camera's noise that lets a model take a strip of the surface beside it: a wall
    cut by the image's edge next to the wall it meets, whose tiles averaged both, or a pipe's
    end cap on the pipe. One by one such pixels are within the noise; as a group they are
    not: their mean distance stands off the model by many times the noise of that mean
    (:func:`rangeseg_o3d.kernels.off_model_tiles`, from the sums ``blocks`` that
    :func:`label_pixels` gathered with the tile models ``tile_fits``) and by many times the
    spread of the region's other tile means about its model (a real surface is not its
    model: a wall bent by the camera's depth distortion stands off its plane tile after tile
    by more than the noise of a mean, everywhere). A tile's pixels of a label are freed when
    its mean is beyond ``CHI_SQUARE_SIGMAS`` times ``OFF_MODEL_MARGIN`` times the largest of:
    its noise times ``spread`` (>= 1: how much more a mean of a tile's returns errs than
    independent returns would, correlated noise or the measured excess of the tile means),
    the region's robust spread, and, on a sensor that reports depth in steps of
    ``depth_step``, the quantisation's rms ``depth_step / sqrt(12)`` (a tile of a face sits
    on its terraces).
    Labels whose model in ``fits`` is no longer their tile model's surface are not tested.
    With ``max_angle_deg`` (and the flat points ``xyz``), only the tiles of a group of
    touching such tiles, of at least ``min_pixels`` pixels, whose plane is turned from the
    model most of them were taken by (:func:`_turned_groups`) are freed: the others are a
    bend of that surface, or too few to be most of a blob, and their recovery would buy
    nothing for its cost.

    Returns ``(labels, released, freed)``: the labels with those pixels 0, the (H, W) labels
    the freed pixels had (0 elsewhere) and their flat indices (raster order);
    ``(labels, None, None)`` when no pixel is freed.
    """
    from .fitting.robust import CHI_SQUARE_SIGMAS
    from .kernels import free_blocks, off_model_tiles

    first, owners, taken, sums, whole = blocks
    if whole.shape[1] != -(-labels.shape[1] // tile):  # blocks row-major over the label grid
        return labels, None, None
    n = max(int(labels.max(initial=0)), int(owners.max(initial=0))) + 1
    kinds, params, rms = model_table(fits, n)
    tile_kinds, tile_params, _ = model_table(tile_fits, n)
    # the sums were taken against the tile models: only labels whose model is still that
    # surface (the recovery before may have given it its pixels' rms, which is the noise floor)
    same = (params == tile_params) | (np.isnan(params) & np.isnan(tile_params))
    usable = (kinds != 0) & (kinds == tile_kinds) & same.all(axis=1)
    tiles, freed_from = off_model_tiles(first, owners, taken, sums, whole, kinds, params, rms, usable,
                                        float(max(spread, 1.0)), float(depth_step) / np.sqrt(12.0),
                                        float(CHI_SQUARE_SIGMAS) * OFF_MODEL_MARGIN)
    if not tiles.size:
        return labels, None, None
    if max_angle_deg is not None:
        keep = _turned_groups(xyz, labels, tiles, freed_from, fits, tile=tile, max_angle_deg=max_angle_deg,
                              min_pixels=min_pixels)
        tiles, freed_from = tiles[keep], freed_from[keep]
        if not tiles.size:
            return labels, None, None
    out = np.array(labels, dtype=np.int32, order="C")
    released = np.zeros(out.shape, np.int32)
    pixels = free_blocks(out, int(tile), tiles, freed_from, released)
    if not pixels.size:
        return labels, None, None
    return out, released, pixels


def recover_off_model(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, *, blocks: tuple, tile_fits: dict,
                      tile: int, spread: float, fitter, config, sensor, ranges: np.ndarray, sigma: np.ndarray,
                      inlier_factor: float):
    """The surfaces beside the regions' models: the pixels :func:`off_model_blocks` frees
    are recovered (:func:`recover_thin_surfaces`, only the leftover blobs that hold some of
    them), and those no surface takes go back to the region they were freed from.
    Returns ``(labels, fits, stats)``; the inputs when no pixel is freed or no blob holds one.
    """
    # only blobs whose freed pixels could be a surface of their own are worth a recovery: a
    # blob is at least min_size pixels, and more than half of them freed (_mostly_new)
    min_size = smallest_region(config, sensor, cloud)
    freed, released, pixels = off_model_blocks(labels, blocks, fits, tile_fits, tile=tile, spread=spread,
                                               depth_step=sensor.depth_step, xyz=np.ascontiguousarray(cloud.xyz.reshape(-1, 3)),
                                               max_angle_deg=config.merge_angle_deg, min_pixels=min_size // 2)
    if released is None:
        return labels, fits, stats
    first = fresh_label(freed, fits)
    found = leftover_blob_labels(freed, cloud.valid, min_size=min_size, first_label=first)
    if found is None:
        return labels, fits, stats
    candidates, boxes, _ = found
    held = np.unique(candidates.reshape(-1)[pixels])
    held = _turned_from_source(held[held > 0], candidates, cloud.xyz.reshape(-1, 3), pixels,
                               released.reshape(-1)[pixels], fits, config.merge_angle_deg)
    if held.size:  # the blobs the recovery before left over (it tried them): not again for a few freed pixels
        before = leftover_blob_labels(labels, cloud.valid, min_size=min_size, first_label=1)
        held = _mostly_new(held, candidates, boxes, first, None if before is None else before[0] > 0)
    if not held.size:
        return labels, fits, stats
    blobs = _renumbered(candidates, boxes, held, first)
    freed_stats = _shifted_stats(stats, cloud, pixels, released.reshape(-1)[pixels], fits, sigma, inlier_factor, -1)
    out, fits_out, stats_out = recover_thin_surfaces(cloud, freed, fits, freed_stats, fitter=fitter, config=config,
                                                     sensor=sensor, ranges=ranges, sigma=sigma,
                                                     inlier_factor=inlier_factor, released=released, blobs=blobs)
    if out is freed:  # no blob holds a freed pixel: nothing was recovered
        return labels, fits, stats
    alive = np.zeros(int(released.max()) + 1, bool)
    alive[[k for k in range(1, alive.size) if fits_out.get(k)]] = True
    back = np.flatnonzero((out == 0) & alive[released])
    if back.size:
        out = np.array(out, dtype=np.int32, order="C")
        owners = released.ravel()[back]
        out.ravel()[back] = owners
        stats_out = _shifted_stats(stats_out, cloud, back, owners, fits_out, sigma, inlier_factor, +1)
    return out, fits_out, stats_out


def _shifted_stats(stats: PixelStats, cloud, pixels: np.ndarray, owners: np.ndarray, fits: dict,
                   sigma: np.ndarray, inlier_factor: float, sign: int) -> PixelStats:
    """``stats`` with the flat ``pixels`` (of labels ``owners``) added (``sign`` +1) to or taken
    (-1) from their labels' statistics: a pass over those pixels, not over the frame."""
    from .kernels import distance_stats

    n = max(stats.counts.size, int(owners.max(initial=0)) + 1)
    kinds, params, rms = model_table(fits, n)
    inliers, squares, counts = distance_stats(
        np.ascontiguousarray(cloud.xyz.reshape(-1, 3)[pixels]), np.ascontiguousarray(owners, dtype=np.int32),
        kinds, params, np.zeros_like(rms), np.ascontiguousarray(np.asarray(sigma, dtype=np.float64).ravel()[pixels]),
        float(inlier_factor))
    out = PixelStats(*(np.zeros(n, a.dtype) for a in (stats.inliers, stats.squares, stats.counts)))
    for mine, theirs, moved in zip((out.inliers, out.squares, out.counts), (stats.inliers, stats.squares, stats.counts),
                                   (inliers, squares, counts)):
        mine[:theirs.size] = theirs
        mine[:moved.size] += sign * moved
    np.maximum(out.squares, 0.0, out=out.squares)  # a label that lost all: no rounding below 0
    return out
def _mostly_new(held: np.ndarray, candidates: np.ndarray, boxes: np.ndarray, first: int,
                tried: np.ndarray | None) -> np.ndarray:
    """The blobs ``held`` (of ``candidates`` numbered from ``first``, ``boxes`` one row each)
    with at most half of their pixels in ``tried`` (None: all of them), counted in their boxes."""
    if tried is None:
        return held
    keep = []
    for blob in held.tolist():
        r0, r1, c0, c1 = (int(v) for v in boxes[blob - first])
        mine = candidates[r0:r1, c0:c1] == blob
        if 2 * np.count_nonzero(mine & tried[r0:r1, c0:c1]) <= np.count_nonzero(mine):
            keep.append(blob)
    return np.asarray(keep, dtype=held.dtype)


def _renumbered(candidates: np.ndarray, boxes: np.ndarray, held: np.ndarray, first: int):
    """The blobs ``held`` of ``candidates`` (numbered from ``first``, ``boxes`` one row
    each) alone, numbered again from ``first`` in their order, their boxes and the first
    number past them (no thin strips among them: see :func:`leftover_blob_labels`)."""
    lut = np.zeros(first + len(boxes), np.int32)
    lut[held] = np.arange(first, first + held.size, dtype=np.int32)
    return lut[candidates], boxes[held - first], first + int(held.size)


def _turned_from_source(held: np.ndarray, candidates: np.ndarray, xyz: np.ndarray, freed: np.ndarray,
                        sources: np.ndarray, fits: dict, max_angle_deg: float) -> np.ndarray:
    """Of the blobs ``held``, those whose freed pixels (flat ``freed``, each freed from the
    model of label ``sources``) could be a surface
    of their own beside the model they were freed from: their least-squares plane turned
    from the model's normal at their centroid (the model most of them were freed from) by
    more than ``max_angle_deg`` (the merge's angle) and by more than ``CHI_SQUARE_SIGMAS``
    times the noise of that plane's tilt (its rms over the root of the pixels' count times
    their rms extent across the direction it is least sure of). Freed pixels along the
    model's own orientation are a bend or step of that surface (a real wall bowed by the
    camera's depth distortion lies off its plane block after block): a surface found on
    them would take the model's orientation, and the recovery's cost would buy nothing."""
    blob_of = candidates.reshape(-1)[freed]
    keep = []
    for blob in held.tolist():
        in_blob = blob_of == blob
        source = int(np.bincount(sources[in_blob]).argmax()) if in_blob.any() else 0
        if _turned(xyz[freed[in_blob]], fits.get(source), max_angle_deg):
            keep.append(blob)
    return np.asarray(keep, dtype=held.dtype)


def _turned_groups(xyz: np.ndarray, labels: np.ndarray, tiles: np.ndarray, owners: np.ndarray, fits: dict, *,
                   tile: int, max_angle_deg: float, min_pixels: int = 3) -> np.ndarray:
    """Whether each tile ``tiles[j]`` (its pixels of label ``owners[j]``) is in a group of
    touching such tiles (:func:`rangeseg_o3d.kernels.tile_groups`; a surface beside two
    regions' models lies off both) of at least ``min_pixels`` such pixels, whose
    least-squares plane is turned from the model most of them were taken by
    (:func:`_turned_plane`; the groups' moments in one pass)."""
    from .kernels import tile_groups, tile_members

    group = tile_groups(tiles, -(-labels.shape[1] // tile))
    pixels, entries = tile_members(np.ascontiguousarray(labels, dtype=np.int32), int(tile), tiles, owners)
    groups = int(group.max(initial=-1)) + 1
    of_pixel = group[entries]
    counts = np.bincount(of_pixel, minlength=groups)
    big = np.flatnonzero(counts >= max(min_pixels, 3))
    if not big.size:
        return np.zeros(tiles.size, bool)
    points = xyz[pixels]
    centres = np.stack([np.bincount(of_pixel, points[:, a], groups) for a in range(3)], axis=1)[big]
    centres /= counts[big, None]
    slot = np.searchsorted(big, of_pixel)  # each pixel's row among the big groups
    inside = (slot < big.size) & (big[slot.clip(0, big.size - 1)] == of_pixel)
    slot = slot[inside]
    offsets = points[inside] - centres[slot]
    scatter = np.zeros((big.size, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            scatter[:, a, b] = scatter[:, b, a] = (np.bincount(slot, offsets[:, a] * offsets[:, b], big.size)
                                                   / counts[big])
    turned = np.zeros(groups, bool)
    owner_of = owners[entries]
    for j, g in enumerate(big.tolist()):
        source = int(np.bincount(owner_of[of_pixel == g]).argmax())
        turned[g] = _turned_plane(centres[j], scatter[j], int(counts[g]), fits.get(source), max_angle_deg)
    return turned[group]


def _turned(points: np.ndarray, model, max_angle_deg: float) -> bool:
    """Whether the least-squares plane of ``points`` (at least 3) is turned from ``model``
    (:func:`_turned_plane`)."""
    if model is None or points.shape[0] < 3:
        return False
    centre = points.mean(axis=0)
    return _turned_plane(centre, np.cov((points - centre).T, bias=True), points.shape[0], model, max_angle_deg)


def _turned_plane(centre: np.ndarray, scatter: np.ndarray, count: int, model, max_angle_deg: float) -> bool:
    """Whether the least-squares plane of ``count`` points (centroid ``centre``, scatter matrix
    ``scatter``, the mean of their outer products about it) is turned from ``model``'s normal
    at their centroid by more than ``max_angle_deg`` and by more than ``CHI_SQUARE_SIGMAS``
    times the noise of that plane's tilt (its rms over the root of the points' count times
    their rms extent across the direction it is least sure of)."""
    from .fitting.robust import CHI_SQUARE_SIGMAS

    if model is None:
        return False
    spreads, axes = np.linalg.eigh(scatter)
    if spreads[1] <= 0.0:
        return False
    facing = np.asarray(model.normals(centre[None]), dtype=np.float64)[0]
    cosine = min(abs(float(axes[:, 0] @ facing)) / float(np.linalg.norm(facing)), 1.0)
    tilt_noise = np.sqrt(max(spreads[0], 0.0) / (count * spreads[1]))
    return bool(np.arccos(cosine) > max(np.radians(max_angle_deg), CHI_SQUARE_SIGMAS * tilt_noise))
