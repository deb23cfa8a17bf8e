"""The dissolve step on its own: small blobs go to the larger neighbours that explain them."""

import numpy as np

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.fitting.primitives import Sphere
from rangeseg_o3d.refinement.dissolve import dissolve_small
from refinement_helpers import plane_grid


def _plane_with_a_blob(blob_z=0.0):
    # two planes at a crease (1 left, 2 right) and a 24-pixel blob (3) on the first one's
    # surface near the crease, fitted as a small sphere; ``blob_z`` lifts the blob
    xyz = plane_grid(20, 60, noise=0.001, seed=4)
    xyz[:, 32:, 2] += 0.5 * (xyz[:, 32:, 0] - xyz[0, 32, 0])
    labels = np.where(np.arange(60) < 32, 1, 2).astype(np.int32)[None, :].repeat(20, axis=0)
    labels[0:6, 28:32] = 3
    xyz[0:6, 28:32, 2] += blob_z
    fits = {1: fit_plane(xyz[labels == 1]), 2: fit_plane(xyz[labels == 2]),
            3: Sphere(center=np.array([0.6, 0.05, 3.2]), radius=0.2, rms=0.001, inliers=24)}
    return xyz, labels, fits


def test_a_small_blob_on_a_neighbours_surface_joins_it(context):
    xyz, labels, fits = _plane_with_a_blob()
    ctx = context(rs.OrganizedCloud(xyz), min_size=10, sigma=np.full((20, 60), 0.001))
    out, dissolved = dissolve_small(ctx, labels, fits, {(1, 2), (1, 3), (2, 3)}, k_sigma=3.0)
    assert (labels[0:6, 28:32] == 3).all() and 3 in fits  # the inputs are left alone
    assert (out[0:6, 28:32] == 1).all() and set(dissolved) == {1, 2}
    assert dissolved[2] is fits[2]
    # the host is refitted with the blob's pixels
    np.testing.assert_allclose(dissolved[1].normal, fit_plane(xyz[out == 1]).normal, atol=1e-9)


def test_a_blob_no_neighbour_explains_stays(context):
    xyz, labels, fits = _plane_with_a_blob(blob_z=-0.2)  # 20 cm in front of the plane
    ctx = context(rs.OrganizedCloud(xyz), min_size=10, sigma=np.full((20, 60), 0.001))
    out, kept = dissolve_small(ctx, labels, fits, {(1, 2), (1, 3), (2, 3)}, k_sigma=3.0)
    assert (out == labels).all() and kept == fits


def test_no_small_region_returns_the_inputs(context):
    xyz, labels, fits = _plane_with_a_blob()
    labels[labels == 3] = 1
    del fits[3]
    ctx = context(rs.OrganizedCloud(xyz), min_size=10)
    out, same = dissolve_small(ctx, labels, fits, {(1, 2)}, k_sigma=3.0)
    assert out is labels and same is fits
