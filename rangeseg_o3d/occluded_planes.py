"""Pieces of one plane that something nearer cuts apart, joined across it.

A pipe (or a box) standing before a far wall or a box face cuts the face in two on the
sensor grid. The two pieces touch not, so no merge of touching regions joins them, and on a
stereo camera their tile models, each averaged over few far tiles, are turned from each other
by several degrees (seed 7 scan 3 of the sensor matrix: 9 degrees between two pieces of one
face), beyond any angle a merge allows. Along the rays, the noise's own direction, the plane
fitted to both pieces' pixels explains them as well as their own planes do, and every pixel on
the sensor grid between them is a nearer surface: the pieces are one face seen around an
occluder (:func:`join_across_occluders`).
"""

from __future__ import annotations

import numpy as np

from .fitting.primitives import Plane
from .fitting.region_fitter import region_indices
from .fullres import region_stats
from .kernels.linalg import CHI_SQUARE_SIGMAS
from .ray_planes import pixel_moments, ray_fits, ray_plane, ray_terms
from .refinement.context import TRIM_SIGMAS

__all__ = ["BRIDGE_SHARE", "MOMENT_PIXELS", "join_across_occluders"]

#: Pixels of a region (an even subsample, its sums scaled to the region's size) over which
#: :func:`join_across_occluders` sums the terms of its plane along the rays to choose the
#: pair to try (every pixel of a floor, a third of a stereo frame, cost most of the step); the
#: pair chosen is judged on all its pixels.
MOMENT_PIXELS = 16384

#: The least share of the pixels on the straight line between two pieces' centres (those of
#: neither piece, with a return) that must lie nearer than the pieces' joint plane by
#: TRIM_SIGMAS of their range noise along the rays, or be free pixels within it: the line's
#: few mixed pixels at the occluder's rims may lie either way.
BRIDGE_SHARE = 0.9


def join_across_occluders(cloud, labels: np.ndarray, fits: dict, stats, *, sigma: np.ndarray,
                          inlier_factor: float, correlation_px: int = 1):
    """Plane regions that touch not join when the plane fitted along the rays to both
    explains them as well as their own two planes do, within the noise (:func:`_one_plane`: an
    F-test over their independent returns, ``correlation_px`` squared pixels each, the noise's
    variance no larger than the model states), and what lies between them on the sensor grid
    is nearer than that plane (:func:`_occluded_between`).
    The pair of least chi-square growth per pixel joins first, under the larger region's label
    and the plane of the union; the sums are then taken again. Returns ``(labels, fits,
    stats)``, the regions that joined gone from ``fits`` and the regions changed measured
    again; the inputs when none joins.

    Not :func:`plane_faces._continued_plane`'s looser rule (growth under one per pixel) for
    touching pieces: across a gap one plane tilted between two parallel faces fits both, and
    faces one range sigma apart grow by 0.1 a pixel on a stereo camera. Two faces that only look
    coplanar (two box tops at one height) have the floor or a wall, farther than their plane,
    between them, and stay apart."""
    counts = stats.counts
    planes = [k for k, m in fits.items() if isinstance(m, Plane) and 0 < k < counts.size and m.d != 0]
    if len(planes) < 2:
        return labels, fits, stats
    xyz, noise = cloud.xyz.reshape(-1, 3), sigma.ravel()
    indices = region_indices(labels, only=planes)
    members = {k: idx for k, idx in indices.items() if idx.size > 0}
    moments = {k: _scaled_moments(xyz, noise, idx) for k, idx in members.items()}
    out = np.array(labels, dtype=np.int32, order="C")
    flat = out.reshape(-1)
    width = out.shape[1]
    window = max(int(correlation_px), 1) ** 2
    exact = {}  # every pixel's sums, of the regions a chosen pair held
    refused, changed, joined = set(), set(), set()
    while len(members) >= 2:
        pair = _best_pair(members, moments, refused, window)
        if pair is None:
            break
        a, b = pair
        # the subsample's sums chose the pair; every pixel's sums decide it (a subsample spreads
        # the large region's plane, and the growth the noise gives, by its step)
        for k in pair:
            if k not in exact:
                exact[k] = pixel_moments(xyz, noise, members[k])
        union = tuple(x + y for x, y in zip(exact[a], exact[b]))
        chi2, plane = ray_fits(union)
        apart = float(ray_fits(exact[a])[0][0] + ray_fits(exact[b])[0][0])
        plane = plane[0]
        if not (_one_plane(chi2, np.array([apart]), np.array([(members[a].size + members[b].size) / window]),
                           window)[0]
                and _occluded_between(xyz, noise, flat, width, members[a], members[b], (a, b), plane,
                                      cloud.valid.reshape(-1))):
            refused.add(pair)
            continue
        keep, gone = (a, b) if members[a].size >= members[b].size else (b, a)
        flat[members[gone]] = keep
        members[keep] = np.union1d(members[keep], members.pop(gone))
        moments[keep] = tuple(x + y for x, y in zip(moments[a], moments[b]))
        moments.pop(gone)
        exact[keep] = union
        exact.pop(gone)
        fits = dict(fits)
        fits[keep] = ray_plane(plane, xyz[members[keep]])
        fits.pop(gone)
        joined.add(gone)
        changed |= {keep, gone}
        refused = {p for p in refused if keep not in p}  # the union is a new region: asked again
    if not joined:
        return labels, fits, stats
    stats = region_stats(cloud.xyz, out, fits, sigma, inlier_factor, known=stats, stale=changed)
    return out, fits, stats


