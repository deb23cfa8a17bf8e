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

from ._numeric import unique_ints
from .fitting.region_fitter import fresh_label, model_table
from .fullres import PixelStats, leftover_blob_labels, recover_thin_surfaces, smallest_region
# (:func:`_ruled_out`'s screen leaves a decision within this of its threshold to numpy; its kernel
# takes no tilt decision on sums whose condition number passes 1e9, so the two stay far closer)
from .ray_planes import SCREEN_TOLERANCE

__all__ = ["OFF_MODEL_MARGIN", "faces_along_rays", "off_model_blocks", "recover_off_model"]


#: The bound of :func:`off_model_blocks` over ``CHI_SQUARE_SIGMAS`` noises of a tile's mean:
#: sqrt(pi / 2), the noise of a median of many values over that of their mean. The test was
#: first made on tile medians; on the mean's own noise it also freed a wall corner of a real
#: frame (pcl_milk_cartoon) 6 degrees off its plane, which the recovery then gave back (3 ms
#: for nothing), and won no simulated surface more (kinect_640x480 seeds 0 and 11 alike).
OFF_MODEL_MARGIN = float(np.sqrt(np.pi / 2.0))


def off_model_blocks(labels: np.ndarray, blocks: tuple, fits: dict, tile_fits: dict, *, tile: int,
                     spread: float = 1.0, depth_step: float = 0.0, xyz: np.ndarray | None = None,
                     max_angle_deg: float | None = None, min_pixels: int = 3, unturned: list | None = None):
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
    nothing for its cost. ``unturned`` (a list, optional) receives ``(tiles, owners)`` of the
    tiles found off their model that no such group holds (for :func:`faces_along_rays`).

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
        if unturned is not None and not keep.all():
            unturned.append((tiles[~keep], freed_from[~keep]))
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
    them), and those no surface takes go back to the region they were freed from; the
    groups of tiles off their model it does not free (too few pixels for a blob, or a
    least-squares plane whose tilt the range noise hides) may each hold a face whose plane,
    fitted along the rays, is turned from that model (:func:`faces_along_rays`).
    Returns ``(labels, fits, stats)``; the inputs when nothing changed.
    """
    # only blobs whose freed pixels could be a surface of their own are worth a recovery: a
    # blob is at least min_size pixels, and more than half of them freed (_mostly_new)
    min_size = smallest_region(config, sensor, cloud)
    unturned = []
    freed, released, pixels = off_model_blocks(labels, blocks, fits, tile_fits, tile=tile, spread=spread,
                                               depth_step=sensor.depth_step, xyz=np.ascontiguousarray(cloud.xyz.reshape(-1, 3)),
                                               max_angle_deg=config.merge_angle_deg, min_pixels=min_size // 2,
                                               unturned=unturned)
    if released is not None:
        labels, fits, stats = _recover_freed(cloud, labels, fits, stats, freed, released, pixels, min_size=min_size,
                                             fitter=fitter, config=config, sensor=sensor, ranges=ranges, sigma=sigma,
                                             inlier_factor=inlier_factor)
    if unturned:
        from .fullres import recovered_region_floor

        labels, fits, stats = faces_along_rays(
            cloud, labels, fits, stats, *unturned[0], tile=tile, sigma=sigma, k_sigma=config.k_sigma,
            inlier_factor=inlier_factor, max_angle_deg=config.merge_angle_deg,
            floor=recovered_region_floor(config, min_size, sensor.noise.correlation_px),
            rms_factor=config.merge_rms_factor if config.merge else None, apart=config.merge_disjoint)
    return labels, fits, stats


def _recover_freed(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, freed: np.ndarray,
                   released: np.ndarray, pixels: np.ndarray, *, min_size: int, fitter, config, sensor,
                   ranges: np.ndarray, sigma: np.ndarray, inlier_factor: float):
    # recover_off_model's recovery of the pixels off_model_blocks freed (``freed`` the labels
    # without them, ``released`` their labels before, ``pixels`` their flat indices)
    first = fresh_label(freed, fits)
    found = leftover_blob_labels(freed, cloud.valid, min_size=min_size, first_label=first)
    if found is None:
        return labels, fits, stats
    candidates, boxes, _ = found
    held = unique_ints(candidates.reshape(-1)[pixels])
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


#: Rings a face :func:`faces_along_rays` found may grow by, and give back (:func:`rangeseg_o3d.kernels.grow_face`):
#: a strip 140 rows long from a seed of three 6-pixel tiles in its middle (compiled, a ring looks
#: only at the neighbours of the pixels the last one moved: kernels.grow_along_rays). (32 rings left a 120-row strip half grown when its plane was refitted, which
#: then tilted 16 degrees towards the wall beside it: tests/test_off_model_faces.py, seed 1.)
GROWTH_RINGS = 64
#: Times a face's plane is refitted to the pixels it grew into (each followed by a growth; a
#: second refit on a 10-px strip keeps too few pixels apart from the crease to set its tilt).
REFITS = 1


def faces_along_rays(cloud, labels: np.ndarray, fits: dict, stats: PixelStats, tiles: np.ndarray,
                     owners: np.ndarray, *, tile: int, sigma: np.ndarray, k_sigma: float, inlier_factor: float,
                     max_angle_deg: float, floor: int, rms_factor: float | None = None, apart: bool = False):
    """Faces in groups of tiles off their model that :func:`off_model_blocks` did not free,
    made regions of their own. Returns ``(labels, fits, stats)``; the inputs when none is.

    A wall cut by the image's edge beside the wall it meets is a strip a few pixels wide.
    Its pixels lie off the model that took them as a group (``tiles[j]``, ``owners[j]``:
    :func:`rangeseg_o3d.kernels.off_model_tiles`), but the group is fewer pixels than a blob,
    and under a range noise as large as the strip is wide its least-squares plane lies along
    the rays, its tilt undetermined. The range errors move only the inverse ranges along the
    rays: each touching group's plane fitted along them (:func:`rangeseg_o3d.ray_planes.robust_ray_plane`)
    is a face when it keeps more than half of the group (and at least ``floor`` pixels)
    within TRIM_SIGMAS of that noise, scattering within the chi-square bound of their
    count, and is turned from the owner's model and from every plane region it touches by
    more than ``max_angle_deg`` and more than ``CHI_SQUARE_SIGMAS`` times the noise of its tilt
    (:func:`_tilt_bound`, :func:`_turned_from`; a plane region that explains it along the rays within their
    noise takes none: it is a piece of that region): how many pixels settle a face is the
    noise's to say, not a count of tiles. A face takes those pixels, grows into the pixels on
    its side of the crease with each plane region beside it (:func:`rangeseg_o3d.kernels.grow_face`), is
    refitted to what it holds away from that crease (:func:`_refit_apart`) and grows again;
    a face a touching region (or another face) then explains along the rays joins it, and
    so does one a touching plane region explains by the merge rule (``rms_factor``, the
    config's merge_rms_factor; None: not asked; :func:`_merged_into`); with ``apart`` (the config's
    merge_disjoint), so does one a plane region it does not touch explains by that rule."""
    from .fitting.robust import CHI_SQUARE_SIGMAS
    from .kernels import grow_face, tile_groups, tile_members
    from .kernels.linalg import noise_rms_bound
    from .fitting.primitives import Plane
    from .fitting.region_fitter import extended_table
    from .fullres import stats_with_moved
    from .ray_planes import ROBUST_CHUNKS, ray_plane, ray_terms, robust_ray_plane
    from .refinement.context import touching

    h, w = labels.shape
    group = tile_groups(tiles, -(-w // tile))
    pixels, entries = tile_members(np.ascontiguousarray(labels, dtype=np.int32), int(tile), tiles, owners)
    if not pixels.size:
        return labels, fits, stats
    xyz = np.ascontiguousarray(cloud.xyz.reshape(-1, 3), dtype=np.float64)
    noise = np.ascontiguousarray(sigma, dtype=np.float64).ravel()
    of_pixel = group[entries]
    planes = {k: m for k, m in fits.items() if isinstance(m, Plane)}
    order = np.argsort(of_pixel, kind="stable")
    bounds = np.searchsorted(of_pixel[order], np.arange(int(group.max()) + 2))
    models = [fits.get(int(np.bincount(owners[entries[order[b0:b1]]]).argmax())) if b1 > b0 else None
              for b0, b1 in zip(bounds[:-1].tolist(), bounds[1:].tolist())]
    ruled_out = _ruled_out(xyz, noise, pixels[order], bounds, w, floor, models, max_angle_deg)
    faces = []
    for g in range(bounds.size - 1):
        members = order[bounds[g]:bounds[g + 1]]
        if ruled_out[g] or members.size < max(floor, 3 * ROBUST_CHUNKS):
            continue
        idx = pixels[members]
        model = models[g]
        points = xyz[idx]
        rays, inverse, weight = ray_terms(points, noise[idx])
        rows, cols = np.divmod(idx, w)
        found = robust_ray_plane(rays, inverse, weight, rows, cols)
        if model is None or found is None:
            continue
        a, keep, mean_square = found
        n = int(np.count_nonzero(keep))
        if 2 * n <= idx.size or n < floor:
            continue
        if mean_square > noise_rms_bound.py_func(1.0, float(n), CHI_SQUARE_SIGMAS) ** 2:
            continue
        # turned from the model it lies off, and from every plane region it touches (one it is
        # not turned from, within the noise of its tilt, is the surface it is a piece of)
        tilt = _tilt_bound(a, rays, weight, max_angle_deg, keep)
        centre = points[keep].mean(axis=0)
        if tilt is None or not _turned_from(tilt, centre, model):
            continue
        around = [k for k in sorted(touching(labels, unique_ints(idx[keep]), 1)) if k in planes]
        if not all(_turned_from(tilt, centre, planes[k]) for k in around):
            continue
        # a piece of a plane region the scan has (whose tile model its pixels left): not a face
        # (plane_beside's test on the plane regions it touches, in one compiled pass)
        near = [k for k in around if k != 0]
        counts, means, _ = _plane_scores(rays, inverse, weight, keep, [planes[k] for k in near], None)
        if _explaining(near, counts, means, n):
            continue
        plane = ray_plane(a, points[keep])
        if plane is not None:
            faces.append((idx[keep], plane, model))
    if not faces:
        return labels, fits, stats
    first = fresh_label(labels, fits)
    out = np.array(labels, dtype=np.int32, order="C", copy=True)
    flat = out.ravel()
    fits_in, fits = fits, dict(fits)
    moved = [[kept] for kept, _, _ in faces]  # the pixels each face took or gave
    for j, (kept, plane, _) in enumerate(faces):
        flat[kept] = first + j
        fits[first + j] = plane
    rows = _plane_rows(fits, first + len(faces))
    units = _unit_rows(rows)  # (each row alone: a refit sets its face's rows of both)
    # every pixel a face may hold, increasing: those it was given and those its growth moved
    # (another face's growth only takes from it), so no pass over the frame finds its pixels
    held = [unique_ints(kept).astype(np.int64, copy=False) for kept, _, _ in faces]
    cos_angle = float(np.cos(np.radians(max_angle_deg)))

    def grow(j):  # (one face at a time: each in its own box; one compiled call)
        step, held[j] = grow_face(xyz, flat, h, w, rows, units, noise, first + j, held[j], float(k_sigma), cos_angle,
                                  GROWTH_RINGS)
        moved[j].append(step)

    for _ in range(REFITS):
        for j in range(len(faces)):
            grow(j)
        for j, (_, _, source) in enumerate(faces):
            plane = _refit_apart(xyz, noise, flat, held[j], first + j, fits[first + j], source, k_sigma, floor)
            if plane is not None:
                fits[first + j] = plane
                rows[first + j] = _plane_rows({first + j: plane}, first + j + 1)[first + j]
                units[first + j] = _unit_rows(rows[first + j:first + j + 1])[0]
    for j in range(len(faces)):
        grow(j)
    fate = _fates(xyz, noise, out, fits, first, [pixels[flat[pixels] == first + j] for j, pixels in enumerate(held)],
                  rms_factor, apart=apart)
    if all(fate[j] is None for j in range(len(faces))):
        return labels, fits_in, stats
    # a face that another explains joins it; one that is no face of its own (a touching region
    # explains it: a piece of that region, seen near grazing; or more than one surface) is
    # undone, every pixel it took or gave back as it was (but those a face kept since)
    alive = np.zeros(first + len(faces), bool)
    alive[[first + j for j in range(len(faces)) if fate[j] == first + j]] = True
    for j in range(len(faces)):
        if fate[j] == first + j:
            continue
        del fits[first + j]
        if fate[j] is not None:  # (another face, or a region the merge rule joins it to)
            flat[flat == first + j] = fate[j]
            continue
        touched = unique_ints(np.concatenate(moved[j]))
        touched = touched[~alive[np.minimum(flat[touched], alive.size - 1)] | (flat[touched] >= alive.size)]
        flat[touched] = labels.ravel()[touched]
    table = extended_table(model_table(fits, first), [fits.get(first + j) or faces[j][1] for j in range(len(faces))])
    changed = np.flatnonzero(flat != labels.ravel())
    return out, fits, stats_with_moved(stats, xyz, noise, labels, out, table, changed, inlier_factor)


def _ruled_out(xyz: np.ndarray, noise: np.ndarray, idx: np.ndarray, bounds: np.ndarray, width: int, floor: int,
               models: list, max_angle_deg: float) -> np.ndarray:
    """Per group of :func:`faces_along_rays` (its flat pixels ``idx[bounds[g]:bounds[g + 1]]``,
    the model most of them were taken by ``models[g]``): True when it certainly holds no face,
    its plane along the rays failing the gates ``faces_along_rays`` puts first, the turn from
    a plane owner's included (:func:`rangeseg_o3d.kernels.ray_groups_ruled_out`: compiled, all
    groups in one pass; only a decision clear of its threshold by ``SCREEN_TOLERANCE`` rules a
    group out, so those left give numpy's answers, and the faces are the same)."""
    from .fitting.primitives import Plane
    from .fitting.robust import CHI_SQUARE_SIGMAS
    from .kernels import ray_groups_ruled_out
    from .ray_planes import ROBUST_CHUNKS, TRIM_PASSES
    from .refinement.context import TRIM_SIGMAS

    facing = np.full((len(models), 3), np.nan)
    for g, model in enumerate(models):
        if isinstance(model, Plane):
            facing[g] = np.asarray(model.normal, dtype=np.float64) / float(np.linalg.norm(model.normal))
    out = ray_groups_ruled_out(xyz, noise, np.ascontiguousarray(idx, dtype=np.int64),
                               np.ascontiguousarray(bounds, dtype=np.int64), int(width), int(floor), facing,
                               float(np.radians(max_angle_deg)), float(CHI_SQUARE_SIGMAS), float(TRIM_SIGMAS),
                               int(ROBUST_CHUNKS), int(TRIM_PASSES), SCREEN_TOLERANCE)
    return out | np.array([model is None for model in models], dtype=bool)


