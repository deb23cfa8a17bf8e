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