def _scaled_moments(xyz: np.ndarray, noise: np.ndarray, idx: np.ndarray) -> tuple:
    """The ray-plane sums (:func:`~rangeseg_o3d.ray_planes.pixel_moments`) of an even
    subsample of at most MOMENT_PIXELS of the flat pixels ``idx``, scaled to all of them."""
    sample = idx[:: max(1, -(-idx.size // MOMENT_PIXELS))]
    scale = idx.size / sample.size
    return tuple(m * scale for m in pixel_moments(xyz, noise, sample))


def _best_pair(members: dict, moments: dict, refused: set, window: int):
    """The pair ``(a, b)`` (a < b) of regions, not in ``refused``, whose joint plane along the
    rays grows their chi-square by the least per pixel of the smaller, of those whose joint
    plane holds (:func:`_one_plane`, ``window`` pixels an independent return); None when
    there is none."""
    labels = sorted(members)
    first, second = np.triu_indices(len(labels), 1)
    if first.size == 0:
        return None
    own = np.array([float(ray_fits(moments[k])[0][0]) for k in labels])
    stacked = [np.concatenate([moments[k][i] for k in labels]) for i in range(3)]
    union = ray_fits(tuple(s[first] + s[second] for s in stacked))[0]
    apart = own[first] + own[second]
    sizes = np.array([members[k].size for k in labels], dtype=np.float64)
    holds = _one_plane(union, apart, (sizes[first] + sizes[second]) / window, window)
    per_pixel = (union - apart) / np.minimum(sizes[first], sizes[second])
    for i in np.argsort(per_pixel, kind="stable"):
        pair = (labels[first[i]], labels[second[i]])
        if holds[i] and pair not in refused:
            return pair
    return None


def _one_plane(union: np.ndarray, apart: np.ndarray, independent: np.ndarray, window: int) -> np.ndarray:
    """Whether the chi-squares ``union`` (pixel units, one plane over two pieces) exceed
    ``apart`` (their two planes) by no more than noise would, over ``independent`` returns of
    ``window`` pixels each: the F-test of :func:`~rangeseg_o3d.kernels.linalg.curvature_resolved`
    for the second plane's three parameters. The noise's variance is the one its model states
    (one, in units of it, an independent return) or the two planes' own residuals' if smaller:
    a piece that holds some of another surface has residuals beyond the noise, and they must
    not widen the test (kinect_real_640x480 seed 37 scan 1: with the pieces' own variance, a
    piece of one box face joined a region 45 % of whose pixels lie on another face)."""
    extra = 3.0
    dof = independent - 6.0
    variance = np.where(dof > 0, np.minimum(apart / window / np.maximum(dof, 1.0), 1.0), 0.0)
    return (dof > 0) & ((union - apart) / window <= (extra + CHI_SQUARE_SIGMAS * np.sqrt(2.0 * extra)) * variance)


def _occluded_between(xyz: np.ndarray, noise: np.ndarray, flat_labels: np.ndarray, width: int,
                      one: np.ndarray, other: np.ndarray, pair: tuple, plane: np.ndarray,
                      valid: np.ndarray) -> bool:
    """Whether the pixels on the straight line between the centres of the flat pixels ``one``
    and ``other`` that belong to neither region of ``pair`` and have a return are, but for
    1 - BRIDGE_SHARE of them, nearer than ``plane`` (``a . p = 1``) by TRIM_SIGMAS of their
    range noise along the rays, or free pixels within it; and at least one is nearer (a
    region beside the pieces that continues their plane is no occluder)."""
    start = np.array(divmod(one, width), dtype=np.float64).mean(axis=1)
    end = np.array(divmod(other, width), dtype=np.float64).mean(axis=1)
    steps = int(np.ceil(np.abs(end - start).max())) + 1
    along = np.linspace(0.0, 1.0, steps)
    rows = np.rint(start[0] + along * (end[0] - start[0])).astype(np.int64)
    cols = np.rint(start[1] + along * (end[1] - start[1])).astype(np.int64)
    line = np.unique(rows * width + cols)
    between = line[valid[line] & ~np.isin(flat_labels[line], pair)]
    if between.size == 0:
        return False
    rays, inverse, weight = ray_terms(xyz[between], noise[between])
    residual = (inverse - rays @ plane) * np.sqrt(weight)  # positive: the return is nearer than the plane
    nearer = residual > TRIM_SIGMAS
    free_on_plane = (flat_labels[between] == 0) & (np.abs(residual) <= TRIM_SIGMAS)
    return bool(nearer.any()) and float(np.mean(nearer | free_on_plane)) >= BRIDGE_SHARE