def _tilt_bound(a: np.ndarray, rays: np.ndarray, weight: np.ndarray, max_angle_deg: float,
                keep: np.ndarray | None = None):
    """``(unit normal, angle)``: the normal of the plane ``a . p = 1`` fitted along ``rays``
    (inverse-range weights ``weight``, :func:`rangeseg_o3d.ray_planes.ray_terms`; only the rows
    ``keep`` marks, all when None) and the angle it must be turned by from a model to stand
    apart from it (:func:`_turned_from`): the largest of ``max_angle_deg`` and
    ``CHI_SQUARE_SIGMAS`` times the noise of its tilt, the largest standard deviation of its
    unit normal across itself, from the fit's covariance ``(sum w u u^T)^-1`` (rays that span
    little of the sky leave it large). None when ``a`` is no plane or that covariance is
    singular (turned from nothing). The same for every model it is tested against: computed
    once per plane.

    Float64 ``(N, 3)`` rays go through one compiled pass (:func:`rangeseg_o3d.kernels.tilt_noise`:
    its own rounding, within ~1e-12 relative of numpy's form :func:`_tilt_bound_numpy` on
    well-conditioned sums; the bound only gates a face); anything else through numpy."""
    from .fitting.robust import CHI_SQUARE_SIGMAS
    from .kernels import tilt_noise

    rays, weight, a = np.asarray(rays), np.asarray(weight), np.asarray(a)
    if not (rays.dtype == weight.dtype == a.dtype == np.float64 and rays.ndim == 2 and rays.shape[1] == 3
            and weight.shape == (rays.shape[0],) and a.shape == (3,)):
        return _tilt_bound_numpy(a, rays if keep is None else rays[keep], weight if keep is None else weight[keep],
                                 max_angle_deg)
    mask = np.ones(weight.size, bool) if keep is None else np.ascontiguousarray(keep, dtype=bool)
    if mask.shape != weight.shape:
        raise ValueError(f"keep: expected a mask of {weight.size} rows, got shape {mask.shape}")
    noise = tilt_noise(np.ascontiguousarray(rays), np.ascontiguousarray(weight), mask, a)
    if noise < 0.0:
        return None
    return a / float(np.linalg.norm(a)), max(np.radians(max_angle_deg), CHI_SQUARE_SIGMAS * noise)


