"""kernels.grow_along_rays: a face grows ring by ring over the free pixels its plane meets
within the range noise, and only those it reaches through such pixels."""

import numpy as np
import pytest
from scipy import ndimage

from rangeseg_o3d.kernels import grow_along_rays

K_SIGMA = 3.0


def _wall(rows=40, cols=50, sigma=0.02, seed=0):
    """A head-on wall 4 m ahead (2 cm pixels) with ``sigma`` of range noise along each ray,
    one pixel in 20 (at random) 10 sigma off it: ``(xyz, noise, plane row a = n / d)``."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    xyz = np.dstack([(u - cols / 2) * 0.02, (v - rows / 2) * 0.02, np.full(u.shape, 4.0)]).reshape(-1, 3)
    ranges = np.linalg.norm(xyz, axis=1, keepdims=True)
    rng = np.random.default_rng(seed)
    errors = rng.normal(0.0, sigma, ranges.shape)
    errors[rng.random(ranges.shape) < 0.05] += 10 * sigma  # pixels off the wall: the face must not take them
    return xyz * (1.0 + errors / ranges), np.full(rows * cols, sigma), np.array([0.0, 0.0, 0.25])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_face_grows_over_the_free_pixels_its_plane_explains(seed):
    rows, cols = 40, 50
    xyz, noise, plane = _wall(rows, cols, seed=seed)
    face = 2
    planes = np.full((face + 1, 3), np.nan)
    planes[face] = plane
    flat = np.zeros(rows * cols, np.int32)
    ranges = np.linalg.norm(xyz, axis=1)
    explained = np.abs(1.0 / ranges - (xyz / ranges[:, None]) @ plane) * ranges ** 2 / noise <= K_SIGMA
    seed_pixel = int(np.flatnonzero(explained)[len(np.flatnonzero(explained)) // 2])
    flat[seed_pixel] = face
    no = np.zeros((1, face + 1), bool)
    r, c = divmod(seed_pixel, cols)
    moved = grow_along_rays(xyz, flat, rows, cols, planes, no, no, noise, face, 1,
                            np.array([r, r + 1, c, c + 1], np.int64), K_SIGMA, 200)
    # what it holds: the piece of the explained pixels, 4-connected, that holds the seed
    pieces, _ = ndimage.label(explained.reshape(rows, cols))
    reached = (pieces == pieces.flat[seed_pixel]).ravel()
    assert np.array_equal(flat == face, reached)
    assert np.array_equal(np.sort(moved), np.flatnonzero(reached & (np.arange(flat.size) != seed_pixel)))
    # (most of the wall: the outliers, 1 in 20, do not cut it apart)
    assert np.count_nonzero(reached) > 0.8 * flat.size


def test_growth_stops_after_its_rings():
    rows, cols = 40, 50
    xyz, noise, plane = _wall(rows, cols, sigma=0.02, seed=0)
    xyz = xyz / np.linalg.norm(xyz, axis=1, keepdims=True) / ((xyz / np.linalg.norm(xyz, axis=1, keepdims=True))
                                                              @ plane)[:, None]  # on the plane exactly
    face = 1
    planes = np.full((face + 1, 3), np.nan)
    planes[face] = plane
    flat = np.zeros(rows * cols, np.int32)
    flat[20 * cols + 25] = face
    no = np.zeros((1, face + 1), bool)
    grow_along_rays(xyz, flat, rows, cols, planes, no, no, noise, face, 1, np.array([20, 21, 25, 26], np.int64),
                    K_SIGMA, 5)
    v, u = np.divmod(np.arange(rows * cols), cols)
    # five rings of 4-neighbours: the diamond of city-block radius 5 around the seed
    assert np.array_equal(flat == face, np.abs(v - 20) + np.abs(u - 25) <= 5)


def test_growth_to_the_edge_of_its_window_stays_in_its_buffers():
    # the buffers are sized for the box grown by a pixel a side per ring: a growth that uses
    # every ring reaches their edge; run in Python (py_func), numpy checks every index
    rows, cols, rings = 40, 50, 8
    xyz, noise, plane = _wall(rows, cols, sigma=0.02, seed=1)
    ranges = np.linalg.norm(xyz, axis=1, keepdims=True)
    xyz = xyz / ranges / ((xyz / ranges) @ plane)[:, None]  # on the plane exactly
    face = 1
    planes = np.full((face + 1, 3), np.nan)
    planes[face] = plane
    no = np.zeros((1, face + 1), bool)
    box = np.array([20, 21, 25, 26], np.int64)
    grown = []
    for kernel in (grow_along_rays, grow_along_rays.py_func):
        flat = np.zeros(rows * cols, np.int32)
        flat[20 * cols + 25] = face
        moved = kernel(xyz, flat, rows, cols, planes, no, no, noise, face, 1, box.copy(), K_SIGMA, rings)
        grown.append((flat == face, np.sort(moved)))
    v, u = np.divmod(np.arange(rows * cols), cols)
    assert np.array_equal(grown[0][0], np.abs(v - 20) + np.abs(u - 25) <= rings)
    assert np.array_equal(grown[0][0], grown[1][0]) and np.array_equal(grown[0][1], grown[1][1])


def _corner(rows=40, cols=60, sigma=0.005, seed=0):
    """A wall 4 m ahead (columns < 30) meeting a wall turned 40 degrees from it (columns >= 30),
    with ``sigma`` of range noise: ``(xyz, noise, plane rows: 1 the turned wall, 2 the face's)``."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) * 0.005, (v - rows / 2) * 0.005, np.ones(u.shape)]).reshape(-1, 3)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    face = np.array([0.0, 0.0, 0.25])
    turn = np.radians(40.0)
    other = np.array([-np.sin(turn), 0.0, np.cos(turn)])
    other = other / (other @ (rays[30] / (rays[30] @ face)))  # through the face's plane at column 30
    a = np.where((u.ravel() < 30)[:, None], face, other)
    ranges = 1.0 / np.einsum("ij,ij->i", rays, a)
    ranges = ranges + np.random.default_rng(seed).normal(0.0, sigma, ranges.shape)
    planes = np.full((3, 3), np.nan)
    planes[1], planes[2] = other, face
    return rays * ranges[:, None], np.full(rows * cols, sigma), planes


def _reference_growth(xyz: np.ndarray, out: np.ndarray, planes: np.ndarray, units: np.ndarray, face: int,
                     held: np.ndarray, noise: np.ndarray, k_sigma: float, max_angle_deg: float) -> np.ndarray:
    """The face ``face`` of ``out`` (in place; its flat pixels among ``held``, increasing;
    ``planes``: every label's plane row, :func:`_plane_rows`, one for each label of ``out``;
    ``units``: those rows of unit length, :func:`_unit_rows`)
    grows ring by ring (:func:`rangeseg_o3d.kernels.grow_along_rays`: 4-neighbours, at most
    GROWTH_RINGS) into the free pixels whose range its plane meets within ``k_sigma``
    range-noise sigmas (``noise``, flat), and into those of a plane region beside it on the
    face's side of their crease, then gives back its pixels on the other side of it (within
    ``k_sigma`` of that region's plane); a curved region, and a plane within
    ``max_angle_deg`` of the face's (no crease between them to tell the sides by), keeps its
    pixels. The side of the crease is where each ray meets the two planes, which the noise
    does not move: across a concave crease (a room's corner, the face on the sensor's side of
    the other plane) the nearer plane is the one seen, across a convex one (a box's edge) the
    farther. Near the crease a pixel's range lies within the noise of both planes; which
    plane is nearer in range there is a coin's toss (a 10-pixel strip at 7 m lost a third of
    itself so).
    Returns the flat pixels that changed hands. (The numpy wrapper off_model used around
    grow_along_rays before grow_face took its decisions into one compiled call: the
    reference grow_face is held to.)"""
    from rangeseg_o3d.off_model import GROWTH_RINGS

    h, w = out.shape
    flat = out.ravel()
    mine = held[flat[held] == face]
    if not mine.size:
        return np.zeros(0, np.int64)
    centre = xyz[mine].mean(axis=0)
    # per region k: the face on the sensor's side of its plane (a . c < 1: nearer along the
    # ray), and the two planes turned from each other
    concave = (planes @ centre < 1.0)[None]
    crease = (np.abs(units @ units[face]) < np.cos(np.radians(max_angle_deg)))[None]
    rows, cols = np.divmod(mine, w)
    box = np.array([rows.min(), rows.max() + 1, cols.min(), cols.max() + 1], np.int64)  # the faces' box
    return grow_along_rays(xyz, flat, h, w, planes, concave, crease, noise, int(face), 1, box, float(k_sigma),
                           GROWTH_RINGS)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_grow_face_is_the_numpy_wrapper_in_one_call(seed):
    # grow_face (the face's centre, its concave and crease rows, the growth and the merged
    # held pixels in one compiled call) against the numpy wrapper it replaced (_reference_growth) and unique_ints
    from rangeseg_o3d._numeric import unique_ints
    from rangeseg_o3d.kernels import grow_face
    from rangeseg_o3d.off_model import GROWTH_RINGS, _unit_rows

    rows, cols = 40, 60
    xyz, noise, planes = _corner(rows, cols, seed=seed)
    units = _unit_rows(planes)
    labels = np.zeros((rows, cols), np.int32)
    labels[:, 24:] = 1  # the turned wall's region took six columns of the face's wall
    labels[15:25, 5:12] = 2  # the face
    held = np.flatnonzero(labels.ravel() == 2).astype(np.int64)
    old = labels.copy()
    moved_old = _reference_growth(xyz, old, planes, units, 2, held, noise, K_SIGMA, 10.0)
    new = labels.copy()
    moved_new, held_new = grow_face(xyz, new.ravel(), rows, cols, planes, units, noise, 2, held, K_SIGMA,
                                    float(np.cos(np.radians(10.0))), GROWTH_RINGS)
    assert np.array_equal(new, old)
    assert np.array_equal(moved_new, moved_old)
    assert np.array_equal(held_new, unique_ints(np.concatenate([held, moved_old])))
    # the face grew over the free pixels of its wall and took back most of the columns the
    # turned wall's region held on its side of the crease
    assert np.count_nonzero(new == 2) > 0.9 * rows * 24
    assert np.count_nonzero(new[:, 24:30] == 2) > 0.8 * rows * 6
    assert np.count_nonzero(new[:, 31:] == 2) == 0


def test_grow_face_without_pixels_moves_nothing():
    from rangeseg_o3d.kernels import grow_face
    from rangeseg_o3d.off_model import _unit_rows

    xyz, noise, planes = _corner()
    flat = np.ones(xyz.shape[0], np.int32)
    held = np.array([3, 4, 5], np.int64)  # (the region's now: no pixel of face 2 among them)
    moved, kept = grow_face(xyz, flat, 40, 60, planes, _unit_rows(planes), noise, 2, held, K_SIGMA, 0.98, 64)
    assert moved.size == 0 and np.array_equal(kept, held) and np.all(flat == 1)


def _refit_reference(xyz, noise, mine, own, source, k_sigma, floor):
    """The numpy refit terms refit_terms replaces (off_model._refit_apart before it): the
    pixels kept and ray_moments of their ray_terms."""
    from rangeseg_o3d.ray_planes import ray_moments, ray_terms

    rays, inverse, weight = ray_terms(xyz[mine], noise[mine])
    kept = mine
    if not np.isnan(source[0]):
        apart = np.abs(rays @ own - rays @ source) * np.sqrt(weight) > k_sigma
        if np.count_nonzero(apart) >= max(floor, 3):
            rays, inverse, weight, kept = rays[apart], inverse[apart], weight[apart], mine[apart]
    outer, first, _ = ray_moments(rays, inverse, weight)
    return outer[0], first[0], kept


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("floor", [3, 500, 10 ** 6])
def test_refit_terms_are_numpys_sums_bit_for_bit(seed, floor):
    from rangeseg_o3d.kernels import refit_terms

    rows, cols = 40, 60
    xyz, noise, planes = _corner(rows, cols, seed=seed)
    noise = noise * np.random.default_rng(seed).uniform(0.5, 2.0, noise.size)  # (each pixel its own weight)
    flat = np.zeros(rows * cols, np.int32)
    grid = flat.reshape(rows, cols)
    grid[5:35, 10:40] = 2  # the face: its wall and ten columns of the turned one
    grid[20, 15] = 1  # (a held pixel another label took since: not summed)
    held = np.flatnonzero((grid >= 1).ravel()).astype(np.int64)
    mine = held[flat[held] == 2]
    for source in (planes[1], np.full(3, np.nan)):
        outer, first, pixels = refit_terms(xyz, noise, flat, held, 2, planes[2], source, K_SIGMA, floor)
        ref_outer, ref_first, ref_pixels = _refit_reference(xyz, noise, mine, planes[2], source, K_SIGMA, floor)
        assert np.array_equal(pixels, ref_pixels)
        assert np.array_equal(outer, ref_outer) and np.array_equal(first, ref_first)
        if np.isnan(source[0]) or floor > mine.size:
            assert np.array_equal(pixels, mine)  # (no plane beside it, or too few apart: all of them)
        else:
            # the face's pixels on the turned wall lie within the noise of both planes near the
            # crease: the refit leaves those out, and keeps its own wall's
            assert 0 < pixels.size < mine.size
            assert np.count_nonzero(pixels % cols < 30) > 0.9 * np.count_nonzero(mine % cols < 30)
