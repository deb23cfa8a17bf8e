"""Tile grid -> sensor grid: full-resolution labels from the tile models, with the
regions' distance statistics in the same pass, and the leftover blobs of the result.

The per-pixel work is what each pixel needs: the candidate models of a tile (the
regions of the tile and of the 8 around it) are listed once per tile, so a pixel inside
a region (one candidate) costs one distance, which serves both its label test and its
region's statistics; only pixels of tiles where regions meet test several models.
"""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .kinds import PLANE
from .creases import _centroids, _crease_pair, _ray_meets_b
from .inline import _incidence, _nearest_neighbour_model, _neighbour, _signed_distance

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("inline.py", "kinds.py", "creases.py")

__all__ = ["label_pixels", "off_model_tiles", "tile_groups", "tile_members", "free_blocks", "leftover_blobs", "grow_free", "label_boxes", "label_sample", "labels_touch"]


@njit(cache=True, nogil=True)
def _tile_candidates(tile_labels, kinds):
    # Per tile: the models its pixels are tested against, in the order of the per-pixel
    # rule (own region first, then the 8 neighbours row by row), each label once.
    # count -1: the tile's region has no model and keeps the tile's pixels.
    th, tw = tile_labels.shape
    n = kinds.shape[0]
    table = np.zeros((th, tw, 9), np.int32)
    count = np.zeros((th, tw), np.int32)
    for tr in range(th):
        for tc in range(tw):
            own = tile_labels[tr, tc]
            if 0 < own < n and kinds[own] == 0:
                count[tr, tc] = -1
                continue
            m = 0
            if 0 < own < n:
                table[tr, tc, 0] = own
                m = 1
            for dr in range(-1, 2):
                rr = tr + dr
                if rr < 0 or rr >= th:
                    continue
                for dc in range(-1, 2):
                    cc = tc + dc
                    if cc < 0 or cc >= tw or (dr == 0 and dc == 0):
                        continue
                    k = tile_labels[rr, cc]
                    if k <= 0 or k >= n or kinds[k] == 0:
                        continue
                    seen = False
                    for j in range(m):
                        if table[tr, tc, j] == k:
                            seen = True
                    if not seen:
                        table[tr, tc, m] = k
                        m += 1
            count[tr, tc] = m
    return table, count


