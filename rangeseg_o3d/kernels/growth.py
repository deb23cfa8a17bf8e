"""Compiled ring growth of faces whose planes were fitted along the rays (the off-model faces of
:func:`rangeseg_o3d.off_model.faces_along_rays`): a numpy pass per ring cost about half a
millisecond however few pixels it looked at, and most faces grown so are undone."""

from __future__ import annotations

import numpy as np
from .inline import _add_ray_terms
from .jit import njit  # numba.njit, with this package's cache locator installed

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("inline.py", "kinds.py")


@njit(cache=True, nogil=True)
def _neighbour(r, c, step):
    """The 4-neighbour ``step`` (0 above, 1 below, 2 left, 3 right) of pixel ``(r, c)``."""
    if step == 0:
        return r - 1, c
    if step == 1:
        return r + 1, c
    if step == 2:
        return r, c - 1
    return r, c + 1


@njit(cache=True, nogil=True)
def _beside(flat, w, r, c, r0, r1, c0, c1, first, count, planes, grow):
    """The label of the first 4-neighbour of pixel ``(r, c)`` inside the window rows
    ``r0:r1``, columns ``c0:c1`` (above, below, left, right) that a ring grows from: a face
    ``first .. first + count - 1`` when growing, a plane region (label > 0, a plane row in
    ``planes``) when giving back; 0 when none."""
    for step in range(4):
        rr, cc = _neighbour(r, c, step)
        if rr < r0 or rr >= r1 or cc < c0 or cc >= c1:
            continue
        k = flat[rr * w + cc]
        face = first <= k < first + count
        if grow:
            if face:
                return k
        elif not face and k > 0 and not np.isnan(planes[k, 0]):
            return k
    return 0


@njit(cache=True, nogil=True)
def grow_along_rays(xyz, flat, h, w, planes, concave, crease, noise, first, count, box, k_sigma, rings):
    """The faces ``first .. first + count - 1`` of the flat labels ``flat`` (an (h, w) grid; in
    place) grow ring by ring (at most ``rings``) into the 4-adjacent pixels that are free and
    whose range the face's plane meets within ``k_sigma`` range-noise sigmas (``noise``), or
    that a plane region holds on the face's side of their crease; then give back, ring by
    ring, their pixels on the region's side that its plane meets so. ``planes[k]`` is region
    ``k``'s plane as ``normal / d`` (NaN for no plane: its ray meets it at ``1 / (a . u)``);
    ``concave[j, k]``: face ``j`` on the sensor's side of region ``k``'s plane (the nearer plane
    is the one seen, else the farther); ``crease[j, k]``: the two planes turned from each other
    (no crease, no side: the region keeps its pixels). ``box`` (row0, row1, col0, col1,
    half-open) holds the faces; a ring looks at the box and one pixel around it, and a
    neighbour outside that does not count. Each ring decides on the labels the last ring left.
    Returns the flat pixels that changed hands, ring by ring."""
    n = planes.shape[0]
    b0, b1, b2, b3 = box[0], box[1], box[2], box[3]
    moved = np.empty(0, np.int64)
    n_moved = 0
    # (buffers for every ring: a ring looks at most at every pixel of the window once, the box
    # and one pixel around it, which grows by at most a pixel a side each ring: sized for the
    # last ring's window, not the frame, whose buffers cost more than the rings of a strip)
    wr0, wr1 = max(b0 - rings - 1, 0), min(b1 + rings + 1, h)
    wc0, wc1 = max(b2 - rings - 1, 0), min(b3 + rings + 1, w)
    across = wc1 - wc0
    size = (wr1 - wr0) * across
    looks = np.empty(size, np.int64)
    take_idx = np.empty(size, np.int64)
    take_new = np.empty(size, np.int64)
    seen = np.zeros(size, np.int32)  # the last ring that looked at a pixel (window rows of ``across``)
    ring = 0
    # a pixel's fate in a ring depends on its label and its 4 neighbours' alone: after a phase's
    # first ring (the whole window), only the neighbours of the pixels the last ring moved can
    # change their answer, and a ring looks at those alone
    for phase in range(2):
        grow = phase == 0
        n_last = 0  # the pixels the last ring moved: take_idx[:n_last]
        for step in range(rings):
            ring += 1
            r0, r1, c0, c1 = max(b0 - 1, 0), min(b1 + 1, h), max(b2 - 1, 0), min(b3 + 1, w)
            n_looks = 0
            if step == 0:
                for r in range(r0, r1):
                    for c in range(c0, c1):
                        looks[n_looks] = r * w + c
                        n_looks += 1
            else:
                for m in range(n_last):
                    r, c = take_idx[m] // w, take_idx[m] % w
                    for near in range(5):  # the pixel and its 4-neighbours
                        rr, cc = (r, c) if near == 4 else _neighbour(r, c, near)
                        if rr < r0 or rr >= r1 or cc < c0 or cc >= c1:
                            continue
                        i = rr * w + cc
                        at = (rr - wr0) * across + cc - wc0
                        if seen[at] != ring:
                            seen[at] = ring
                            looks[n_looks] = i
                            n_looks += 1
            n_take = 0
            for m in range(n_looks):
                i = looks[m]
                r, c = i // w, i % w
                holder = flat[i]
                inside = first <= holder < first + count
                if inside != (not grow):
                    continue  # growing looks at pixels off the faces, giving back at theirs
                other = _beside(flat, w, r, c, r0, r1, c0, c1, first, count, planes, grow)
                if other == 0:
                    continue
                x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
                rng = np.sqrt(x * x + y * y + z * z)
                if not (np.isfinite(rng) and rng > 0):
                    continue
                if grow:
                    face_of, region = other, holder
                else:
                    face_of, region = holder, other
                reg = region if region >= 0 else region + n  # (as numpy indexes)
                ux, uy, uz = x / rng, y / rng, z / rng
                scale = rng * rng / max(noise[i], 1e-12)  # inverse-range residuals in noise sigmas
                at_face = ux * planes[face_of, 0] + uy * planes[face_of, 1] + uz * planes[face_of, 2]
                px, py, pz = planes[reg, 0], planes[reg, 1], planes[reg, 2]
                is_plane = not np.isnan(px)
                if not is_plane:
                    px, py, pz = 0.0, 0.0, 0.0
                at_region = ux * px + uy * py + uz * pz
                plane_region = region > 0 and is_plane and crease[face_of - first, reg]
                # which plane the ray sees: the nearer (larger inverse range) across a concave crease
                if concave[face_of - first, reg]:
                    face_seen = at_face > at_region
                else:
                    face_seen = at_face < at_region
                face_seen = face_seen or at_region <= 0
                if grow:
                    take = (abs(1.0 / rng - at_face) * scale <= k_sigma
                            and (region == 0 or (plane_region and face_seen)))
                    new = face_of
                else:
                    take = plane_region and not face_seen and abs(1.0 / rng - at_region) * scale <= k_sigma
                    new = region
                if take:
                    take_idx[n_take] = i
                    take_new[n_take] = new
                    n_take += 1
            if n_take == 0:
                break
            if n_moved + n_take > moved.size:
                grown = np.empty(max(2 * moved.size, n_moved + n_take), np.int64)
                grown[:n_moved] = moved[:n_moved]
                moved = grown
            for t in range(n_take):
                i = take_idx[t]
                flat[i] = take_new[t]
                moved[n_moved] = i
                n_moved += 1
                if grow:
                    r, c = i // w, i % w
                    b0, b1, b2, b3 = min(b0, r), max(b1, r + 1), min(b2, c), max(b3, c + 1)
            n_last = n_take
    return moved[:n_moved]


