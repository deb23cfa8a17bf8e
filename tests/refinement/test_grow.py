"""The grow step and its kernel call: edge-band pixels go back to the surface that explains them."""

import numpy as np

from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.refinement.grow import grow_into_edges


def _flat_grid(h=12, w=16, z=2.0):
    v, u = np.mgrid[0:h, 0:w].astype(float)
    return np.dstack([u * 0.05, v * 0.05, np.full((h, w), z)])


def test_grow_hands_band_pixels_to_the_surface_that_explains_them():
    xyz = _flat_grid()
    xyz[:, 8:, 2] = 2.0 + (xyz[:, 8:, 0] - 0.4)  # a 45 degree crease at column 8
    labels = np.zeros((12, 16), np.int32)
    labels[:, :6] = 1
    labels[:, 10:] = 2
    models = {1: fit_plane(xyz[:, :6].reshape(-1, 3)), 2: fit_plane(xyz[:, 10:].reshape(-1, 3))}
    sigma = np.full((12, 16), 0.002)
    grown = grow_into_edges(xyz, labels, models, sigma, xyz[..., 2], iterations=5, k_sigma=3.0)
    assert (grown[:, :8] == 1).all()
    # Column 8 lies on both planes (the crease line); the rest must go to its own side.
    assert (grown[:, 9:] == 2).all()
    assert (grown[:, 8] > 0).all()


def test_grow_does_not_cross_jumps_or_take_far_points():
    xyz = _flat_grid()
    xyz[:, 8:, 2] = 3.0  # a parallel plane 1 m behind: a jump, not the same surface
    labels = np.zeros((12, 16), np.int32)
    labels[:, :6] = 1
    models = {1: fit_plane(xyz[:, :6].reshape(-1, 3))}
    grown = grow_into_edges(xyz, labels, models, np.full((12, 16), 0.002), xyz[..., 2],
                            iterations=10)
    assert (grown[:, :8] == 1).all() and (grown[:, 8:] == 0).all()