def _tilt_bound_numpy(a: np.ndarray, rays: np.ndarray, weight: np.ndarray, max_angle_deg: float):
    """:func:`_tilt_bound` in numpy (BLAS and LAPACK; the rows given are the fit's): the form its
    compiled pass replaced, and the one for other dtypes and shapes."""
    from .fitting.robust import CHI_SQUARE_SIGMAS

    size = float(np.linalg.norm(a))
    if not np.isfinite(size) or size <= 0.0:
        return None
    normal = a / size
    outer = (weight[:, None] * rays).T @ rays
    try:
        covariance = np.linalg.inv(outer)
    except np.linalg.LinAlgError:
        return None
    across = np.eye(3) - np.outer(normal, normal)
    tilt_noise = np.sqrt(max(float(np.linalg.eigvalsh(across @ covariance @ across)[-1]), 0.0)) / size
    return normal, max(np.radians(max_angle_deg), CHI_SQUARE_SIGMAS * tilt_noise)


def _turned_from(tilt: tuple, centre: np.ndarray, model) -> bool:
    """Whether the plane of ``tilt`` (:func:`_tilt_bound`) is turned from ``model``'s normal at
    ``centre`` by more than its angle (False where the model has no normal there)."""
    normal, bound = tilt
    facing = np.asarray(model.normals(centre[None]), dtype=np.float64)[0]
    norm = float(np.linalg.norm(facing))
    if norm <= 0.0:
        return False
    return bool(np.arccos(min(abs(float(normal @ facing)) / norm, 1.0)) > bound)


