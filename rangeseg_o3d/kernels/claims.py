"""Pixels passed between plane regions along the viewing rays, round by round over the grid."""

from __future__ import annotations

import numpy as np
from .growth import _ray_term
from .inline import _neighbour
from .jit import njit  # numba.njit, with this package's cache locator installed

CACHE_DEPENDS = ("growth.py", "inline.py", "kinds.py")

__all__ = ["outlier_claims", "box_claims", "block_offsets"]


@njit(cache=True, nogil=True)
def _off_along_ray(xyz, noise, i, a):
    # how far, in range sigmas, the plane a . p = 1 meets the ray of pixel i from its return
    # (NaN without a return: never beyond, never within)
    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    r = np.sqrt(x * x + y * y + z * z)
    return r * abs(1.0 - (a[0] * x + a[1] * y + a[2] * z)) / noise[i]


@njit(cache=True, nogil=True)
def _other_plane(out, is_plane, j, own):
    # whether pixel j lies in a plane region other than own
    other = out[j]
    return other != own and is_plane[other]


@njit(cache=True, nogil=True)
def outlier_claims(labels, xyz, noise, inverse_planes, is_plane, limit, rounds):
    """The labels after plane regions pass on the pixels their planes leave beyond ``limit``
    range sigmas along the rays: each such pixel goes to the plane region of a 4-neighbour
    whose plane meets its ray within ``limit`` and nearest, in range sigmas. It starts at the
    pixels of a plane region with a 4-neighbour in another plane region; a pixel given passes
    the claim on to the pixels beside it, looked at once each, round by round (at most
    ``rounds``). Each round judges its pixels by the labels at its start, and a pixel not given
    is judged again only once a pixel beside it has been given (nothing else it depends on
    changes).

    ``labels`` (H, W) int32; ``xyz`` (H*W, 3) and ``noise`` (H*W,) flat; ``inverse_planes``
    (n, 3) the plane ``a . p = 1`` of each label ``k`` with ``is_plane[k]`` (n > every label).
    Returns the new labels, flat int32 (a copy)."""
    h, w = labels.shape
    out = labels.copy().reshape(-1)
    size = out.size
    seen = np.zeros(size, np.bool_)
    waiting = np.zeros(size, np.bool_)  # looked at, beyond its plane, not given
    far = np.empty(size)
    # the round a pixel was last queued for, read only for waiting pixels and set (-1) when one
    # starts to wait: no pass over the frame to fill it (7 MB on a 1280 x 720 scan)
    queued = np.empty(size, np.int64)
    active = np.empty(size, np.int64)
    count = 0
    for row in range(h):  # the start: plane pixels beside another plane region
        for col in range(w):
            i = row * w + col
            own = out[i]
            if not is_plane[own]:
                continue
            if not ((row > 0 and _other_plane(out, is_plane, i - w, own))
                    or (row < h - 1 and _other_plane(out, is_plane, i + w, own))
                    or (col > 0 and _other_plane(out, is_plane, i - 1, own))
                    or (col < w - 1 and _other_plane(out, is_plane, i + 1, own))):
                continue
            seen[i] = True
            d = _off_along_ray(xyz, noise, i, inverse_planes[own])
            if d > limit:
                waiting[i], far[i], queued[i] = True, d, -1
                active[count] = i
                count += 1
    best = np.empty(size, np.int32)
    for round_ in range(rounds):
        if count == 0:
            break
        moved = 0
        for t in range(count):
            i = active[t]
            own = out[i]
            choice, nearest = own, far[i]
            for s in range(4):
                j = _neighbour(i, s, h, w)
                if j < 0:
                    continue
                other = out[j]
                if other == own or not is_plane[other]:
                    continue
                d = _off_along_ray(xyz, noise, i, inverse_planes[other])
                if d <= limit and d < nearest:
                    choice, nearest = other, d
            best[t] = choice
            if choice != own:
                moved += 1
        if moved == 0:
            break
        given = np.empty(moved, np.int64)
        g = 0
        for t in range(count):
            i = active[t]
            if best[t] != out[i]:
                out[i] = best[t]
                waiting[i] = False
                given[g] = i
                g += 1
        count = 0
        for t in range(moved):  # the next round: the pixels beside those given
            for s in range(4):
                j = _neighbour(given[t], s, h, w)
                if j < 0 or not is_plane[out[j]]:
                    continue
                if not seen[j]:
                    seen[j] = True
                    d = _off_along_ray(xyz, noise, j, inverse_planes[out[j]])
                    if d > limit:
                        waiting[j], far[j], queued[j] = True, d, -1
                # (a pixel queued this round is waiting: the gives came before the queueing)
                if waiting[j] and queued[j] != round_:
                    queued[j] = round_
                    active[count] = j
                    count += 1
    return out



