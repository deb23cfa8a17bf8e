"""Compiled ring growth of faces whose planes were fitted along the rays (the off-model faces of
:func:`rangeseg_o3d.off_model.faces_along_rays`): a numpy pass per ring cost about half a
millisecond however few pixels it looked at, and most faces grown so are undone."""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed


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