def _plane_rows(fits: dict, n: int) -> np.ndarray:
    """Per label below ``n``, its plane in ``fits`` as ``a = normal / d`` (the plane meets ray
    ``u`` at inverse range ``a . u``); NaN rows for no plane (or one through the sensor)."""
    from .fitting.primitives import Plane

    planes = np.full((n, 3), np.nan)
    for k, model in fits.items():
        if isinstance(model, Plane) and 0 < k < n and model.d > 0:
            planes[k] = np.asarray(model.normal) / model.d
    return planes


def _unit_rows(planes: np.ndarray) -> np.ndarray:
    """The rows of ``planes`` (:func:`_plane_rows`) scaled to unit length, each row on its own
    (NaN rows stay NaN)."""
    return planes / np.linalg.norm(np.nan_to_num(planes), axis=1, keepdims=True).clip(1e-300)


def _refit_apart(xyz: np.ndarray, noise: np.ndarray, flat: np.ndarray, held: np.ndarray, label: int, face, source,
                 k_sigma: float, floor: int):
    """The plane of a face (label ``label`` of the flat labels ``flat``, its pixels among
    ``held``, flat, increasing; plane ``face``) fitted along their rays again,
    to those of its pixels whose rays meet it and the plane ``source`` it was found beside
    more than ``k_sigma`` range-noise sigmas apart (all of them when ``source`` is no plane or
    fewer than ``floor`` are): near their crease a pixel lies within the noise of both, and
    which one took it says nothing of the face's tilt but drags it towards the other.
    The choice depends on the rays alone, not on the ranges the noise moved. None when no
    plane comes out. The pixels and their sums come from one compiled call
    (:func:`rangeseg_o3d.kernels.refit_terms`: the same sums as ``ray_moments`` of
    ``ray_terms``, without their dozen numpy temporaries over the face's pixels); the solve
    and the plane are numpy's."""
    from .fitting.primitives import Plane
    from .kernels import refit_terms
    from .ray_planes import ray_plane, ray_solutions

    own = np.asarray(face.normal, dtype=np.float64) / face.d
    if isinstance(source, Plane) and source.d > 0:
        other = np.asarray(source.normal, dtype=np.float64) / source.d
    else:
        other = np.full(3, np.nan)
    outer, first, pixels = refit_terms(xyz, noise, flat, np.ascontiguousarray(held, dtype=np.int64), int(label),
                                       own, other, float(k_sigma), int(floor))
    if len(pixels) == 0 or not np.trace(outer) > 0:  # no pixel held (the solve would be singular)
        return None
    a = ray_solutions(outer[None], first[None])
    return ray_plane(a[0], xyz[pixels])


