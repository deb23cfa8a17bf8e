"""kernels.pool_inliers (the trimmed fit's inlier count) against the models' own distances."""

import numpy as np
import pytest

from rangeseg_o3d.fitting.primitives import Cylinder, FitFailure, Plane, Sphere
from rangeseg_o3d.fitting.region_fitter import model_row
from rangeseg_o3d.kernels import pool_inliers
from rangeseg_o3d.kernels.kinds import NONE

MODELS = [
    Plane(normal=np.array([0.6, 0.0, 0.8]), d=1.5, rms=0.002, inliers=0),
    Sphere(center=np.array([0.2, -0.1, 2.0]), radius=0.3, rms=0.002, inliers=0),
    Cylinder(axis=np.array([0.0, 0.6, 0.8]), point=np.array([0.1, 0.2, 2.5]), radius=0.15, rms=0.002,
             inliers=0),
]


def _points_near(model, rng, n=4000, spread=0.02):
    # points scattered around the model's surface (and far from it), with NaN rows
    pts = rng.uniform(-1.0, 1.0, (n, 3)) + np.array([0.0, 0.0, 2.0])
    if isinstance(model, Plane):
        pts -= np.outer(pts @ model.normal - model.d - rng.normal(0, spread, n), model.normal)
    elif isinstance(model, Sphere):
        rel = pts - model.center
        scale = (model.radius + rng.normal(0, spread, n)) / np.linalg.norm(rel, axis=1)
        pts = model.center + rel * scale[:, None]
    else:
        rel = pts - model.point
        radial = rel - np.outer(rel @ model.axis, model.axis)
        scale = (model.radius + rng.normal(0, spread, n)) / np.linalg.norm(radial, axis=1)
        pts = model.point + np.outer(rel @ model.axis, model.axis) + radial * scale[:, None]
    pts[::97] = np.nan
    return np.ascontiguousarray(pts)


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.kind)
def test_pool_inliers_counts_as_the_models_distances(model):
    rng = np.random.default_rng(3)
    xyz = _points_near(model, rng)
    pool = np.sort(rng.choice(len(xyz), 2500, replace=False)).astype(np.int64)
    tolerance, noise = 0.015, 0.006
    kind, row = model_row(model)
    inliers, n_inliers, n_noise = pool_inliers(xyz, pool, kind, row, tolerance, noise)
    distances = np.abs(model.distances(xyz[pool]))
    expected = distances <= tolerance
    # the same operations in the same order: equal up to the last bit but for points at the
    # tolerance itself (none here)
    assert np.array_equal(inliers, expected)
    assert n_inliers == expected.sum() and 0.2 * len(pool) < n_inliers < len(pool)
    assert n_noise == np.count_nonzero(distances <= noise) and n_noise < n_inliers


def test_pool_inliers_of_no_model_is_empty():
    xyz = np.zeros((5, 3))
    kind, row = model_row(FitFailure("plane", "none"))
    assert kind == NONE and not row.any()
    inliers, n_inliers, n_noise = pool_inliers(xyz, np.arange(5), kind, row, 1.0, 1.0)
    assert not inliers.any() and n_inliers == 0 and n_noise == 0