@njit(cache=True, nogil=True)
def grow_face(xyz, flat, h, w, planes, units, noise, face, held, k_sigma, cos_angle, rings):
    """One face's ring growth of :func:`rangeseg_o3d.off_model.faces_along_rays` in one call:
    face ``face`` of the flat labels ``flat`` (in place; its pixels among ``held``, flat,
    increasing) grows by :func:`grow_along_rays` alone, with its ``concave`` row (the face's
    centre on the sensor's side of each region's plane row of ``planes``) and its ``crease``
    row (each unit row of ``units`` turned from the face's by more than the angle whose cosine
    is ``cos_angle``). Returns ``(moved, held)``: the flat pixels that changed hands and the
    pixels the face may hold now (``held`` with ``moved``, increasing, each once). No pixel
    held: nothing moves. The same decisions as the numpy wrapper it replaces (the centre is
    the same sum in the same order; a plane's side is taken against 1.0 and a crease against
    ``cos_angle``, which only the last bit of a dot product could move) without its dozen
    small numpy calls a face."""
    n = planes.shape[0]
    count = 0
    sx, sy, sz = 0.0, 0.0, 0.0
    r0, r1, c0, c1 = h, -1, w, -1
    for i in range(held.size):
        p = held[i]
        if flat[p] != face:
            continue
        count += 1
        # (numpy's mean over the rows: each column summed in row order, then divided)
        sx += xyz[p, 0]
        sy += xyz[p, 1]
        sz += xyz[p, 2]
        r, c = p // w, p % w
        r0, r1, c0, c1 = min(r0, r), max(r1, r), min(c0, c), max(c1, c)
    if count == 0:
        return np.zeros(0, np.int64), held
    cx, cy, cz = sx / count, sy / count, sz / count
    concave = np.zeros((1, n), np.bool_)
    crease = np.zeros((1, n), np.bool_)
    ux, uy, uz = units[face, 0], units[face, 1], units[face, 2]
    for k in range(n):
        concave[0, k] = planes[k, 0] * cx + planes[k, 1] * cy + planes[k, 2] * cz < 1.0
        crease[0, k] = abs(units[k, 0] * ux + units[k, 1] * uy + units[k, 2] * uz) < cos_angle
    box = np.array([r0, r1 + 1, c0, c1 + 1], np.int64)
    moved = grow_along_rays(xyz, flat, h, w, planes, concave, crease, noise, face, 1, box, k_sigma, rings)
    both = np.empty(held.size + moved.size, np.int64)
    both[:held.size] = held
    both[held.size:] = moved
    both.sort()
    keep = np.ones(both.size, np.bool_)
    for i in range(1, both.size):
        keep[i] = both[i] != both[i - 1]
    return moved, both[keep]