def _plane_scores(rays: np.ndarray, inverse: np.ndarray, weight: np.ndarray, keep, models: list, own) -> tuple:
    """:func:`rangeseg_o3d.kernels.plane_scores` of the pixels ``keep`` marks (all when None;
    their :func:`rangeseg_o3d.ray_planes.ray_terms`) against the planes ``models`` and then
    ``own`` (a last row; None: none): ``(counts, means, owns)``, per plane the pixels it keeps
    within TRIM_SIGMAS of their range noise along the rays, the mean of their squares and the
    mean over them of ``own``'s squares (:func:`rangeseg_o3d.plane_faces.planes_keeping`'s
    test on every plane in one pass)."""
    from .kernels import plane_scores
    from .refinement.context import TRIM_SIGMAS

    table, own_row = _score_rows(models, own)
    mask = np.ones(inverse.size, bool) if keep is None else np.ascontiguousarray(keep, dtype=bool)
    return plane_scores(np.ascontiguousarray(rays, dtype=np.float64), np.ascontiguousarray(inverse, dtype=np.float64),
                        np.ascontiguousarray(weight, dtype=np.float64), mask, table, own_row, float(TRIM_SIGMAS))


def _score_rows(models: list, own) -> tuple:
    """The rows ``a = normal / d`` :func:`_plane_scores` tests: ``(table, own_row)``, the
    planes ``models`` then ``own`` (a NaN row and no last row when None)."""
    own_row = np.full(3, np.nan) if own is None else np.asarray(own.normal, dtype=np.float64) / own.d
    rows = [np.asarray(model.normal, dtype=np.float64) / model.d for model in models]
    if own is not None:
        rows.append(own_row)
    return np.array(rows, dtype=np.float64).reshape(-1, 3), own_row


