"""Faces seen near grazing that kept no region, grown from the free pixels they left.

A stereo camera's range noise spans a far box's top seen near grazing, a few pixels high:
the tile models give most of it to the front face beside it (its pixels there are within
that face's noise), and what they leave free is a piece of a few independent returns, under
the floor of a region recovered at full resolution (``scales.MIN_PIXELS`` counted as pixels
over the matching window). Along the rays the face is a plane all the same
(:func:`rangeseg_o3d.ray_planes.robust_ray_plane`): grown from its free piece, it takes
back what its plane explains, and the crease with the front face is put where the two
planes fitted along the rays fit best on either side of a straight line on the grid, then
where the two planes meet (:func:`faces_from_free`).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from .fitting.primitives import Plane
from .fitting.region_fitter import fresh_label, region_indices
from .fullres import region_stats
from .kernels.linalg import CHI_SQUARE_SIGMAS, noise_rms_bound
from .plane_faces import CLAIM_REACH, crease_line
from .ray_planes import ROBUST_CHUNKS, ray_plane, ray_terms, robust_ray_plane, seen_near_grazing
from .refinement.context import TRIM_SIGMAS, touching
from .scales import MIN_PIXELS

__all__ = ["CLAIM_ROUNDS", "SEED_PIXELS", "SURFACE_TEST_PIXELS", "faces_from_free"]

#: Rounds of claim and robust refit a face grown from a free piece takes.
CLAIM_ROUNDS = 2
#: The fewest pixels of a free piece a face is grown from: the fewest
#: :func:`rangeseg_o3d.ray_planes.robust_ray_plane` fits (the face is judged on what it grew to).
SEED_PIXELS = 3 * ROBUST_CHUNKS
#: Pixels of a touching region (an even subsample) on which a face is asked whether it is
#: a piece of that region's surface.
SURFACE_TEST_PIXELS = 4096


def faces_from_free(cloud, labels: np.ndarray, fits: dict, stats, *, sigma: np.ndarray, noise,
                    inlier_factor: float):
    """Plane regions for the faces seen near grazing that the free pixels hold.

    Each 4-connected piece of free pixels of at least SEED_PIXELS whose plane fitted robustly
    along its rays is seen near grazing (median incidence cosine under
    ``scales.GRAZING_COSINE``) claims the pixels beside it CLAIM_ROUNDS times, refitted
    robustly after each (:func:`_claim`: free pixels that plane meets within TRIM_SIGMAS of
    their range noise, pixels of a plane region it meets within that noise and nearer, in
    those units, than their region's plane). Within the noise of both planes those claims
    follow the noise; so the face and the pixels of the region it took most from, within its
    box, are cut along the straight line on the grid whose sides' planes along the rays fit
    them best (``plane_faces.crease_line``), and of them the face keeps those its plane
    explains, where the region's plane explains them too those whose rays meet the face's
    plane beyond that plane (a convex crease) or before it (a concave one), else those on its
    side of the line (:func:`_by_the_crease`).

    The face becomes a region when it holds at least ``scales.MIN_PIXELS``
    independent returns (``noise``: the sensor's :class:`rangeseg_o3d.sensor.NoiseModel`,
    :meth:`~rangeseg_o3d.sensor.NoiseModel.independent_returns` of the face's shape: a strip
    a pixel high holds three times the returns of a compact piece as large over a 3-pixel
    window), their mean square in noise units within the chi-square bound of that many, the
    plane still seen near grazing, and no plane region it touches mostly on that plane (a
    rim of a grazing wall, not a face). Returns ``(labels, fits, stats)``, the regions
    changed measured again; the inputs when no face is found.

    No share of the face's pixels its plane explains is asked for (as a strip's is,
    ``strips.EXPLAINED_SHARE``): the face's last robust fit is to pixels all within
    TRIM_SIGMAS of the plane fitted just before it (its claims and its side of the crease
    are taken within that band, the rest are that fit's own), and keeps nearly all of them:
    every face grown on the sensor matrix's stereo row (studied seeds) kept all, and far
    corners drawn as tests/test_free_faces.py draws them, rough faces and faces with a step
    of 2-5 noise sigmas included, kept 0.976 or more."""
    from .kernels import free_pieces

    # the free pieces a face may grow from, in scipy.ndimage.label's order (compiled)
    seeds, bounds = free_pieces(np.ascontiguousarray(labels, dtype=np.int32), np.ascontiguousarray(cloud.valid),
                                SEED_PIXELS)
    if bounds.size < 2:
        return labels, fits, stats
    xyz, flat_sigma = cloud.xyz.reshape(-1, 3), sigma.ravel()
    h, w = labels.shape
    planes = {k: m.normal / m.d for k, m in fits.items() if isinstance(m, Plane) and k > 0 and m.d != 0}
    out = np.array(labels, dtype=np.int32, order="C")
    flat = out.reshape(-1)
    found, changed = dict(fits), set()
    next_label = fresh_label(labels, fits)
    for b0, b1 in zip(bounds[:-1].tolist(), bounds[1:].tolist()):
        seed = seeds[b0:b1]
        seed = seed[flat[seed] == 0]  # a face found before may have taken some
        grown = _grown_face(cloud, sigma, out, seed, planes) if seed.size >= SEED_PIXELS else None
        if grown is None:
            continue
        face, a, mean_square = grown
        rows, cols = np.divmod(face, w)
        mask = np.zeros((int(np.ptp(rows)) + 1, int(np.ptp(cols)) + 1), bool)
        mask[rows - rows.min(), cols - cols.min()] = True
        independent = noise.independent_returns(mask)
        if (independent < MIN_PIXELS or not seen_near_grazing(a, xyz[face])
                or mean_square > noise_rms_bound.py_func(1.0, independent, CHI_SQUARE_SIGMAS) ** 2
                or _surface_of(xyz, flat_sigma, out, face, a, planes)):
            continue
        plane = ray_plane(a, xyz[face])
        if plane is None:
            continue
        changed |= set(np.unique(flat[face]).tolist()) | {next_label}
        flat[face] = next_label
        found[next_label] = plane
        planes[next_label] = a
        next_label += 1
    changed.discard(0)
    if not changed:
        return labels, fits, stats
    counts = np.bincount(flat, minlength=next_label)
    found = {k: m for k, m in found.items() if not (k in changed and counts[k] == 0)}
    stats = region_stats(cloud.xyz, out, found, sigma, inlier_factor, known=stats, stale=changed)
    return out, found, stats


def _grown_face(cloud, grid_sigma: np.ndarray, labels: np.ndarray, seed: np.ndarray, planes: dict):
    """``(face, a, mean square)``: the face grown from the free piece ``seed`` (flat
    pixels) as :func:`faces_from_free` says, its plane ``a . p = 1`` fitted robustly along
    the rays and its mean squared residual in noise units; None when the seed's plane is
    not seen near grazing or no plane is found."""
    xyz, sigma = cloud.xyz.reshape(-1, 3), grid_sigma.ravel()
    w = labels.shape[1]
    found = _robust(xyz, sigma, seed, w)
    if found is None or not seen_near_grazing(found[0], xyz[seed[found[1]]]):
        return None
    a, face = found[0], seed[found[1]]
    for _ in range(CLAIM_ROUNDS):
        union = np.union1d(face, _claim(cloud, grid_sigma, labels, a, face, planes))
        found = _robust(xyz, sigma, union, w)
        if found is None:
            return None
        a, keep, mean_square = found
        face = union[keep]
    # the crease with the region the claims took most from
    owners, taken = np.unique(labels.reshape(-1)[face], return_counts=True)
    taken[owners == 0] = 0
    if not (taken.size and taken.max() > 0):
        return face, a, mean_square
    other = int(owners[np.argmax(taken)])
    zone = np.union1d(face, _in_box(labels, other, face))
    ctx = SimpleNamespace(xyz=xyz, sigma=sigma, width=w, min_size=SEED_PIXELS)
    _, sides = crease_line(ctx, zone)
    if not sides or other not in planes:
        return face, a, mean_square
    side = max(sides, key=lambda s: int(np.count_nonzero(np.isin(seed, s))))
    for keep_side in (True, False):  # the line's side, then the planes' crease (the face is in the zone)
        union = side if keep_side else _by_the_crease(xyz, sigma, zone, side, face, a, planes[other])
        found = _robust(xyz, sigma, union, w)
        if found is None:
            return None
        a, keep, mean_square = found
        face = union[keep]
    return face, a, mean_square


def _robust(xyz: np.ndarray, sigma: np.ndarray, idx: np.ndarray, width: int):
    # robust_ray_plane of the flat pixels idx (their rows and columns on a grid this wide)
    rays, inverse, weight = ray_terms(xyz[idx], sigma[idx])
    return robust_ray_plane(rays, inverse, weight, *np.divmod(idx, width))


def _box(shape, idx: np.ndarray):
    """``(r0, r1, c0, c1)``: the box of the flat pixels ``idx`` grown by its own height and
    width (at least CLAIM_REACH pixels: a face may go on beyond its piece along its length)."""
    h, w = shape
    rows, cols = np.divmod(idx, w)
    down, across = max(CLAIM_REACH, int(np.ptp(rows)) + 1), max(CLAIM_REACH, int(np.ptp(cols)) + 1)
    return (max(int(rows.min()) - down, 0), min(int(rows.max()) + down + 1, h),
            max(int(cols.min()) - across, 0), min(int(cols.max()) + across + 1, w))


def _in_box(labels: np.ndarray, label: int, face: np.ndarray) -> np.ndarray:
    # the flat pixels of region ``label`` within the grown box of ``face`` (_box)
    r0, r1, c0, c1 = _box(labels.shape, face)
    rows, cols = np.nonzero(labels[r0:r1, c0:c1] == label)
    return (rows + r0) * labels.shape[1] + cols + c0


def _by_the_crease(xyz, sigma, zone, side, face, a, other) -> np.ndarray:
    """The pixels of ``zone`` that are the face's (its plane ``a``, its pixels ``face``)
    beside the plane region of plane ``other`` (``a . p = 1`` form): within TRIM_SIGMAS of
    the face's plane along their rays and, where ``other`` explains them within that noise
    too, met by the face's plane beyond ``other``'s at a convex crease (each side behind the
    other's plane, seen from the sensor), before it at a concave one, else on the face's
    ``side`` of the crease line (the pixels the planes cannot tell)."""
    rays, inverse, weight = ray_terms(xyz[zone], sigma[zone])
    scale = np.sqrt(weight)
    mine_q, theirs_q = rays @ a, rays @ other
    mine, theirs = scale * np.abs(inverse - mine_q), scale * np.abs(inverse - theirs_q)
    beside = zone[~np.isin(zone, face)]
    face_behind = float(xyz[face].mean(axis=0) @ other) > 1.0
    other_behind = beside.size > 0 and float(xyz[beside].mean(axis=0) @ a) > 1.0
    on_side = np.isin(zone, side)
    if face_behind == other_behind:
        # (a smaller inverse range: the plane met beyond)
        geometry = (mine_q < theirs_q) if face_behind else (mine_q > theirs_q)
    else:
        geometry = on_side
    both = (mine <= TRIM_SIGMAS) & (theirs <= TRIM_SIGMAS)
    return zone[(mine <= TRIM_SIGMAS) & np.where(both, geometry, on_side)]


def _surface_of(xyz: np.ndarray, sigma: np.ndarray, labels: np.ndarray, face: np.ndarray, a: np.ndarray,
                planes: dict) -> int:
    """A plane region touching ``face`` most of whose pixels (of an even subsample of
    SURFACE_TEST_PIXELS) the plane ``a`` meets within TRIM_SIGMAS of their range noise along
    the rays (0 when none): the face is a piece of that region's surface."""
    others = sorted(k for k in touching(labels, face, 1) - {0} if k in planes)
    for other, pixels in region_indices(labels, only=others).items():
        pixels = pixels[:: max(1, pixels.size // SURFACE_TEST_PIXELS)]
        rays, inverse, weight = ray_terms(xyz[pixels], sigma[pixels])
        if 2 * np.count_nonzero(weight * (inverse - rays @ a) ** 2 <= TRIM_SIGMAS ** 2) > pixels.size:
            return other
    return 0


def _claim(cloud, sigma: np.ndarray, labels: np.ndarray, a: np.ndarray, idx: np.ndarray,
           planes: dict) -> np.ndarray:
    """The flat pixels a face (its flat pixels ``idx``, its plane ``a . p = 1``) claims,
    connected to it through such pixels within its grown box (:func:`_box`): free pixels its
    plane meets within TRIM_SIGMAS of their range noise, and pixels of a plane region
    (``planes``: label -> its ``a``) its plane meets within that noise and nearer, in those
    units, than their region's plane."""
    from scipy import ndimage

    w = labels.shape[1]
    r0, r1, c0, c1 = _box(labels.shape, idx)
    owner = labels[r0:r1, c0:c1].reshape(-1)
    points = cloud.xyz[r0:r1, c0:c1].reshape(-1, 3)
    valid = cloud.valid[r0:r1, c0:c1].reshape(-1) & np.isfinite(points).all(axis=1)
    u, q, wt = ray_terms(np.where(valid[:, None], points, 1.0), sigma[r0:r1, c0:c1].reshape(-1))
    scale = np.sqrt(wt)
    mine = scale * np.abs(q - u @ a)
    theirs = np.where(owner == 0, np.inf, -np.inf)  # a region of no plane: none taken
    for j in np.unique(owner).tolist():
        if j in planes:
            at = owner == j
            theirs[at] = scale[at] * np.abs(q[at] - u[at] @ planes[j])
    take = valid & (mine <= TRIM_SIGMAS) & (mine < theirs)
    rows, cols = np.divmod(idx, w)
    region = np.zeros((r1 - r0, c1 - c0), bool)
    region[rows - r0, cols - c0] = True
    grown = ndimage.binary_propagation(region, mask=region | take.reshape(region.shape))
    box_rows, box_cols = np.nonzero(grown & ~region)
    return (box_rows + r0) * w + box_cols + c0