@njit(cache=True, nogil=True)
def box_claims(xyz, sigma, valid, owner, k, a, others, trim):
    """The (H, W) mask of the pixels of a box of the grid that region ``k``'s plane along the
    rays ``a`` (``a . p = 1``) may claim, row by row (``xyz`` (H, W, 3), ``sigma``, ``valid``
    and the labels ``owner`` (H, W), views of the frame's): a valid pixel (:func:`box_ray_terms`)
    free (label 0) or of another region with a plane along the rays (row ``others[j]`` finite;
    ``j`` within its rows and not ``k``) that ``a`` meets within ``trim`` of its range noise
    along its ray, and nearer in those units than its own region's plane. The same decisions
    as numpy's terms of :func:`box_ray_terms` with ``sqrt(w) |q - u @ a|`` for both planes,
    without the box's terms, distances and a pass a neighbouring region (the form it replaced
    in :func:`rangeseg_o3d.plane_faces.claim_along_rays`: 4-5 ms of a stereo scan's 1280 x 720)."""
    h, w = valid.shape
    n = others.shape[0]
    out = np.zeros((h, w), np.bool_)
    a0, a1, a2 = a[0], a[1], a[2]
    for row in range(h):
        for col in range(w):
            j = owner[row, col]
            if j == k or not valid[row, col]:
                continue
            other = j != 0
            if other and (j < 0 or j >= n or not np.isfinite(others[j, 0])):
                continue  # neither free nor of a plane region: not claimed
            x, y, z = xyz[row, col, 0], xyz[row, col, 1], xyz[row, col, 2]
            if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
                continue
            ux, uy, uz, q, wt = _ray_term(x, y, z, sigma[row, col])
            root = np.sqrt(wt)
            mine = root * abs(q - (ux * a0 + uy * a1 + uz * a2))
            if not mine <= trim:
                continue
            if other:
                theirs = root * abs(q - (ux * others[j, 0] + uy * others[j, 1] + uz * others[j, 2]))
                if not (np.isfinite(theirs) and mine < theirs):
                    continue
            out[row, col] = True
    return out


@njit(cache=True, nogil=True)
def block_offsets(xyz, sigma, labels, slots, normals, offsets, step, block):
    """``(sums, counts)``, each ``(P, ceil(H / step / block), ceil(W / step / block))``: over
    the pixels of every ``step``-th row and column of the ``(H, W)`` label image (one a
    matching window: independent returns), in blocks of ``block`` x ``block`` of them, per
    label ``k`` with a slot ``p = slots[k] >= 0`` (of ``P``) whose plane ``normals[p] . p =
    offsets[p]`` is set (a zero normal: none), the sum of its pixels' ranges less the range
    at which that plane meets their rays, in units of their range noise ``sigma`` (clipped
    at 10: a few mixed pixels make no face), and how many pixels were summed. ``xyz`` is
    ``(H * W, 3)``, ``sigma`` ``(H * W,)``; labels at or past ``slots``' length are skipped,
    as are pixels whose ray does not meet the plane in front or whose return is not finite.
    The sums are kept for the planes' slots only (one per label over the hundreds of labels
    of a stereo scan took more to zero and scan than the pass itself)."""
    height, width = labels.shape
    top = slots.shape[0]
    planes = normals.shape[0]
    rows_s, cols_s = (height + step - 1) // step, (width + step - 1) // step
    rows_b, cols_b = (rows_s + block - 1) // block, (cols_s + block - 1) // block
    sums = np.zeros((planes, rows_b, cols_b))
    counts = np.zeros((planes, rows_b, cols_b), np.int64)
    for rs in range(rows_s):
        r = rs * step
        for cs in range(cols_s):
            k = labels[r, cs * step]
            if k <= 0 or k >= top:
                continue
            p = slots[k]
            if p < 0 or p >= planes:
                continue
            nx, ny, nz = normals[p, 0], normals[p, 1], normals[p, 2]
            if nx == 0.0 and ny == 0.0 and nz == 0.0:
                continue
            i = r * width + cs * step
            x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            along = nx * x + ny * y + nz * z  # the range times the ray's cosine on the plane
            s = sigma[i]
            if not (along * offsets[p] > 0.0) or not (s > 0.0):
                continue
            rng = np.sqrt(x * x + y * y + z * z)
            off = (rng - offsets[p] * rng / along) / s
            if not (off == off):
                continue
            sums[p, rs // block, cs // block] += min(10.0, max(-10.0, off))
            counts[p, rs // block, cs // block] += 1
    return sums, counts
