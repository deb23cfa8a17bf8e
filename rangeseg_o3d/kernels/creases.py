"""Compiled pass for :func:`rangeseg_o3d.fullres.settle_creases`: the plane pixels near a
border between two plane regions that the planes' rays give to the other face.

One pass finds the pixels on such borders, a second marks the pixels within ``reach - 1``
4-steps of them, and only those are judged (a frame's plane borders hold a tenth of its
pixels or fewer: the numpy version, which judged them offset by offset, cost 40-230 ms a
real 640 x 480 frame)."""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

__all__ = ["crease_moves", "cap_moves"]


@njit(cache=True, nogil=True)
def _centroids(sums):
    # each label's centroid from its rows of (sum x, sum y, sum z, count); a label with no
    # point keeps the origin
    n = sums.shape[0]
    centroids = np.zeros((n, 3))
    for k in range(n):
        count = max(sums[k, 3], 1.0)
        centroids[k, 0], centroids[k, 1], centroids[k, 2] = sums[k, 0] / count, sums[k, 1] / count, sums[k, 2] / count
    return centroids


@njit(cache=True, nogil=True)
def _plane_borders(xyz, labels, is_plane, sums):
    """An (H, W) mask of the pixels of a plane region 4-adjacent to another plane region; adds
    each plane pixel's point and a count to ``sums[label]`` (x, y, z, count)."""
    h, w = labels.shape
    n = is_plane.shape[0]
    border = np.zeros((h, w), np.bool_)
    # a region's pixels come in runs along a row: its sums are carried in registers along the
    # run and written back when the label changes (the same additions in the same order, the
    # same bits; adding into sums[label] pixel by pixel chained each add through memory, a
    # fifth of the pass on a stereo scan's 1280 x 720)
    run = -1
    sx = sy = sz = count = 0.0
    for r in range(h):
        for c in range(w):
            a = labels[r, c]
            if a <= 0 or a >= n or not is_plane[a]:
                continue
            if a != run:
                if run >= 0:
                    sums[run, 0], sums[run, 1], sums[run, 2], sums[run, 3] = sx, sy, sz, count
                run = a
                sx, sy, sz, count = sums[a, 0], sums[a, 1], sums[a, 2], sums[a, 3]
            i = r * w + c
            sx += xyz[i, 0]
            sy += xyz[i, 1]
            sz += xyz[i, 2]
            count += 1.0
            if c + 1 < w:
                b = labels[r, c + 1]
                if b != a and 0 < b < n and is_plane[b]:
                    border[r, c] = border[r, c + 1] = True
            if r + 1 < h:
                b = labels[r + 1, c]
                if b != a and 0 < b < n and is_plane[b]:
                    border[r, c] = border[r + 1, c] = True
    if run >= 0:
        sums[run, 0], sums[run, 1], sums[run, 2], sums[run, 3] = sx, sy, sz, count
    return border