def _explaining(labels: list, counts: np.ndarray, means: np.ndarray, size: int) -> int:
    """Of the planes ``labels`` (their :func:`_plane_scores` over ``size`` pixels), the one
    :func:`rangeseg_o3d.plane_faces.plane_beside` picks (one return a pixel): it keeps
    ``strips.EXPLAINED_SHARE`` of the pixels, their mean square within the chi-square bound of
    their count, the least such mean square; 0 when none does."""
    from .fitting.robust import CHI_SQUARE_SIGMAS
    from .kernels.linalg import noise_rms_bound
    from .strips import EXPLAINED_SHARE

    best, label = np.inf, 0
    for other, n, mean_square in zip(labels, counts.tolist(), means.tolist()):
        if (n >= EXPLAINED_SHARE * size and mean_square <= noise_rms_bound.py_func(1.0, float(n), CHI_SQUARE_SIGMAS) ** 2
                and mean_square < best):
            best, label = mean_square, other
    return label


def _merged(labels: list, counts: np.ndarray, means: np.ndarray, owns: np.ndarray, size: int,
            rms_factor: float) -> int:
    """Of the planes ``labels`` (their :func:`_plane_scores` over ``size`` pixels, ``owns`` the
    face's own plane's), the one :func:`_merged_into` picks; 0 when none."""
    from .strips import EXPLAINED_SHARE

    best, label = np.inf, 0
    for other, n, mean_square, mine in zip(labels, counts.tolist(), means.tolist(), owns.tolist()):
        if (n >= EXPLAINED_SHARE * size and mean_square <= rms_factor * rms_factor * mine
                and mean_square < best):
            best, label = mean_square, other
    return label


