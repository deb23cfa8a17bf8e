"""Compiled passes for the refinement's tests of models against the noise of their pixels'
distances (:meth:`rangeseg_o3d.refinement.context.Context.plane_along_rays` and
:meth:`~rangeseg_o3d.refinement.context.Context.within_distance_noise`).

The numpy form gathers the pixels' points, their rays, the incidence cosines, the noise and
the distances as six arrays per call; the full-resolution recovery asks it a few dozen
times per frame, 0.1-0.3 ms each. Each pass here reads the pixels once and also returns the
largest magnitude of the terms it added, so that the caller can tell where its answer, whose
rounding differs from numpy's, could differ from numpy's (there it asks numpy).
"""

from __future__ import annotations

import numpy as np

from .jit import njit  # numba.njit, with this package's cache locator installed

__all__ = ["plane_noise_sums", "plane_noise_near"]


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
        norm = max(np.sqrt(x * x + y * y + z * z), 1e-12)
        noise = sigma[i] * abs(x / norm * nx + y / norm * ny + z / norm * nz)
        distance = x * nx + y * ny + z * nz - d
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
        norm = max(np.sqrt(x * x + y * y + z * z), 1e-12)
        bound = k_sigma * (sigma[i] * abs(x / norm * nx + y / norm * ny + z / norm * nz))
        distance = abs(x * nx + y * ny + z * nz - d)
        near[t] = distance <= bound
        terms = abs(x * nx) + abs(y * ny) + abs(z * nz) + abs(d) + k_sigma * abs(sigma[i])
        if not abs(distance - bound) > relative * bound + absolute * terms:  # (also a NaN)
            unsure = True
    return near, unsure
