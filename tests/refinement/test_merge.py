"""The merge step: which regions touch, which pairs are worth a union fit."""

import numpy as np

from rangeseg_o3d.fitting.primitives import Plane, Sphere
from rangeseg_o3d.refinement.merge import merge_candidates, region_adjacency, similar_models


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
