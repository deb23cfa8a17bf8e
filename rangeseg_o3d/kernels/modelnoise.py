"""Compiled passes for the refinement's tests of models against the noise of their pixels'
distances (:meth:`rangeseg_o3d.refinement.context.Context.plane_along_rays`,
:meth:`~rangeseg_o3d.refinement.context.Context.within_distance_noise` and the pretest of
:func:`rangeseg_o3d.refinement.merge.merge_into_curved`).

The numpy form gathers the pixels' points, their rays, the incidence cosines, the noise and
the distances as six arrays per call; the full-resolution recovery asks it a few dozen
times per frame, 0.1-0.3 ms each. Each pass here reads the pixels once and also returns the
largest magnitude of the terms it added, so that the caller can tell where its answer, whose
rounding differs from numpy's, could differ from numpy's (there it asks numpy).
"""

from __future__ import annotations

import numpy as np

from .jit import njit  # numba.njit, with this package's cache locator installed

from .kinds import CYLINDER, PLANE, SPHERE

#: Files whose constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("kinds.py",)

__all__ = ["plane_noise_sums", "plane_noise_near", "plane_distances_noise", "pieces_near_models"]


@njit(cache=True, nogil=True, inline="always")
def _plane_distance_noise(x, y, z, s, nx, ny, nz, d):
    # (signed distance, its noise) of the point (x, y, z) of range noise ``s`` to the plane
    # ``n . p = d``: the noise is the range noise times the incidence cosine, the ray
    # ``p / max(|p|, 1e-12)`` dotted with the normal, as fitting.robust.distance_noise has it
    norm = max(np.sqrt(x * x + y * y + z * z), 1e-12)
    return x * nx + y * ny + z * nz - d, s * abs(x / norm * nx + y / norm * ny + z / norm * nz)


@njit(cache=True, nogil=True)
def plane_noise_sums(xyz, sigma, idx, normal, d):
    """``(squares, noise_squares, scale, sigma_max)`` over the flat pixels ``idx`` (rows of
    ``xyz`` and ``sigma``): the sum of their squared distances to the plane ``normal . p = d``,
    the sum of the squares of each distance's noise (the range noise ``sigma`` times the
    incidence cosine, as :func:`rangeseg_o3d.fitting.robust.distance_noise` computes it for a
    plane: the ray ``p / max(|p|, 1e-12)`` dotted with the normal), the largest
    ``|x nx| + |y ny| + |z nz| + |d|`` (what a distance's rounding is relative to) and the
    largest ``sigma``."""
    nx, ny, nz = normal[0], normal[1], normal[2]
    squares, noise_squares, scale, sigma_max = 0.0, 0.0, abs(d), 0.0
    for t in range(idx.shape[0]):
        i = idx[t]
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        distance, noise = _plane_distance_noise(x, y, z, sigma[i], nx, ny, nz, d)
        squares += distance * distance
        noise_squares += noise * noise
        scale = max(scale, abs(x * nx) + abs(y * ny) + abs(z * nz) + abs(d))
        sigma_max = max(sigma_max, sigma[i])
    return squares, noise_squares, scale, sigma_max


@njit(cache=True, nogil=True)
def plane_noise_near(xyz, sigma, idx, normal, d, k_sigma, relative, absolute):
    """``(near, unsure)``: per flat pixel of ``idx``, whether its distance to the plane
    ``normal . p = d`` is within ``k_sigma`` times its noise (:func:`plane_noise_sums`'), and
    whether any pixel's two sides of that test lie closer than ``relative`` of the bound plus
    ``absolute`` times the magnitude of its terms (``|x nx| + |y ny| + |z nz| + |d|`` and
    ``k_sigma sigma``): there another rounding could answer the other way."""
    nx, ny, nz = normal[0], normal[1], normal[2]
    n = idx.shape[0]
    near = np.empty(n, np.bool_)
    unsure = False
    for t in range(n):
        i = idx[t]
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        distance, noise = _plane_distance_noise(x, y, z, sigma[i], nx, ny, nz, d)
        bound = k_sigma * noise
        distance = abs(distance)
        near[t] = distance <= bound
        terms = abs(x * nx) + abs(y * ny) + abs(z * nz) + abs(d) + k_sigma * abs(sigma[i])
        if not abs(distance - bound) > relative * bound + absolute * terms:  # (also a NaN)
            unsure = True
    return near, unsure


