"""Compiled passes over the leftover strips' pixels alone (not the grid): each strip's
distance statistics against its own plane and against the models of the regions it touches."""

from __future__ import annotations

import numpy as np
from .jit import njit  # numba.njit, with this package's cache locator installed

from .inline import _incidence, _signed_distance
from .kinds import NONE

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("inline.py", "kinds.py")

#: The most regions one strip may touch that are tried (a strip two or three pixels wide
#: between two faces touches two or three; more are ignored).
MAX_TOUCHING = 16


@njit(cache=True, nogil=True)
def strip_fit_stats(xyz, sigma, pixels, lo, hi, kinds, params, rms, k_sigma):
    """Per row ``s``: the flat pixels ``pixels[lo[s]:hi[s]]`` (a strip's) under the model row
    ``s`` of ``(kinds, params, rms)``: ``(counts, squares, noise_squares, within)``, its
    pixels with a finite distance, their sum of squared distances, the sum of squared
    distance noises (range noise ``sigma`` times the incidence cosine, at least the model's
    rms) and how many lie within ``k_sigma`` of that noise."""
    n = lo.shape[0]
    counts = np.zeros(n, np.int64)
    squares = np.zeros(n)
    noise_squares = np.zeros(n)
    within = np.zeros(n, np.int64)
    for s in range(n):
        kind = kinds[s]
        if kind == NONE:
            continue
        prm = params[s]
        for m in range(lo[s], hi[s]):
            i = pixels[m]
            x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            dist = _signed_distance(kind, prm, x, y, z)
            if not np.isfinite(dist):
                continue
            noise = max(sigma[i] * _incidence(kind, prm, x, y, z), rms[s])
            counts[s] += 1
            squares[s] += dist * dist
            noise_squares[s] += noise * noise
            if abs(dist) <= k_sigma * noise:
                within[s] += 1
    return counts, squares, noise_squares, within


@njit(cache=True, nogil=True)
def strip_touching(flat, h, w, pixels, starts, kinds):
    """``(strip, label)`` pairs: each region with a model (``kinds[label]`` not NONE) one of
    a strip's pixels has as a 4-neighbour (at most ``MAX_TOUCHING`` per strip), strips in
    order."""
    n = starts.shape[0] - 1
    out_strip = np.empty(n * MAX_TOUCHING, np.int64)
    out_label = np.empty(n * MAX_TOUCHING, np.int64)
    found = np.empty(MAX_TOUCHING, np.int64)
    m_out = 0
    for s in range(n):
        n_found = 0
        for m in range(starts[s], starts[s + 1]):
            i = pixels[m]
            r, c = i // w, i % w
            for step in range(4):
                rr, cc = r, c
                if step == 0:
                    rr -= 1
                elif step == 1:
                    rr += 1
                elif step == 2:
                    cc -= 1
                else:
                    cc += 1
                if rr < 0 or rr >= h or cc < 0 or cc >= w:
                    continue
                k = flat[rr * w + cc]
                if k <= 0 or k >= kinds.shape[0] or kinds[k] == NONE:
                    continue
                seen = False
                for f in range(n_found):
                    if found[f] == k:
                        seen = True
                        break
                if not seen and n_found < MAX_TOUCHING:
                    found[n_found] = k
                    n_found += 1
        for f in range(n_found):
            out_strip[m_out] = s
            out_label[m_out] = found[f]
            m_out += 1
    return out_strip[:m_out], out_label[:m_out]


@njit(cache=True, nogil=True)
def grow_faces(xyz, flat, h, w, kinds, params, rms, sigma, first, boxes, rim, claim, k_sigma, trim_sigmas):
    """Each face ``first + j`` of the flat labels ``flat`` (an (h, w) grid; in place), within
    its box ``boxes[j] = (row0, row1, col0, col1)`` (half-open) alone: ``rim`` rings of free
    pixels (finite points) its model explains within ``k_sigma`` of ``max(sigma, rms)``, then
    ``claim`` rings of other regions' pixels (not faces) it explains so and nearer, in those
    units, than their own model; of what it took, the pixels beyond ``trim_sigmas`` of their
    distance noise (``sigma`` times the incidence cosine, at least its rms) go back to their
    labels before. Each ring joins the pixels 4-adjacent to the face as the last ring left it.
    Returns the flat pixels the faces took (kept or given back)."""
    total = 0
    for j in range(boxes.shape[0]):
        total += max(boxes[j, 1] - boxes[j, 0], 0) * max(boxes[j, 3] - boxes[j, 2], 0)
    taken = np.empty(total, np.int64)
    n_taken = 0
    for j in range(boxes.shape[0]):
        k = first + j
        r0, r1 = max(boxes[j, 0], 0), min(boxes[j, 1], h)
        c0, c1 = max(boxes[j, 2], 0), min(boxes[j, 3], w)
        if r1 <= r0 or c1 <= c0:
            continue
        bw = c1 - c0
        before = np.empty((r1 - r0) * bw, np.int32)
        for r in range(r0, r1):
            for c in range(c0, c1):
                before[(r - r0) * bw + c - c0] = flat[r * w + c]
        ring = np.empty((r1 - r0) * bw, np.int64)
        prm = params[k]
        for step in range(rim + claim):
            n_ring = 0
            for r in range(r0, r1):
                for c in range(c0, c1):
                    i = r * w + c
                    own = flat[i]
                    if own == k or (step < rim and own != 0) or (step >= rim and (own <= 0 or own >= first)):
                        continue
                    if not ((r > r0 and flat[i - w] == k) or (r + 1 < r1 and flat[i + w] == k)
                            or (c > c0 and flat[i - 1] == k) or (c + 1 < c1 and flat[i + 1] == k)):
                        continue
                    x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
                    dist = abs(_signed_distance(kinds[k], prm, x, y, z)) / max(sigma[i], rms[k])
                    if not dist <= k_sigma:
                        continue
                    if step >= rim:
                        theirs = abs(_signed_distance(kinds[own], params[own], x, y, z)) / max(sigma[i], rms[own])
                        if not dist < theirs:
                            continue
                    ring[n_ring] = i
                    n_ring += 1
            for m in range(n_ring):
                flat[ring[m]] = k
        for r in range(r0, r1):
            for c in range(c0, c1):
                i = r * w + c
                old = before[(r - r0) * bw + c - c0]
                if flat[i] != k or old == k:
                    continue
                taken[n_taken] = i
                n_taken += 1
                x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
                noise = max(sigma[i] * _incidence(kinds[k], prm, x, y, z), rms[k])
                if abs(_signed_distance(kinds[k], prm, x, y, z)) > trim_sigmas * noise:
                    flat[i] = old
    return taken[:n_taken]