@njit(cache=True, nogil=True)
def label_pixels(xyz, height, width, tile_labels, tile, kinds, params, rms, sigma, k_sigma,
                 inlier_factor, tile_xyz, max_cos, least_cos):
    """Full-resolution labels from labels of ``tile x tile`` means and the regions' models.

    Each valid pixel joins, among the regions of its own tile and the 8 tiles around it
    whose models are within ``k_sigma`` of it in units of ``max(sigma, rms)``, the one it is
    fewest sigmas of its distance's noise off (``sigma`` times the incidence cosine, floored
    at a curved model's ``rms``, and at every model's once a curved one explains the pixel);
    its own tile's region wins ties, then the first neighbour in row order. Pixels of a
    tile whose region has no model (``kinds == 0``) keep that region. ``xyz`` and
    ``sigma`` are flat (H*W).

    Returns ``(labels (H, W) int32, inliers, squares, counts, blocks)``: per label, the
    pixels within ``inlier_factor * sigma`` of its model, the sum of their squared distances
    and the number of pixels with a finite distance (pixels taken in raster order, as
    :func:`rangeseg_o3d.kernels.distance_stats` counts them with a zero rms); ``blocks`` the
    sums per tile and label that tile's pixels joined, in the same pass (see
    :func:`_block_sums_layout`): ``(first, owners, taken, sums, whole)``.

    With ``tile_xyz`` (the tile means, flat (th*tw, 3); empty: off), a pixel two planes
    both explain within ``k_sigma`` goes to the face its ray meets there when the planes
    form a crease, whatever the noise says (:func:`_face_by_ray`; ``max_cos`` and
    ``least_cos`` as :func:`rangeseg_o3d.kernels.crease_moves` takes them).
    """
    table, count = _tile_candidates(tile_labels, kinds)
    normals, offsets, centroids = _crease_geometry(tile_labels, kinds, params, tile_xyz)
    creased, pairs = _creased_tiles(table, count, kinds, normals, offsets, centroids, max_cos)
    n = kinds.shape[0]
    th, tw = tile_labels.shape
    out = np.zeros((height, width), np.int32)
    inliers = np.zeros(n, np.int64)
    squares = np.zeros(n)
    counts = np.zeros(n, np.int64)
    first, owners = _block_sums_layout(table, count)
    taken_in = np.zeros(owners.size, np.int64)
    sums = np.zeros((owners.size, _BLOCK_SUMS))
    # per candidate of the pixel at hand: whether it explains it, its signed distance, the
    # noise of that distance
    explains, near_signed, near_noise = np.zeros(9, np.bool_), np.zeros(9), np.zeros(9)
    # Row by row (the statistics sum in raster order), tile by tile along the row: a pixel
    # of a tile inside a region tests one model.
    for r in range(height):
        tr = min(r // tile, th - 1)
        for tc in range(tw):
            c0, c1 = tc * tile, min(tc * tile + tile, width)
            m = count[tr, tc]
            if m == 0:
                continue
            own = tile_labels[tr, tc]
            if m < 0:  # a region without a model keeps its tile
                for c in range(c0, c1):
                    if np.isfinite(xyz[r * width + c, 2]):
                        out[r, c] = own
                continue
            slot = first[tr * tw + tc]
            if m == 1:
                k = table[tr, tc, 0]
                kind, prm, floor = kinds[k], params[k], rms[k]
                ties = k == own  # the own region wins ties
                # the region's statistics in registers along the tile's row (the same
                # additions in the same order as _take's)
                taken, total, near = counts[k], squares[k], inliers[k]
                before = taken
                offset, sx, sy, sz, noise2 = 0.0, 0.0, 0.0, 0.0, 0.0
                for c in range(c0, c1):
                    i = r * width + c
                    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
                    if not np.isfinite(z):
                        continue
                    noise = sigma[i]
                    signed = _signed_distance(kind, prm, x, y, z)
                    dist = abs(signed)
                    score = dist / max(noise, floor)
                    if score < k_sigma or (ties and score <= k_sigma):
                        out[r, c] = k
                        taken += 1
                        total += dist * dist
                        if dist <= inlier_factor * max(noise, 0.0):
                            near += 1
                        offset += signed
                        sx += x
                        sy += y
                        sz += z
                        noise2 += noise * noise
                counts[k], squares[k], inliers[k] = taken, total, near
                _add_block_row(taken_in, sums, slot, taken - before, offset, sx, sy, sz, noise2)
                continue
            own_first = table[tr, tc, 0] == own
            by_rays = creased[tr, tc]
            for c in range(c0, c1):
                i = r * width + c
                x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
                if not np.isfinite(z):
                    continue
                noise = sigma[i]
                planes = 0  # bit j: candidate j is a plane that explains the pixel
                curved = False  # a curved candidate explains it
                for j in range(m):
                    k = table[tr, tc, j]
                    signed = _signed_distance(kinds[k], params[k], x, y, z)  # kept for the block sums
                    dist = abs(signed)  # _distance's value
                    # explained within k_sigma (the own region at the bound too)...
                    limit = k_sigma * max(noise, rms[k])
                    ok = dist < limit
                    if not ok and j == 0 and own_first and dist <= limit:
                        ok = True
                    explains[j] = ok
                    if not ok:
                        continue
                    near_signed[j] = signed
                    near_noise[j] = noise * _incidence(kinds[k], params[k], x, y, z)
                    if kinds[k] == PLANE:
                        planes |= 1 << j
                    else:
                        curved = True
                best, best_j, best_score, best_dist, best_signed = 0, 0, np.inf, 0.0, 0.0
                for j in range(m):
                    if not explains[j]:
                        continue
                    k = table[tr, tc, j]
                    dist = abs(near_signed[j])
                    # ...and of those, the one it is fewest noise sigmas off, each in the noise
                    # of its own distances (range noise x incidence cosine: a pipe's end cap
                    # faces the sensor, the pipe's flanks graze it; a box face seen edge-on
                    # takes no pixel of the face beside it that the noise along the rays
                    # could not have moved onto it). Among planes alone that noise is the
                    # whole of it: a grazing face's region whose tiles took a neighbour's means
                    # has an rms far over its pixels' noise, and as a floor it let the face
                    # take the band of the face beside it (stereo study seed 1292 scan 3). A
                    # curved model's rms is its misfit to its tiles, and beside a curved
                    # candidate every model keeps that floor.
                    floor = rms[k] if curved or kinds[k] != PLANE else 0.0
                    score = dist / max(near_noise[j], floor, 1e-300)
                    # neighbours must beat what is found so far
                    if score < best_score or (j == 0 and own_first and score <= best_score):
                        best, best_j, best_score, best_dist, best_signed = k, j, score, dist, near_signed[j]
                if by_rays and best != 0 and kinds[best] == PLANE and planes != 1 << best_j:
                    j = _face_by_ray(table, pairs, tr, tc, m, best_j, planes, x, y, z, normals, offsets, least_cos)
                    if j != best_j:
                        best, best_j = table[tr, tc, j], j
                        best_signed = _signed_distance(PLANE, params[best], x, y, z)
                        best_dist = abs(best_signed)
                if best != 0:
                    _take(out, inliers, squares, counts, r, c, best, best_dist, noise, inlier_factor)
                    _add_block_row(taken_in, sums, slot + best_j, 1, best_signed, x, y, z, noise * noise)
    whole = _whole_tiles(taken_in, first, count, th, tw, tile, height, width)
    return out, inliers, squares, counts, (first, owners, taken_in, sums, whole)


@njit(cache=True, nogil=True)
def _crease_geometry(tile_labels, kinds, params, tile_xyz):
    # The planes with the sensor's side positive (normals, offsets) and each label's
    # centroid from its tiles' finite means, as crease_moves' _crease_pair reads them;
    # empty with no tile means
    n = kinds.shape[0]
    if tile_xyz.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))
    normals, offsets, sums = np.zeros((n, 3)), np.zeros(n), np.zeros((n, 4))
    for k in range(n):
        if kinds[k] == PLANE:
            sign = -1.0 if params[k, 3] > 0 else 1.0
            normals[k, 0], normals[k, 1], normals[k, 2] = sign * params[k, 0], sign * params[k, 1], sign * params[k, 2]
            offsets[k] = sign * params[k, 3]
    th, tw = tile_labels.shape
    for t in range(th * tw):
        k = tile_labels[t // tw, t % tw]
        if 0 < k < n and kinds[k] == PLANE and np.isfinite(tile_xyz[t, 2]):
            sums[k, 0] += tile_xyz[t, 0]
            sums[k, 1] += tile_xyz[t, 1]
            sums[k, 2] += tile_xyz[t, 2]
            sums[k, 3] += 1.0
    centroids = _centroids(sums)
    return normals, offsets, centroids


@njit(cache=True, nogil=True)
def _creased_tiles(table, count, kinds, normals, offsets, centroids, max_cos):
    # Per tile: whether two of its candidate planes meet at a crease, and per pair of its
    # candidates (j, q) crease_moves' _crease_pair (1 concave, -1 convex, 0 none); all
    # none without the crease geometry
    th, tw = count.shape
    creased = np.zeros((th, tw), np.bool_)
    pairs = np.zeros((th, tw, 9, 9) if normals.shape[0] else (0, 0, 9, 9), np.int8)
    if normals.shape[0] == 0:
        return creased, pairs
    for tr in range(th):
        for tc in range(tw):
            m = count[tr, tc]
            for j in range(m):
                a = table[tr, tc, j]
                for q in range(j + 1, m):
                    b = table[tr, tc, q]
                    if kinds[a] == PLANE and kinds[b] == PLANE:
                        pair = _crease_pair(a, b, normals, offsets, centroids, max_cos)
                        pairs[tr, tc, j, q] = pairs[tr, tc, q, j] = pair
                        if pair != 0:
                            creased[tr, tc] = True
    return creased, pairs


@njit(cache=True, nogil=True, inline="always")
def _face_by_ray(table, pairs, tr, tc, m, best_j, planes, x, y, z, normals, offsets, least_cos):
    # The candidate (index j of tile (tr, tc)'s table) a plane pixel goes to: that of the first other
    # plane explaining it (bit j of ``planes``) that forms a crease with the nearest one (``pairs``), on
    # whose side of the crease the ray meets the surface (crease_moves' rule: the noise cannot
    # tell the two faces apart there, the rays can); ``best_j`` when none
    a = table[tr, tc, best_j]
    dist = 0.0  # the ray only once a crease needs it (most pairs of planes there are none)
    for j in range(m):
        if j == best_j or not planes & (1 << j) or pairs[tr, tc, best_j, j] == 0:
            continue
        if dist == 0.0:
            dist = np.sqrt(x * x + y * y + z * z)
            if not dist > 0.0:
                return best_j
        # the point's own vector for the unit ray: every test scales by its length alike
        if _ray_meets_b(x, y, z, a, table[tr, tc, j], pairs[tr, tc, best_j, j] > 0, normals, offsets,
                        least_cos * dist):
            return j
    return best_j


#: Sums per tile and label (:func:`label_pixels`' ``blocks``): signed distance, x, y, z, noise**2.
_BLOCK_SUMS = 5


@njit(cache=True, nogil=True)
def _block_sums_layout(table, count):
    # one slot per tile and candidate model, tiles in raster order: tile t's slots are
    # first[t]:first[t + 1], slot first[t] + j for its candidate table[t, j]
    th, tw = count.shape
    first = np.zeros(th * tw + 1, np.int64)
    for t in range(th * tw):
        first[t + 1] = first[t] + max(count[t // tw, t % tw], 0)
    owners = np.empty(first[-1], np.int32)
    for t in range(th * tw):
        for j in range(first[t + 1] - first[t]):
            owners[first[t] + j] = table[t // tw, t % tw, j]
    return first, owners


@njit(cache=True, nogil=True, inline="always")
def _add_block_row(taken_in, sums, slot, taken, offset, sx, sy, sz, noise2):
    taken_in[slot] += taken
    sums[slot, 0] += offset
    sums[slot, 1] += sx
    sums[slot, 2] += sy
    sums[slot, 3] += sz
    sums[slot, 4] += noise2


@njit(cache=True, nogil=True)
def _whole_tiles(taken_in, first, count, th, tw, tile, height, width):
    # tiles inside the image whose every pixel one label took (a single candidate)
    whole = np.zeros((th, tw), np.bool_)
    for tr in range(th):
        rows = min(tr * tile + tile, height) - tr * tile if tr < th - 1 else height - tr * tile
        for tc in range(tw):
            cols = min(tc * tile + tile, width) - tc * tile
            t = tr * tw + tc
            whole[tr, tc] = (count[tr, tc] == 1 and rows == tile and cols == tile
                             and taken_in[first[t]] == tile * tile)
    return whole


#: The standard deviation of normal values over their median absolute value.
MAD_SIGMA = 1.4826


@njit(cache=True, nogil=True)
def off_model_tiles(first, owners, taken_in, sums, whole, kinds, params, rms, usable, spread, floor, bound):
    """The tiles and labels whose pixels lie, as a group, off the label's model: the tile
    and label slots of :func:`label_pixels`' ``blocks`` whose mean signed distance is beyond
    ``bound`` times the larger of its noise times ``spread``, ``floor`` and the label's
    robust spread of such means (``MAD_SIGMA`` times their median absolute value).

    Slots of tiles inside a region (the tile and the 8 around it each ``whole`` with one
    label: a tile model takes a surface beside its own only where its tiles met another
    region or the image's edge) and of labels not ``usable`` (no model, or a model that
    changed since) are not tested. The noise of a mean: the root of the pixels' summed noise
    squares (a plane's range noise times the incidence cosine at their centroid, a curved
    model's range noise, at least ``rms``) over their count.

    Returns ``(tiles, owners)`` of the slots beyond the bound, tiles as ``tr * tw + tc``.
    """
    th, tw = whole.shape
    n = kinds.shape[0]
    slots = owners.size
    tested = np.zeros(slots, np.bool_)
    offsets = np.zeros(slots)
    noises = np.zeros(slots)
    per_label = np.zeros(n + 1, np.int64)
    for tr in range(th):
        for tc in range(tw):
            t = tr * tw + tc
            if _inside_whole(whole, owners, first, tr, tc):
                continue
            for s in range(first[t], first[t + 1]):
                k = owners[s]
                m = taken_in[s]
                if m == 0 or not usable[k]:
                    continue
                tested[s] = True
                offsets[s] = abs(sums[s, 0]) / m
                scale = 1.0
                if kinds[k] == PLANE:
                    scale = _incidence(kinds[k], params[k], sums[s, 1] / m, sums[s, 2] / m, sums[s, 3] / m)
                noises[s] = np.sqrt(max(sums[s, 4] * scale * scale, m * rms[k] * rms[k])) / m
                per_label[k + 1] += 1
    # each label's tested means together, for the median of their absolute values
    for k in range(n):
        per_label[k + 1] += per_label[k]
    gathered = np.empty(per_label[n])
    filled = per_label[:n].copy()
    for s in range(slots):
        if tested[s]:
            gathered[filled[owners[s]]] = offsets[s]
            filled[owners[s]] += 1
    spread_of = np.zeros(n)
    for k in range(n):
        if per_label[k + 1] > per_label[k]:
            spread_of[k] = MAD_SIGMA * np.median(gathered[per_label[k]:per_label[k + 1]])
    tiles = np.empty(slots, np.int64)
    labels = np.empty(slots, np.int32)
    found = 0
    for t in range(th * tw):
        for s in range(first[t], first[t + 1]):
            if tested[s] and offsets[s] > bound * max(spread * noises[s], floor, spread_of[owners[s]]):
                tiles[found], labels[found] = t, owners[s]
                found += 1
    return tiles[:found].copy(), labels[:found].copy()


@njit(cache=True, nogil=True, inline="always")
def _inside_whole(whole, owners, first, tr, tc):
    # tile (tr, tc) and the 8 around it inside the image, each whole with the same label
    th, tw = whole.shape
    if tr == 0 or tc == 0 or tr == th - 1 or tc == tw - 1:
        return False
    k = owners[first[tr * tw + tc]] if whole[tr, tc] else -1
    if k < 0:
        return False
    for rr in range(tr - 1, tr + 2):
        for cc in range(tc - 1, tc + 2):
            if not whole[rr, cc] or owners[first[rr * tw + cc]] != k:
                return False
    return True


@njit(cache=True, nogil=True, inline="always")
def _take(out, inliers, squares, counts, r, c, k, dist, noise, inlier_factor):
    # pixel (r, c) joins region k at distance dist (finite: it passed the test)
    out[r, c] = k
    counts[k] += 1
    squares[k] += dist * dist
    if dist <= inlier_factor * max(noise, 0.0):
        inliers[k] += 1


@njit(cache=True, nogil=True)
def tile_groups(tiles, tiles_across):
    """Groups of the entries ``tiles[j]`` (tiles row-major, ``tiles_across`` per row):
    entries whose tiles are the same or touch (8-neighbours) share a group, numbered from 0
    in order of their first entry. Returns the group of each entry."""
    n = tiles.shape[0]
    parent = np.arange(n)
    for i in range(n):
        ri, ci = tiles[i] // tiles_across, tiles[i] % tiles_across
        for j in range(i + 1, n):
            rj, cj = tiles[j] // tiles_across, tiles[j] % tiles_across
            if abs(rj - ri) <= 1 and abs(cj - ci) <= 1:
                a, b = i, j
                while parent[a] != a:
                    a = parent[a]
                while parent[b] != b:
                    b = parent[b]
                if a != b:
                    parent[max(a, b)] = min(a, b)
    group = np.empty(n, np.int64)
    number = np.full(n, -1, np.int64)
    count = 0
    for i in range(n):
        a = i
        while parent[a] != a:
            a = parent[a]
        if number[a] < 0:
            number[a] = count
            count += 1
        group[i] = number[a]
    return group


@njit(cache=True, nogil=True)
def tile_members(labels, tile, tiles, owners):
    """The pixels of label ``owners[j]`` in tile ``tiles[j]`` (row-major over the ``tile x
    tile`` blocks of ``labels``), for every j: their flat indices and their entry j."""
    h, w = labels.shape
    tiles_across = (w + tile - 1) // tile
    pixels = np.empty(tiles.shape[0] * tile * tile, np.int64)
    entries = np.empty(tiles.shape[0] * tile * tile, np.int64)
    count = 0
    for j in range(tiles.shape[0]):
        r0 = (tiles[j] // tiles_across) * tile
        c0 = (tiles[j] % tiles_across) * tile
        for r in range(r0, min(r0 + tile, h)):
            for c in range(c0, min(c0 + tile, w)):
                if labels[r, c] == owners[j]:
                    pixels[count] = r * w + c
                    entries[count] = j
                    count += 1
    return pixels[:count].copy(), entries[:count].copy()


@njit(cache=True, nogil=True)
def free_blocks(labels, tile, blocks, owners, released):
    """Set to 0 the pixels of label ``owners[j]`` in block ``blocks[j]`` (row-major index over
    the ``tile x tile`` blocks of ``labels``), for every j, and to ``owners[j]`` the same
    pixels of ``released``; both are changed in place. Returns the flat indices of the
    freed pixels, in raster order."""
    h, w = labels.shape
    blocks_across = (w + tile - 1) // tile
    freed = np.empty(blocks.shape[0] * tile * tile, np.int64)
    count = 0
    for j in range(blocks.shape[0]):
        r0 = (blocks[j] // blocks_across) * tile
        c0 = (blocks[j] % blocks_across) * tile
        k = owners[j]
        for r in range(r0, min(r0 + tile, h)):
            for c in range(c0, min(c0 + tile, w)):
                if labels[r, c] == k:
                    labels[r, c] = 0
                    released[r, c] = k
                    freed[count] = r * w + c
                    count += 1
    return np.sort(freed[:count])


@njit(cache=True, nogil=True)
def leftover_blobs(labels, valid, min_size, first_label, thin_min_size=0):
    """Compact blobs of valid, unlabelled pixels: :func:`rangeseg_o3d.refinement.recover.leftover_candidates`
    without a jump mask, in one pass over the grid and then work on the leftover pixels only.

    Cores are the leftover pixels whose 3x3 neighbourhood is all leftover (the grid border
    replicated); 4-connected cores are numbered in raster order of their first pixel, each
    leftover pixel takes the largest core number in its 3x3 neighbourhood, and blobs of at
    least ``min_size`` pixels are renumbered from ``first_label``. With ``thin_min_size > 0``
    the leftover pixels no such blob took (strips too thin for a core, and what is left of
    blobs under ``min_size``) follow as thin blobs: their 4-connected pieces of at least
    ``thin_min_size`` pixels, numbered on after the others in raster order of their first pixel.

    ``labels`` and ``valid`` must be C-contiguous: the pass reads them as flat views (a
    compiled reshape cannot copy); :mod:`rangeseg_o3d.fullres` passes them through
    ``np.ascontiguousarray``.

    Returns ``(candidates (H, W) int32, boxes (n, 4) int64, n_cored, free)``: each blob's bounding
    box ``(row0, row1, col0, col1)`` (half-open), blob ``first_label + j`` in row ``j``; the
    first ``n_cored`` blobs are the cored ones; ``free`` the flat indices of the valid
    unlabelled pixels, increasing (the pass lists them: a caller that needs them later need
    not scan the grid again).
    """
    h, w = labels.shape
    candidates = np.zeros((h, w), np.int32)
    none = np.zeros((0, 4), np.int64)
    # one pass over the grid (flat: no 2-D index per pixel): the leftover pixels listed in
    # raster order and marked -1 in ``candidates`` (each of them is written again below, so
    # the marks never reach the answer); all later work is theirs (a few percent of a frame)
    flat_labels = labels.reshape(h * w)
    flat_valid = valid.reshape(h * w)
    marks = candidates.reshape(h * w)
    listed = np.empty(h * w, np.int64)  # (only the first n_free entries are touched)
    n_free = 0
    for i in range(h * w):
        if flat_valid[i] and flat_labels[i] == 0:
            marks[i] = -1
            listed[n_free] = i
            n_free += 1
    free = listed[:n_free].copy()
    if n_free == 0:
        return candidates, none, 0, free
    rows = np.empty(n_free, np.int64)
    cols = np.empty(n_free, np.int64)
    for j in range(n_free):
        rows[j] = listed[j] // w
        cols[j] = listed[j] - rows[j] * w
    # cores: leftover pixels whose 3x3 neighbourhood (border replicated) is all leftover
    core = np.zeros((h, w), np.int32)  # -1: a core pixel not yet numbered
    n_core_pixels = 0
    for j in range(n_free):
        r, c = rows[j], cols[j]
        if _all_marked_around(candidates, r, c, h, w):
            core[r, c] = -1
            n_core_pixels += 1
    n_cores = _number_listed(core, rows, cols, n_core_pixels) if n_core_pixels else 0
    # every leftover pixel takes the largest core number around it (3x3, border replicated)
    sizes = np.zeros(n_cores + 1, np.int64)
    for j in range(n_free):
        r, c = rows[j], cols[j]
        k = _max_around(core, r, c, h, w)
        candidates[r, c] = k
        sizes[k] += 1
    lut = np.zeros(n_cores + 1, np.int32)
    kept = 0
    for k in range(1, n_cores + 1):
        if sizes[k] >= min_size:
            lut[k] = first_label + kept
            kept += 1
    n_cored = kept
    # the leftover pixels no kept blob took, marked -1 in ``thin`` (when asked for): the core
    # image again, whose numbers are read no more; every -1 in it was numbered, so a -1
    # there now is a thin pixel, and each thin pixel's entry is set below
    thin = core if thin_min_size > 0 else np.zeros((1, 1), np.int32)
    n_thin_pixels = 0
    for j in range(n_free):
        r, c = rows[j], cols[j]
        k = candidates[r, c]
        if k != 0:
            k = lut[k]
            candidates[r, c] = k
        if k == 0 and thin_min_size > 0:
            thin[r, c] = -1
            n_thin_pixels += 1
    thin_lut = np.zeros(1, np.int32)
    n_thin = _number_listed(thin, rows, cols, n_thin_pixels) if n_thin_pixels else 0
    if n_thin:
        thin_sizes = np.zeros(n_thin + 1, np.int64)
        for j in range(n_free):
            r, c = rows[j], cols[j]
            if candidates[r, c] == 0:
                thin_sizes[thin[r, c]] += 1
        thin_lut = np.zeros(n_thin + 1, np.int32)
        for k in range(1, n_thin + 1):
            if thin_sizes[k] >= thin_min_size:
                thin_lut[k] = first_label + kept
                kept += 1
    if kept == 0:
        return candidates, none, 0, free
    boxes = np.empty((kept, 4), np.int64)
    boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3] = h, 0, w, 0
    for j in range(n_free):
        r, c = rows[j], cols[j]
        k = candidates[r, c]
        if k == 0 and n_thin:
            k = thin_lut[thin[r, c]]
            candidates[r, c] = k
        if k:
            b = k - first_label
            boxes[b, 0], boxes[b, 1] = min(boxes[b, 0], r), max(boxes[b, 1], r + 1)
            boxes[b, 2], boxes[b, 3] = min(boxes[b, 2], c), max(boxes[b, 3], c + 1)
    return candidates, boxes, n_cored, free


@njit(cache=True, nogil=True, inline="always")
def _all_marked_around(marks, r, c, h, w):
    # every pixel of the 3x3 neighbourhood of (r, c) marked -1 (leftover), the grid's border replicated
    for rr in (max(r - 1, 0), r, min(r + 1, h - 1)):
        for cc in (max(c - 1, 0), c, min(c + 1, w - 1)):
            if marks[rr, cc] != -1:
                return False
    return True


@njit(cache=True, nogil=True, inline="always")
def _max_around(image, r, c, h, w):
    # the largest value of the 3x3 neighbourhood of (r, c), the grid's border replicated
    best = image[r, c]
    for rr in (max(r - 1, 0), r, min(r + 1, h - 1)):
        for cc in (max(c - 1, 0), c, min(c + 1, w - 1)):
            best = max(best, image[rr, cc])
    return best


@njit(cache=True, nogil=True)
def _number_listed(marks, rows, cols, n_marked):
    # Number the 4-connected pieces of the pixels marked -1 (all among the listed pixels,
    # listed in raster order) as 1, 2, ... in raster order of their first pixel (OpenCV's
    # order); returns how many there are.
    h, w = marks.shape
    stack_r = np.empty(n_marked, np.int64)
    stack_c = np.empty(n_marked, np.int64)
    pieces = 0
    for j in range(rows.shape[0]):
        r, c = rows[j], cols[j]
        if marks[r, c] != -1:
            continue
        pieces += 1
        marks[r, c] = pieces
        stack_r[0], stack_c[0], depth = r, c, 1
        while depth:
            depth -= 1
            pr, pc = stack_r[depth], stack_c[depth]
            if pr > 0 and marks[pr - 1, pc] == -1:
                marks[pr - 1, pc] = pieces
                stack_r[depth], stack_c[depth] = pr - 1, pc
                depth += 1
            if pr < h - 1 and marks[pr + 1, pc] == -1:
                marks[pr + 1, pc] = pieces
                stack_r[depth], stack_c[depth] = pr + 1, pc
                depth += 1
            if pc > 0 and marks[pr, pc - 1] == -1:
                marks[pr, pc - 1] = pieces
                stack_r[depth], stack_c[depth] = pr, pc - 1
                depth += 1
            if pc < w - 1 and marks[pr, pc + 1] == -1:
                marks[pr, pc + 1] = pieces
                stack_r[depth], stack_c[depth] = pr, pc + 1
                depth += 1
    return pieces


@njit(cache=True, nogil=True)
def _grown(array, size):
    # ``array`` with room for at least ``size`` items (doubled), its items kept
    if size <= array.shape[0]:
        return array
    out = np.empty(max(size, 2 * array.shape[0]), array.dtype)
    out[: array.shape[0]] = array
    return out


@njit(cache=True, nogil=True)
def grow_free(xyz, labels, kinds, params, rms, sigma, ranges, k_sigma, jump_ratio, jump_min,
              inlier_factor, inliers, squares, counts, touch):
    """Grow regions into free valid pixels, ring after ring until no pixel joins (in place).

    A free pixel joins the 4-neighbouring region whose model is within
    ``k_sigma * max(sigma, rms)`` of it, the nearest in those units when several are, when
    the range step to that neighbour is no jump (``<= max(jump_min, jump_ratio * r)``, or,
    into a plane, within that of the plane's own step between the two rays); each ring is decided on the labels as they were at its start. Regions with
    ``kinds[k] == 0`` do not grow. ``inliers``, ``squares`` and ``counts`` (per label, as
    :func:`label_pixels` returns them) take each pixel that joins. A pixel is looked at
    again only when a neighbour joined a region in the ring before (nothing else changes its
    answer). ``touch`` (n x n bool, n = ``kinds.shape[0]``) is set for every pair of labels
    below n that a pixel which joined made 4-neighbours. Returns the number of pixels added.
    The work arrays grow with the frontier (a frame-sized one per call costs more than the
    growth on a frame with few free pixels).
    """
    h, w = labels.shape
    flat = labels.ravel()
    n = kinds.shape[0]
    front = np.empty(1024, np.int64)
    n_front = 0
    # one pass: the first frontier, free valid pixels next to a labelled one; a listed
    # pixel is marked -1 in ``labels`` until its ring decides it
    for r in range(h):
        for c in range(w):
            if labels[r, c] != 0:
                continue
            i = r * w + c
            if not np.isfinite(xyz[i, 2]):
                continue
            if ((r > 0 and labels[r - 1, c] > 0) or (r < h - 1 and labels[r + 1, c] > 0)
                    or (c > 0 and labels[r, c - 1] > 0) or (c < w - 1 and labels[r, c + 1] > 0)):
                front = _grown(front, n_front + 1)
                front[n_front] = i
                n_front += 1
    for f in range(n_front):
        flat[front[f]] = -1
    following = np.empty(front.shape[0], np.int64)
    chosen = np.empty(front.shape[0], np.int32)
    gaps = np.empty(front.shape[0])
    added = np.empty(1024, np.int64)
    total = 0
    while n_front > 0:
        chosen = _grown(chosen, n_front)
        gaps = _grown(gaps, n_front)
        for f in range(n_front):
            chosen[f], gaps[f] = _nearest_neighbour_model(front[f], flat, h, w, xyz, kinds, params, rms, sigma,
                                                          ranges, k_sigma, jump_ratio, jump_min, True)
        for f in range(n_front):
            i = front[f]
            k = chosen[f]
            flat[i] = k  # 0 again when nothing took it
            if k == 0:
                continue
            added = _grown(added, total + 1)
            added[total] = i
            total += 1
            counts[k] += 1
            squares[k] += gaps[f] * gaps[f]
            if gaps[f] <= inlier_factor * sigma[i]:
                inliers[k] += 1
        n_next = 0
        for f in range(n_front):
            if chosen[f] == 0:
                continue
            i = front[f]
            for step in range(4):
                j = _neighbour(i, step, h, w)
                if j >= 0 and flat[j] == 0 and np.isfinite(xyz[j, 2]):
                    flat[j] = -1
                    following = _grown(following, n_next + 1)
                    following[n_next] = j
                    n_next += 1
        front, following = following, front
        n_front = n_next
    for a in range(total):  # the pairs the grown pixels made
        i = added[a]
        k = flat[i]
        for step in range(4):
            j = _neighbour(i, step, h, w)
            if j >= 0 and 0 < flat[j] < n and flat[j] != k:
                touch[k, flat[j]] = touch[flat[j], k] = True
    return total


@njit(cache=True, nogil=True, inline="always")
def _run_end(row, start, stop, k):
    # The first index from ``start`` (before ``stop``) where ``row`` is not ``k``, else
    # ``stop``: eight pixels a test while the run goes on (one vector compare; a frame's
    # runs are dozens to hundreds of pixels long), then pixel by pixel.
    end = start
    while end + 8 <= stop:
        if not ((row[end] == k) & (row[end + 1] == k) & (row[end + 2] == k) & (row[end + 3] == k)
                & (row[end + 4] == k) & (row[end + 5] == k) & (row[end + 6] == k) & (row[end + 7] == k)):
            break
        end += 8
    while end < stop and row[end] == k:
        end += 1
    return end


@njit(cache=True, nogil=True)
def label_boxes(labels, n):
    """(n, 4) int64: label ``k``'s bounding box ``(row0, row1, col0, col1)`` (half-open) in
    row ``k``; ``(h, 0, w, 0)`` for a label without pixels (and for labels >= n)."""
    h, w = labels.shape
    boxes = np.empty((n, 4), np.int64)
    boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3] = h, 0, w, 0
    # a row's runs of one label update its box once each (first and last column of the
    # run), not once per pixel; a run's end is found eight pixels at a time (a pixel at a
    # time cost a 640 x 480 frame ~0.2 ms, this ~0.14)
    for r in range(h):
        row = labels[r]
        c = 0
        while c < w:
            k = row[c]
            end = _run_end(row, c + 1, w, k)
            if 0 < k < n:
                boxes[k, 0] = min(boxes[k, 0], r)
                boxes[k, 1] = max(boxes[k, 1], r + 1)
                boxes[k, 2] = min(boxes[k, 2], c)
                boxes[k, 3] = max(boxes[k, 3], end)
            c = end
    return boxes


@njit(cache=True, nogil=True)
def label_sample(xyz, labels, k, row0, row1, col0, col1, step):
    """The points ``xyz[r, c]`` (all three coordinates finite) of the pixels of label ``k``
    at rows ``row0, row0 + step, ... < row1`` and columns ``col0, col0 + step, ... < col1``,
    in raster order: ``xyz[box][::step, ::step][labels[box][::step, ::step] == k]`` without
    its non-finite rows, as one (m, 3) array of ``xyz``'s dtype (numpy's slicing, mask and
    finite test cost ~30 microseconds a region in small-array calls)."""
    rows = len(range(row0, row1, step))
    cols = len(range(col0, col1, step))
    out = np.empty((rows * cols, 3), xyz.dtype)  # room for every grid pixel: one pass
    m = 0
    for r in range(row0, row1, step):
        for c in range(col0, col1, step):
            if labels[r, c] == k:
                x, y, z = xyz[r, c, 0], xyz[r, c, 1], xyz[r, c, 2]
                if np.isfinite(x) and np.isfinite(y) and np.isfinite(z):
                    out[m, 0], out[m, 1], out[m, 2] = x, y, z
                    m += 1
    return out[:m].copy()


@njit(cache=True, nogil=True)
def labels_touch(labels, a, b, row0, row1, col0, col1):
    """Whether a pixel of label ``a`` and one of label ``b`` are 4-neighbours within rows
    ``row0:row1`` and columns ``col0:col1`` (stops at the first such pair)."""
    for r in range(row0, row1):
        for c in range(col0, col1):
            k = labels[r, c]
            if k != a and k != b:
                continue
            other = b if k == a else a
            if (c + 1 < col1 and labels[r, c + 1] == other) or (r + 1 < row1 and labels[r + 1, c] == other):
                return True
    return False