@njit(cache=True, nogil=True)
def plane_distances_noise(xyz, sigma, idx, normal, d):
    """``(distances, noise)`` of the flat pixels ``idx`` (rows of ``xyz`` and ``sigma``): each
    one's signed distance to the plane ``normal . p = d`` and that distance's noise
    (:func:`plane_noise_sums`' terms, pixel by pixel), in one pass without the gathered points,
    rays and cosines of numpy's ``Plane.distances`` and ``distance_noise`` (other rounding: a
    few units of the last place)."""
    nx, ny, nz = normal[0], normal[1], normal[2]
    n = idx.shape[0]
    distances, noise = np.empty(n), np.empty(n)
    for t in range(n):
        i = idx[t]
        distances[t], noise[t] = _plane_distance_noise(xyz[i, 0], xyz[i, 1], xyz[i, 2], sigma[i], nx, ny, nz, d)
    return distances, noise


@njit(cache=True, nogil=True)
def _median_of(values):
    # numpy's median of a non-empty 1-D array without NaN: the middle value, or the two middle
    # ones' sum over 2 (a partition, not a sort: a piece can hold tens of thousands of pixels)
    half = values.shape[0] // 2
    upper = np.partition(values, half)[half]
    if values.shape[0] % 2:
        return upper
    lower = np.max(np.partition(values, half - 1)[:half])
    return (lower + upper) / 2.0


@njit(cache=True, nogil=True)
def _absolute_distance(kind, prm, x, y, z):
    # |distance| of (x, y, z) from the model, in the operations of the Python models'
    # ``distances`` (a cylinder's radial part as the point less its part along the axis)
    if kind == PLANE:
        return abs(x * prm[0] + y * prm[1] + z * prm[2] - prm[3])
    if kind == SPHERE:
        dx, dy, dz = x - prm[0], y - prm[1], z - prm[2]
        return abs(np.sqrt(dx * dx + dy * dy + dz * dz) - prm[3])
    if kind == CYLINDER:
        rx, ry, rz = x - prm[3], y - prm[4], z - prm[5]
        along = rx * prm[0] + ry * prm[1] + rz * prm[2]
        ax, ay, az = rx - along * prm[0], ry - along * prm[1], rz - along * prm[2]
        return abs(np.sqrt(ax * ax + ay * ay + az * az) - prm[6])
    return np.inf


@njit(cache=True, nogil=True)
def pieces_near_models(xyz, sigma, pixels, starts, kinds, params, k_sigma, relative, absolute):
    """Per piece ``j`` (its flat pixels ``pixels[starts[j]:starts[j + 1]]``, rows of ``xyz``
    and ``sigma``; a model of :mod:`.kinds` ``kinds[j]``, ``params[j]``): 1 when the median of
    the pixels' distances to the model is within ``k_sigma`` times the median of their
    ``sigma``, 0 when over, -1 where the two lie within ``relative`` of that bound plus
    ``absolute`` times the magnitude of the terms (the points' and the model's parameters'),
    or either is NaN, or the piece is empty: there another rounding could answer otherwise."""
    m = starts.shape[0] - 1
    out = np.empty(m, np.int8)
    for j in range(m):
        a, b = starts[j], starts[j + 1]
        if b <= a:
            out[j] = -1
            continue
        distances, noise = np.empty(b - a), np.empty(b - a)
        terms = 0.0
        for p in range(params.shape[1]):
            terms += abs(params[j, p])
        largest = 0.0
        for t in range(b - a):
            i = pixels[a + t]
            x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            distances[t] = _absolute_distance(kinds[j], params[j], x, y, z)
            noise[t] = sigma[i]
            largest = max(largest, abs(x) + abs(y) + abs(z))
        out[j] = near_verdict(distances, noise, k_sigma, relative, absolute * (largest + terms))
    return out


@njit(cache=True, nogil=True)
def near_verdict(distances, noise, k_sigma, relative, absolute):
    """1 when the median of ``distances`` (non-empty) is within ``k_sigma`` times the median
    of ``noise``, 0 when over, -1 where the two lie within ``relative`` of that bound plus
    ``absolute`` (the rounding the caller's terms allow), or either is NaN."""
    median_distance, bound = _median_of(distances), k_sigma * _median_of(noise)
    slack = relative * abs(bound) + absolute
    if median_distance - bound > slack:
        return 0
    if bound - median_distance > slack:
        return 1
    return -1  # (a NaN too)
