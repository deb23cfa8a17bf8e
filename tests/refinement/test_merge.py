"""The merge step: which regions touch, which pairs are worth a union fit."""

import numpy as np

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.fitting.primitives import Plane, Sphere
from rangeseg_o3d.refinement.merge import merge_candidates, merge_regions, region_adjacency, similar_models
from refinement_helpers import plane_grid


def test_region_adjacency_reach():
    labels = np.zeros((5, 9), np.int32)
    labels[:, :3] = 1
    labels[:, 4:] = 2  # one empty column between: pixels two apart
    assert region_adjacency(labels, reach=2) == {(1, 2)}
    assert region_adjacency(labels, reach=1) == set()


def test_merge_candidates_need_adjacency_or_similar_parameters():
    a = Plane(normal=[0, 0, 1], d=1.0, rms=0.004, inliers=100)
    b = Plane(normal=[0, 0.01, 1], d=1.01, rms=0.004, inliers=100)
    c = Plane(normal=[1, 0, 0], d=1.0, rms=0.004, inliers=100)
    s = Sphere(center=[0, 0, 0], radius=1.0, rms=0.004, inliers=100)
    assert similar_models(a, b, max_angle_deg=3, tolerance=0.05)
    assert not similar_models(a, c, max_angle_deg=3, tolerance=0.05)
    assert not similar_models(a, s, max_angle_deg=3, tolerance=0.05)
    models = {1: a, 2: b, 3: c, 4: s}
    assert merge_candidates(models, max_angle_deg=3, tolerance=0.05, adjacency=set()) == [(1, 2)]
    assert merge_candidates(models, max_angle_deg=3, tolerance=0.05, adjacency=set(),
                            disjoint=False) == []
    assert (1, 3) in merge_candidates(models, max_angle_deg=3, tolerance=0.05, adjacency={(1, 3)})


def _three_strips():
    # one plane seen as two strips (1, 2) and a plane at a crease beside them (3)
    xyz = plane_grid(20, 60, noise=0.002, seed=2)
    xyz[:, 40:, 2] += 0.5 * (xyz[:, 40:, 0] - xyz[0, 40, 0])
    labels = np.repeat(np.repeat(np.array([[1, 2, 3]], np.int32), 20, axis=0), 20, axis=1)
    fits = {k: fit_plane(xyz[labels == k]) for k in (1, 2, 3)}
    return xyz, labels, fits


def test_merge_regions_merges_the_parts_of_one_surface_only(context):
    xyz, labels, fits = _three_strips()
    adjacency = region_adjacency(labels)
    assert adjacency == {(1, 2), (2, 3)}
    out, merged, touching = merge_regions(context(rs.OrganizedCloud(xyz)), labels, fits, adjacency,
                                          max_angle_deg=3.0, tolerance=0.05, disjoint=True, rms_factor=1.3)
    assert set(np.unique(labels)) == {1, 2, 3} and set(fits) == {1, 2, 3}  # inputs left alone
    assert (out[:, :40] == 1).all() and (out[:, 40:] == 3).all()
    assert set(merged) == {1, 3} and merged[3] is fits[3]
    union = fit_plane(xyz[:, :40].reshape(-1, 3))
    np.testing.assert_allclose(merged[1].normal, union.normal, atol=1e-9)
    assert touching == {(1, 3)}  # the union touches what its parts touched


def test_merge_regions_only_pairs_with_the_labels_named(context):
    xyz, labels, fits = _three_strips()
    out, merged, _ = merge_regions(context(rs.OrganizedCloud(xyz)), labels, fits, region_adjacency(labels),
                                   max_angle_deg=3.0, tolerance=0.05, disjoint=True, rms_factor=1.3,
                                   only={3})
    assert (out == labels).all() and all(merged[k] is fits[k] for k in fits) and set(merged) == set(fits)