@njit(cache=True, nogil=True)
def _maximum(a, b):
    """``np.maximum`` of two floats (a NaN wins, as numpy's does)."""
    if np.isnan(a) or a >= b:
        return a
    return b


@njit(cache=True, nogil=True, inline="always")
def _ray_term(x, y, z, sigma):
    """One point's ``(u_x, u_y, u_z, q, w)`` of :func:`rangeseg_o3d.ray_planes.ray_terms`, each
    rounded as numpy's: the norm ``sqrt((x^2 + y^2) + z^2)`` (np.linalg.norm over a row of
    three), ``np.maximum`` with NaN winning, ``r ** 2`` and ``noise ** 2`` as one product
    (every kernel that makes these terms calls it: kernels.rays' sums and box terms too)."""
    r = _maximum(np.sqrt(x * x + y * y + z * z), 1e-12)
    sig = _maximum(sigma, 1e-12) / (r * r)
    return x / r, y / r, z / r, 1.0 / r, 1.0 / (sig * sig)


@njit(cache=True, nogil=True)
def ray_terms_of(points, sigma):
    """:func:`rangeseg_o3d.ray_planes.ray_terms` of float64 ``points`` (N, 3) and ``sigma`` (N,)
    in one pass, the same bits: ``(rays, inverse, weight)`` (numpy's form costs eight passes
    and their temporaries, ~30 us on a face of a thousand pixels)."""
    n = points.shape[0]
    rays = np.empty((n, 3))
    inverse = np.empty(n)
    weight = np.empty(n)
    for i in range(n):
        rays[i, 0], rays[i, 1], rays[i, 2], inverse[i], weight[i] = _ray_term(points[i, 0], points[i, 1],
                                                                              points[i, 2], sigma[i])
    return rays, inverse, weight


@njit(cache=True, nogil=True)
def refit_terms(xyz, noise, flat, held, face, own, source, k_sigma, floor):
    """The sums of a face's plane fitted along its rays again (the refit of
    :func:`rangeseg_o3d.off_model._refit_apart`, less its solve): over the pixels of ``held``
    (flat, increasing) that face ``face`` of the flat labels ``flat`` holds, those whose rays
    meet its plane row ``own`` (``normal / d``) and the plane row ``source`` of the plane it
    was found beside more than ``k_sigma`` range-noise sigmas (``noise``) apart; all of them
    when fewer than ``max(floor, 3)`` are, or when ``source`` is NaN (no plane). Returns
    ``(outer, first, pixels)``: ``sum w u u^T`` (3 x 3), ``sum w q u`` and the flat pixels
    summed, in the terms of :func:`rangeseg_o3d.ray_planes.ray_terms` (unit ray ``u``, inverse
    range ``q``, weight ``w = range**4 / sigma**2``). Each term and each sum is numpy's, in its
    order (a point's norm summed over x, y, z; the sums over the points in their order): the
    same bits as ``ray_moments`` of ``ray_terms``. Only the choice of the pixels apart takes
    its dot products in its own order, a decision the last bit moves only at its threshold."""
    m = 0
    for i in range(held.size):
        if flat[held[i]] == face:
            m += 1
    mine = np.empty(m, np.int64)
    m = 0
    for i in range(held.size):
        if flat[held[i]] == face:
            mine[m] = held[i]
            m += 1
    rays = np.empty((m, 3))
    inverse = np.empty(m)
    weight = np.empty(m)
    apart = np.zeros(m, np.bool_)
    n_apart = 0
    for i in range(m):
        p = mine[i]
        rays[i, 0], rays[i, 1], rays[i, 2], inverse[i], weight[i] = _ray_term(xyz[p, 0], xyz[p, 1], xyz[p, 2],
                                                                              noise[p])
        if not np.isnan(source[0]):
            gap = abs((rays[i, 0] * own[0] + rays[i, 1] * own[1] + rays[i, 2] * own[2])
                      - (rays[i, 0] * source[0] + rays[i, 1] * source[1] + rays[i, 2] * source[2]))
            apart[i] = gap * np.sqrt(weight[i]) > k_sigma
            if apart[i]:
                n_apart += 1
    use_apart = n_apart >= max(floor, 3)
    outer = np.zeros((3, 3))
    first = np.zeros(3)
    pixels = np.empty(n_apart if use_apart else m, np.int64)
    n = 0
    for i in range(m):
        if use_apart and not apart[i]:
            continue
        pixels[n] = mine[i]
        n += 1
        wi = weight[i]
        _add_ray_terms(outer, first, wi, wi * inverse[i], rays[i, 0], rays[i, 1], rays[i, 2])
    return outer, first, pixels
