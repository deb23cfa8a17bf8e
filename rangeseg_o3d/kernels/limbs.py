"""Compiled ring claim of a cylinder's or sphere's limbs (and a plane's far rows) seen near grazing
(:func:`rangeseg_o3d.refinement.recover.claim_grazing_limbs`).

The numpy form builds masks per claiming region and ring and gathers each ring's points, rays,
normals and distances as arrays: a few dozen small-array calls per region, 0.2-0.4 ms an
LMS200 scan. Here one pass per ring visits only the free pixels beside a claiming region (the
first ring) or beside the pixels the last ring added, and tests each against its neighbours'
models in the caller's order. It also reports whether any test lay within the rounding of its
bound, where numpy, whose rounding differs, could answer the other way (the caller then asks
numpy).
"""

from __future__ import annotations

import numpy as np

from .jit import njit  # numba.njit, with this package's cache locator installed

from .inline import _neighbour
from .kinds import CYLINDER, PLANE, SPHERE

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("inline.py", "kinds.py")

__all__ = ["claim_limbs"]


@njit(cache=True, nogil=True)
def _limb_test(kind, prm, x, y, z, ux, uy, uz, bound_sigma, relative):
    # (joins, unsure) of a point (x, y, z) seen along the unit ray (ux, uy, uz) for a sphere or
    # cylinder row ``prm``: |distance| <= bound_sigma x |cos(normal, ray)|, the normal the unit
    # radial vector at the point (zero on a cylinder's axis or a sphere's centre), in numpy's
    # order of operations (primitives.Sphere/Cylinder .distances, .normals); ``unsure`` where
    # the two sides lie within ``relative`` times the magnitude of their terms of each other
    if kind == CYLINDER:
        dx, dy, dz = x - prm[3], y - prm[4], z - prm[5]
        along = dx * prm[0] + dy * prm[1] + dz * prm[2]
        nx, ny, nz = dx - along * prm[0], dy - along * prm[1], dz - along * prm[2]
        radius = prm[6]
    elif kind == SPHERE:
        dx, dy, dz = x - prm[0], y - prm[1], z - prm[2]
        nx, ny, nz = dx, dy, dz
        radius = prm[3]
    elif kind == PLANE:
        # (primitives.Plane.distances: points @ normal - d; the normal is the plane's own)
        distance = abs(x * prm[0] + y * prm[1] + z * prm[2] - prm[3])
        bound = bound_sigma * abs(prm[0] * ux + prm[1] * uy + prm[2] * uz)
        slack = relative * (abs(x) + abs(y) + abs(z) + abs(prm[3]) + bound)
        return distance <= bound, abs(distance - bound) <= slack
    else:
        return False, False
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    distance = abs(norm - radius)
    cosine = 0.0
    if norm > 0.0:
        cosine = abs((nx / norm) * ux + (ny / norm) * uy + (nz / norm) * uz)
    bound = bound_sigma * cosine
    slack = relative * (abs(dx) + abs(dy) + abs(dz) + abs(radius) + bound)
    # (a NaN fails the test and is not unsure: numpy's comparison fails it too)
    return distance <= bound, abs(distance - bound) <= slack


@njit(cache=True, nogil=True)
def claim_limbs(labels, valid, xyz, sigma, origins, order, kinds, params, k_sigma, rings, relative):
    """``(labels, unsure)``: the ``(H, W)`` ``labels`` (a copy) with the free (0) ``valid``
    pixels beside a region that its model explains within the noise of their
    distances joined to it, ring by ring, at most ``rings`` rings.

    ``order`` holds the claiming regions' labels in the order they claim (a free pixel beside
    two takes the first that explains it), ``kinds[t]`` / ``params[t]`` the model of
    ``order[t]`` as a model-table row (SPHERE, CYLINDER or PLANE). A pixel ``i`` (flat) joins region
    ``k`` when ``|distance| <= k_sigma * sigma[i] * |cos|``, the cosine between the model's
    unit normal at the point and the unit ray from ``origins[row]`` to the point (``xyz[i]``).
    A ring tests the free pixels 4-adjacent to a region as it stood when the ring began;
    the pixels it adds join at its end. Rings do not wrap across the grid's sides. ``unsure``
    is True where some test lay within ``relative`` times its terms of its bound."""
    h, w = labels.shape
    out = labels.copy()
    flat = out.reshape(-1)
    free_ok = valid.reshape(-1)
    top = 0
    for t in range(order.shape[0]):
        top = max(top, order[t])
    # rank of each claiming label in ``order`` (-1 for any other label)
    rank = np.full(top + 1, -1, np.int64)
    for t in range(order.shape[0] - 1, -1, -1):
        rank[order[t]] = t
    n = h * w
    queued = np.zeros(n, np.int32)  # the ring in which a pixel was last queued
    cand = np.empty(n, np.int64)
    took = np.empty(n, np.int64)  # the label each candidate takes (0 none)
    added = np.empty(n, np.int64)  # the pixels the last ring added
    n_added = 0
    near = np.empty(4, np.int64)  # the ranks of the claiming regions beside a candidate
    unsure = False
    for ring in range(1, rings + 1):
        n_cand = 0
        if ring == 1:
            for i in range(n):
                if flat[i] != 0 or not free_ok[i]:
                    continue
                for step in range(4):
                    j = _neighbour(i, step, h, w)
                    if j >= 0 and 0 < flat[j] <= top and rank[flat[j]] >= 0:
                        cand[n_cand] = i
                        n_cand += 1
                        break
        else:
            # a free pixel beside only the pixels a region held before the last ring was
            # tested by it then (and is tested the same now): only the last ring's
            # additions bring new candidates
            for t in range(n_added):
                i = added[t]
                for step in range(4):
                    j = _neighbour(i, step, h, w)
                    if j >= 0 and flat[j] == 0 and free_ok[j] and queued[j] != ring:
                        queued[j] = ring
                        cand[n_cand] = j
                        n_cand += 1
        if n_cand == 0:
            break
        # decide every candidate on the labels as the ring began, then write
        for t in range(n_cand):
            i = cand[t]
            r = i // w
            # the claiming regions beside the pixel, by rank (at most four)
            m = 0
            for step in range(4):
                j = _neighbour(i, step, h, w)
                if j < 0:
                    continue
                k = flat[j]
                if k <= 0 or k > top or rank[k] < 0:
                    continue
                q = rank[k]
                seen = False
                for s in range(m):
                    if near[s] == q:
                        seen = True
                if not seen:
                    s = m
                    while s > 0 and near[s - 1] > q:
                        near[s] = near[s - 1]
                        s -= 1
                    near[s] = q
                    m += 1
            took[t] = 0
            if m == 0:
                continue
            x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            rx, ry, rz = x - origins[r, 0], y - origins[r, 1], z - origins[r, 2]
            length = max(np.sqrt(rx * rx + ry * ry + rz * rz), 1e-12)
            ux, uy, uz = rx / length, ry / length, rz / length
            bound_sigma = k_sigma * sigma[i]
            for s in range(m):
                q = near[s]
                joins, close = _limb_test(kinds[q], params[q], x, y, z, ux, uy, uz, bound_sigma, relative)
                if close:
                    unsure = True
                if joins:
                    took[t] = order[q]
                    break
        n_added = 0
        for t in range(n_cand):
            if took[t] != 0:
                flat[cand[t]] = took[t]
                added[n_added] = cand[t]
                n_added += 1
        if n_added == 0:
            break
    return out, unsure