def _one_face(rays: np.ndarray, inverse: np.ndarray, weight: np.ndarray, plane) -> bool:
    """Whether ``plane`` explains the pixels of a face (their :func:`rangeseg_o3d.ray_planes.ray_terms`)
    as one surface: ``strips.EXPLAINED_SHARE`` of them within TRIM_SIGMAS of their range noise
    along the rays, with a mean square of those within the chi-square bound of their count
    (as :func:`rangeseg_o3d.strips.recover_strips` holds a face found along the rays).
    (:func:`_plane_scores`' sums: compiled, added pixel after pixel.)"""
    counts, means, _ = _plane_scores(rays, inverse, weight, None, [], plane)
    return _stands(int(counts[0]), float(means[0]), inverse.size)


def _stands(n: int, mean_square: float, size: int) -> bool:
    """:func:`_one_face`'s test on a plane's :func:`_plane_scores` over ``size`` pixels."""
    from .fitting.robust import CHI_SQUARE_SIGMAS
    from .kernels.linalg import noise_rms_bound
    from .strips import EXPLAINED_SHARE

    return bool(n >= EXPLAINED_SHARE * size and n > 0
                and mean_square <= noise_rms_bound.py_func(1.0, float(n), CHI_SQUARE_SIGMAS) ** 2)