@njit(cache=True, nogil=True)
def _within_reach(seeds, spread):
    """Flat indices, ascending, of the pixels of an (H, W) image within ``spread`` 4-steps of
    a pixel set in the (H, W) bool mask ``seeds`` (none when no seed is set): the pixels
    :func:`crease_moves` and :func:`cap_moves` judge, ``spread`` being ``reach - 1``."""
    h, w = seeds.shape
    size = h * w
    flat = seeds.reshape(size)
    # both scans read eight pixels a word and skip the empty words (a frame's borders and the
    # pixels near them hold a tenth of it or fewer), and a run of seeds along a row marks its
    # diamonds' union row by row, one span each (a seed and its neighbours, as cap_moves
    # sets them, marked diamond by diamond cost 4 % more than its own pass)
    seed_words = flat[:size // 8 * 8].view(np.uint64)
    near = np.zeros(size // 8 * 8 + 8, np.uint8)  # the padding past the image is never set
    i = 0
    while i < size:
        if i % 8 == 0 and i // 8 < seed_words.size and seed_words[i // 8] == 0:
            i += 8
            continue
        if not flat[i]:
            i += 1
            continue
        r0, c0 = i // w, i % w
        c1 = c0  # the run's last seed
        while c1 + 1 < w and flat[i + c1 + 1 - c0]:
            c1 += 1
        for dr in range(-spread, spread + 1):  # the diamonds of spread 4-steps, clipped
            r = r0 + dr
            if r < 0 or r >= h:
                continue
            left = spread - abs(dr)
            for c in range(max(c0 - left, 0), min(c1 + left + 1, w)):
                near[r * w + c] = 1
        i += c1 - c0 + 1
    found = np.empty(size, np.int64)  # room for every pixel; only those listed are written
    k = 0
    near_words = near.view(np.uint64)
    for j in range(near_words.size):
        if near_words[j] == 0:
            continue
        for i in range(8 * j, 8 * j + 8):
            if near[i]:
                found[k] = i
                k += 1
    return found[:k]


# inline: read per pixel (and per step around it) by crease_moves and label_pixels; as a
# call of its own, each use paid a call with two arrays' worth of arguments (same operations)
@njit(cache=True, nogil=True, inline="always")
def _crease_pair(a, b, normals, offsets, centroids, max_cos):
    """1 when planes ``a`` and ``b`` are turned by more than ``acos(max_cos)`` and meet at a
    concave crease (each region's centroid on the sensor's side of the other's plane), -1 at a
    convex one (each behind), 0 otherwise."""
    na0, na1, na2 = normals[a, 0], normals[a, 1], normals[a, 2]
    nb0, nb1, nb2 = normals[b, 0], normals[b, 1], normals[b, 2]
    if not abs(na0 * nb0 + na1 * nb1 + na2 * nb2) < max_cos:
        return 0
    front_a = na0 * centroids[b, 0] + na1 * centroids[b, 1] + na2 * centroids[b, 2] - offsets[a]
    front_b = nb0 * centroids[a, 0] + nb1 * centroids[a, 1] + nb2 * centroids[a, 2] - offsets[b]
    if front_a > 0 and front_b > 0:
        return 1
    if front_a < 0 and front_b < 0:
        return -1
    return 0


# inline: read per pixel (and per step around it) by crease_moves and label_pixels; as a
# call of its own, each use paid a call with two arrays' worth of arguments (same operations)
@njit(cache=True, nogil=True, inline="always")
def _ray_meets_b(rx, ry, rz, a, b, concave, normals, offsets, least_cos):
    """Whether the unit ray ``r`` meets the face of plane ``b`` at the crease of planes ``a`` and
    ``b``: it meets each plane at least ``asin(least_cos)`` from grazing and in front of the
    sensor, ``b`` first at a concave crease (last at a convex one). Also read by
    :func:`rangeseg_o3d.kernels.label_pixels`."""
    ua = rx * normals[a, 0] + ry * normals[a, 1] + rz * normals[a, 2]
    ub = rx * normals[b, 0] + ry * normals[b, 1] + rz * normals[b, 2]
    if not (abs(ua) >= least_cos and abs(ub) >= least_cos):
        return False
    ta, tb = offsets[a] / ua, offsets[b] / ub  # where each plane meets the ray
    if not (ta > 0 and tb > 0):
        return False
    return (tb < ta) if concave else (tb > ta)


# inline: read per pixel (and per step around it) by crease_moves and label_pixels; as a
# call of its own, each use paid a call with two arrays' worth of arguments (same operations)
@njit(cache=True, nogil=True, inline="always")
def _on_b_side(rx, ry, rz, x, y, z, a, b, concave, noise, normals, offsets, rms, k_sigma, least_cos):
    """Whether the pixel at ``(x, y, z)`` (unit ray ``r``) of plane ``a`` lies on plane ``b``'s
    side of their crease: the ray meets ``b`` there (:func:`_ray_meets_b`) and both
    planes explain the pixel within ``noise`` (``k_sigma`` times its range noise) or ``k_sigma``
    times their rms."""
    if not _ray_meets_b(rx, ry, rz, a, b, concave, normals, offsets, least_cos):
        return False
    return (abs(x * normals[a, 0] + y * normals[a, 1] + z * normals[a, 2] - offsets[a]) <= max(noise, k_sigma * rms[a])
            and abs(x * normals[b, 0] + y * normals[b, 1] + z * normals[b, 2] - offsets[b]) <= max(noise, k_sigma * rms[b]))


# inline: read per pixel and step by crease_moves, as _on_b_side is
@njit(cache=True, nogil=True, inline="always")
def _on_b_side_along_rays(rx, ry, rz, dist, a, b, concave, noise, normals, offsets, rms, k_sigma, least_cos):
    """:func:`_on_b_side` with both planes judged along the ray: the ray meets ``b`` at the
    crease (:func:`_ray_meets_b`) and meets each plane within ``noise`` (``k_sigma`` times the
    pixel's range noise) of its range ``dist``, or within ``k_sigma`` times the plane's rms
    over the ray's incidence cosine (the plane's spread along this ray). A range error moves
    a return along its ray: a plane seen near grazing lies within a small distance of returns
    many range sigmas off it along their rays (a floor's pixels beside a far box face seen at
    80 degrees: 13 range sigmas, 2.2 in distance)."""
    if not _ray_meets_b(rx, ry, rz, a, b, concave, normals, offsets, least_cos):
        return False
    ua = rx * normals[a, 0] + ry * normals[a, 1] + rz * normals[a, 2]
    ub = rx * normals[b, 0] + ry * normals[b, 1] + rz * normals[b, 2]
    ta, tb = offsets[a] / ua, offsets[b] / ub  # where each plane meets the ray
    return (abs(dist - ta) <= max(noise, k_sigma * rms[a] / abs(ua))
            and abs(dist - tb) <= max(noise, k_sigma * rms[b] / abs(ub)))


# inline: the judgement crease_moves makes per pixel and step (and its test's reference)
@njit(cache=True, nogil=True, inline="always")
def _judged_on_b_side(rx, ry, rz, x, y, z, dist, a, b, concave, noise, normals, offsets, rms, k_sigma, least_cos,
                      along_rays):
    """:func:`_on_b_side_along_rays` when ``along_rays``, else :func:`_on_b_side`."""
    if along_rays:
        return _on_b_side_along_rays(rx, ry, rz, dist, a, b, concave, noise, normals, offsets, rms, k_sigma,
                                     least_cos)
    return _on_b_side(rx, ry, rz, x, y, z, a, b, concave, noise, normals, offsets, rms, k_sigma, least_cos)


@njit(cache=True, nogil=True)
def crease_moves(xyz, labels, is_plane, normals, offsets, rms, sigma, k_sigma, max_cos, least_cos, steps, reach,
                 along_rays=False):
    """The labels after :func:`rangeseg_o3d.fullres.settle_creases`' moves, and the flat
    indices of the pixels that moved.

    ``labels`` (H, W) int32; ``xyz`` (H*W, 3) and ``sigma`` (H*W,) flat; ``is_plane``,
    ``normals``, ``offsets`` (each plane's sensor side positive) and ``rms`` indexed by
    label; ``steps`` (K, 2) the (row, column) steps within ``reach`` 4-steps, nearest
    first. A pixel of a plane region within ``reach - 1`` 4-steps of a pixel on a plane
    border moves to the plane region of the first step whose pixel holds one it lies on
    the side of (:func:`_crease_pair`, :func:`_on_b_side`; the regions' centroids from
    their pixels); decisions are taken on ``labels`` as they are. ``along_rays``: both planes
    are judged by their distances along the pixel's ray (:func:`_on_b_side_along_rays`), as a
    stereo camera's range noise lies.
    """
    h, w = labels.shape
    n = is_plane.shape[0]
    out = labels.copy()
    sums = np.zeros((n, 4))
    near = _within_reach(_plane_borders(xyz, labels, is_plane, sums), reach - 1)
    if near.size == 0:  # no plane border
        return out, np.empty(0, np.int64)
    centroids = _centroids(sums)
    moved = np.empty(h * w, np.int64)
    tried = np.empty(steps.shape[0], labels.dtype)  # the regions a pixel refused (see below)
    # a pixel whose steps all stay inside the grid reads them at flat offsets, unchecked (the
    # same steps in the same order: bounds checks and 2-D indexing per step were most of the
    # loop on a stereo scan, 40 000 pixels judged of 24 steps each)
    flat = labels.reshape(h * w)
    offsets_flat = np.empty(steps.shape[0], np.int64)
    span = 0
    for s in range(steps.shape[0]):
        offsets_flat[s] = steps[s, 0] * w + steps[s, 1]
        span = max(span, abs(steps[s, 0]), abs(steps[s, 1]))
    count = 0
    for i in near:
        r0, c0 = i // w, i % w
        a = flat[i]
        if a <= 0 or a >= n or not is_plane[a]:
            continue
        inside = span <= r0 < h - span and span <= c0 < w - span
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        dist = np.sqrt(x * x + y * y + z * z)
        if not dist > 0.0:  # a point at the sensor (or NaN) has no ray; numba raises on / 0
            continue
        rx, ry, rz = x / dist, y / dist, z / dist
        noise = k_sigma * sigma[i]
        # a pixel's verdict on region b depends on the pixel and b alone, not on the step
        # that met b: the regions already refused here are skipped (the steps of one pixel
        # meet a few regions, most of them many times; the same moves as judging each step)
        refused = 0
        for s in range(steps.shape[0]):
            if inside:
                b = flat[i + offsets_flat[s]]
            else:
                r, c = r0 + steps[s, 0], c0 + steps[s, 1]
                if r < 0 or r >= h or c < 0 or c >= w:
                    continue
                b = labels[r, c]
            if b == a or b <= 0 or b >= n or not is_plane[b]:
                continue
            seen = False
            for j in range(refused):
                if tried[j] == b:
                    seen = True
                    break
            if seen:
                continue
            # judged afresh at each meeting (a few products): a table of the label pairs
            # would take n^2 bytes, 2.5 GB at 50 000 labels
            crease = _crease_pair(a, b, normals, offsets, centroids, max_cos)
            if crease != 0 and _judged_on_b_side(rx, ry, rz, x, y, z, dist, a, b, crease > 0, noise, normals,
                                                 offsets, rms, k_sigma, least_cos, along_rays):
                out[r0, c0] = b
                moved[count] = i
                count += 1
                break
            tried[refused] = b
            refused += 1
    return out, moved[:count]


@njit(cache=True, nogil=True, inline="always")
def _cylinder_entry(rx, ry, rz, axis, point, radius):
    """Where the unit ray ``r`` from the sensor enters the infinite cylinder (the nearer root),
    and the cosine between the ray and the surface's normal there; ``(-1, 0)`` when it misses."""
    ox, oy, oz = -point[0], -point[1], -point[2]
    ua = rx * axis[0] + ry * axis[1] + rz * axis[2]
    oa = ox * axis[0] + oy * axis[1] + oz * axis[2]
    px, py, pz = rx - ua * axis[0], ry - ua * axis[1], rz - ua * axis[2]  # the ray across the axis
    qx, qy, qz = ox - oa * axis[0], oy - oa * axis[1], oz - oa * axis[2]  # the sensor off the axis
    a = px * px + py * py + pz * pz
    b = 2.0 * (px * qx + py * qy + pz * qz)
    c = qx * qx + qy * qy + qz * qz - radius * radius
    disc = b * b - 4.0 * a * c
    if not (a > 0.0 and disc > 0.0):
        return -1.0, 0.0
    t = (-b - np.sqrt(disc)) / (2.0 * a)
    if not t > 0.0:
        return -1.0, 0.0
    # the surface's normal at the entry is the entry point's offset from the axis over the radius
    nx, ny, nz = t * px + qx, t * py + qy, t * pz + qz
    return t, abs(rx * nx + ry * ny + rz * nz) / radius


@njit(cache=True, nogil=True)
def cap_moves(xyz, labels, kind, normals, offsets, axes, points, radii, rms, sigma, k_sigma, least_cos, cap_cos,
              steps, reach, rounds):
    """The labels after :func:`rangeseg_o3d.fullres.settle_caps`' moves, and the flat indices
    of the pixels that moved (a pixel that moved twice is listed twice).

    ``labels`` (H, W) int32; ``xyz`` (H*W, 3) and ``sigma`` (H*W,) flat; ``kind`` by label
    (1 plane, 2 cylinder, 0 neither); ``normals``, ``offsets`` the planes' (sensor side
    positive), ``axes``, ``points``, ``radii`` the cylinders', ``rms`` each model's; ``steps``
    (K, 2) the (row, column) steps within ``reach`` 4-steps, nearest first. A plane and a
    cylinder form a cap when the plane faces along the axis (``|n . axis| >= cap_cos``), the
    plane region's centroid lies inside the cylinder and the cylinder region's behind the
    plane: the solid is their intersection, and a ray shows the surface it enters last. A
    pixel of either region within ``reach - 1`` 4-steps of a border pixel between the two
    (the first of a pair across it) or of that pixel's left, right and lower neighbours moves to
    the other when its ray enters the other's surface later, both models explain it within
    ``k_sigma`` times its range noise (or their rms) and the ray meets both at least
    ``asin(least_cos)`` from grazing. Up to ``rounds`` passes, each on the labels the one
    before left, until none moves.
    """
    h, w = labels.shape
    n = kind.shape[0]
    out = labels.copy()
    sums = np.zeros((n, 4))
    for i in range(h * w):
        a = labels[i // w, i % w]
        if 0 < a < n and kind[a] > 0:
            sums[a, 0] += xyz[i, 0]
            sums[a, 1] += xyz[i, 1]
            sums[a, 2] += xyz[i, 2]
            sums[a, 3] += 1.0
    centroids = _centroids(sums)
    moved = np.empty(0, np.int64)
    before = labels.copy()
    spread = reach - 1
    for _ in range(rounds):
        # the pixels on a plane-cylinder border, then those within spread 4-steps of them
        seeds = np.zeros((h, w), np.bool_)
        for r in range(h):
            for c in range(w):
                a = before[r, c]
                if a <= 0 or a >= n or kind[a] == 0:
                    continue
                edge = False
                if c + 1 < w:
                    b = before[r, c + 1]
                    edge = 0 < b < n and kind[b] > 0 and kind[b] != kind[a]
                if not edge and r + 1 < h:
                    b = before[r + 1, c]
                    edge = 0 < b < n and kind[b] > 0 and kind[b] != kind[a]
                if not edge:
                    continue
                # (r, c) and its right, lower and left neighbours: both pixels of the pair and
                # more (the pass has judged the pixels within reach 4-steps of (r, c) but the
                # one straight above, the spread-diamonds about these four; the same moves)
                seeds[r, c] = True
                if c + 1 < w:
                    seeds[r, c + 1] = True
                if r + 1 < h:
                    seeds[r + 1, c] = True
                if c > 0:
                    seeds[r, c - 1] = True
        near = _within_reach(seeds, spread)
        if near.size == 0:  # no plane-cylinder border
            break
        step_moved = np.empty(h * w, np.int64)
        count = 0
        for i in near:
            r0, c0 = i // w, i % w
            a = before[r0, c0]
            if a <= 0 or a >= n or kind[a] == 0:
                continue
            x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            dist = np.sqrt(x * x + y * y + z * z)
            if not dist > 0.0:
                continue
            rx, ry, rz = x / dist, y / dist, z / dist
            noise = k_sigma * sigma[i]
            for s in range(steps.shape[0]):
                r, c = r0 + steps[s, 0], c0 + steps[s, 1]
                if r < 0 or r >= h or c < 0 or c >= w:
                    continue
                b = before[r, c]
                if b <= 0 or b >= n or kind[b] == 0 or kind[b] == kind[a]:
                    continue
                p, q = (a, b) if kind[a] == 1 else (b, a)  # the plane, the cylinder
                if not abs(normals[p, 0] * axes[q, 0] + normals[p, 1] * axes[q, 1]
                           + normals[p, 2] * axes[q, 2]) >= cap_cos:
                    continue
                behind = (normals[p, 0] * centroids[q, 0] + normals[p, 1] * centroids[q, 1]
                          + normals[p, 2] * centroids[q, 2] - offsets[p])
                ex, ey, ez = centroids[p, 0] - points[q, 0], centroids[p, 1] - points[q, 1], centroids[p, 2] - points[q, 2]
                along = ex * axes[q, 0] + ey * axes[q, 1] + ez * axes[q, 2]
                off = np.sqrt(max(ex * ex + ey * ey + ez * ez - along * along, 0.0))
                if not (behind < 0.0 and off < radii[q]):
                    continue  # not a cap: no convex solid
                un = rx * normals[p, 0] + ry * normals[p, 1] + rz * normals[p, 2]
                if not abs(un) >= least_cos:
                    continue
                tp = offsets[p] / un
                tc, cc_ = _cylinder_entry(rx, ry, rz, axes[q], points[q], radii[q])
                if not (tp > 0.0 and tc > 0.0 and cc_ >= least_cos):
                    continue
                # both explain the pixel within the noise (the rays cannot tell otherwise)
                dp = abs(x * normals[p, 0] + y * normals[p, 1] + z * normals[p, 2] - offsets[p])
                ox, oy, oz = x - points[q, 0], y - points[q, 1], z - points[q, 2]
                oa = ox * axes[q, 0] + oy * axes[q, 1] + oz * axes[q, 2]
                dc = abs(np.sqrt(max(ox * ox + oy * oy + oz * oz - oa * oa, 0.0)) - radii[q])
                if not (dp <= max(noise, k_sigma * rms[p]) and dc <= max(noise, k_sigma * rms[q])):
                    continue
                # the solid's surface is where the ray enters it: the later of the two entries
                if (tp > tc) == (b == p):
                    out[r0, c0] = b
                    step_moved[count] = i
                    count += 1
                break  # the nearest other-kind neighbour decides
        if count == 0:
            break
        moved = np.concatenate((moved, step_moved[:count]))
        before = out.copy()
    return out, moved