def _fates(xyz: np.ndarray, noise: np.ndarray, out: np.ndarray, fits: dict, first: int, pixels: list,
           rms_factor: float | None = None, apart: bool = False) -> list:
    """Per face ``first + j`` of ``out`` (grown, its flat pixels ``pixels[j]``, increasing;
    planes in ``fits``): the label it ends as. ``first + j`` when it stands as a face,
    ``first + f`` when face ``f`` explains it along the rays
    (:func:`rangeseg_o3d.plane_faces.plane_beside`), a region's label below ``first`` when it
    would stand but that region's plane explains it by the merge rule (:func:`_merged_into`,
    ``rms_factor`` the config's merge_rms_factor; None: no such join), None when it is
    undone: a region the scan had explains it, or its plane does not explain it as one
    surface (:func:`_one_face`). With ``apart`` the merge rule also weighs the plane regions
    the scan had that the face does not touch: a strip of a far wall at the image's edge,
    cut from the wall's region by a column before it, is a piece of that wall (kinect seed
    1043 scan 4: 204 px at 5.2 m on the wall's plane within 2 mm on the mean, left a face
    of its own). Each face's three tests take one compiled pass over its pixels against
    every plane it weighs and its own (:func:`rangeseg_o3d.kernels.pixel_plane_scores`:
    :func:`_plane_scores` with the ray terms made in the pass)."""
    from .fitting.primitives import Plane
    from .kernels import pixel_plane_scores
    from .refinement.context import TRIM_SIGMAS, touching

    planes = {k: m for k, m in fits.items() if isinstance(m, Plane)}  # (the other faces too)
    apart_planes = sorted(k for k in planes if k < first)
    xyz = np.ascontiguousarray(xyz, dtype=np.float64).reshape(-1, 3)  # (no copy from faces_along_rays)
    noise = np.ascontiguousarray(noise, dtype=np.float64).reshape(-1)
    fate = []
    count = len(pixels)
    for j in range(count):
        mine = pixels[j]
        if not mine.size:
            fate.append(None)
            continue
        near = [k for k in sorted(touching(out, mine, 1) - {0, first + j}) if k in planes]
        # (the regions apart are weighed for the merge rule only: one of them explaining the
        # face along the rays does not undo it, as a touching one's piece would be)
        weighed = near + ([k for k in apart_planes if k not in near] if apart and rms_factor is not None else [])
        table, own_row = _score_rows([planes[k] for k in weighed], fits[first + j])
        counts, means, owns = pixel_plane_scores(xyz, noise, np.ascontiguousarray(mine, dtype=np.int64), table,
                                                 own_row, float(TRIM_SIGMAS))
        beside = _explaining(near, counts[:len(near)], means[:len(near)], mine.size)
        if beside:
            fate.append(beside if first <= beside < first + count else None)
        elif not _stands(int(counts[-1]), float(means[-1]), mine.size):
            fate.append(None)
        else:
            below = [i for i, k in enumerate(weighed) if k < first]
            joined = 0 if rms_factor is None else _merged([weighed[i] for i in below], counts[below], means[below],
                                                          owns[below], mine.size, rms_factor)
            fate.append(joined or first + j)
    # a face that joins one which does not stand is undone too
    return [f if f is None or f < first or fate[f - first] == f else None for f in fate]


def _merged_into(labels: np.ndarray, k: int, idx: np.ndarray, rays: np.ndarray, inverse: np.ndarray,
                 weight: np.ndarray, planes: dict, own, rms_factor: float) -> int:
    """The plane region (``planes``: label -> Plane, the regions the scan had) touching face
    ``k`` of ``labels`` (its flat pixels ``idx``, their :func:`~rangeseg_o3d.ray_planes.ray_terms`)
    whose plane explains the face as the merge explains a union: it keeps
    ``strips.EXPLAINED_SHARE`` of its pixels within TRIM_SIGMAS of their range noise along the
    rays, with an rms of those within ``rms_factor`` of the face's own plane's (``own``) on the
    same pixels; the one with the least rms, 0 when none does (:func:`_plane_scores`' sums).

    A face grown along the rays on a wall beside the crease it was sought at can come out
    parallel to that wall's region; the wall's plane, fitted to thousands of pixels, may then
    miss the chi-square bound of :func:`rangeseg_o3d.plane_faces.plane_beside` by a hair
    (seed 0 kinect scan 0: 447 of 448 pixels kept, mean square 1.2705 against 1.2676) while
    it explains the face as well as the face's own plane does: one surface, not two."""
    from .refinement.context import touching

    near = [other for other in sorted(touching(labels, idx, 1) - {0, k}) if other in planes]
    counts, means, owns = _plane_scores(rays, inverse, weight, None, [planes[other] for other in near], own)
    return _merged(near, counts[:-1], means[:-1], owns[:-1], idx.size, rms_factor)
