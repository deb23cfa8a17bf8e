"""kernels.nearer_models: the move of refinement.facets._nearest (each point to a clearly nearer model), compiled."""

import numpy as np

from rangeseg_o3d.fitting.primitives import Cylinder, Plane
from rangeseg_o3d.fitting.region_fitter import model_row
from rangeseg_o3d.fitting.robust import distance_noise
from rangeseg_o3d.kernels import nearer_models


def _numpy_form(points, sigma, owner, models, margin):
    # the (models x points) distances, argmin and gains of the numpy step it replaces
    distances = np.stack([np.abs(model.distances(points)) for model in models])
    nearest = np.argmin(distances, axis=0)
    move = np.flatnonzero(nearest != owner)
    gain = distances[owner[move], move] - distances[nearest[move], move]
    for i, model in enumerate(models):
        mine = owner[move] == i
        gain[mine] -= margin * distance_noise(model, points[move[mine]], sigma[move[mine]])
    out = owner.copy()
    out[move[gain > 0]] = nearest[move[gain > 0]]
    return out


def _scene(rng, n=3000):
    # a floor, a wall and a pipe lying on the floor, 2-4 m away; each point owned by a random
    # model half the time (a split's pull), else by the one it was drawn from
    models = [Plane(normal=[0.0, -1.0, 0.0], d=-1.0, rms=0.002, inliers=n),
              Plane(normal=[0.0, 0.0, 1.0], d=4.0, rms=0.002, inliers=n),
              Cylinder(axis=[1.0, 0.0, 0.0], point=[0.0, 0.85, 3.0], radius=0.15, rms=0.002, inliers=n)]
    drawn = rng.integers(0, 3, n)
    x = rng.uniform(-1.0, 1.0, n)
    angle = rng.uniform(np.pi, 2 * np.pi, n)
    points = np.stack([
        np.stack([x, np.full(n, 1.0), rng.uniform(2.0, 4.0, n)], axis=1),
        np.stack([x, rng.uniform(-1.0, 1.0, n), np.full(n, 4.0)], axis=1),
        np.stack([x, 0.85 + 0.15 * np.sin(angle), 3.0 + 0.15 * np.cos(angle)], axis=1)])[drawn, np.arange(n)]
    points += rng.normal(0.0, 0.01, (n, 3))
    sigma = 0.002 * np.linalg.norm(points, axis=1) ** 2
    owner = np.where(rng.random(n) < 0.5, rng.integers(0, 3, n), drawn).astype(np.int64)
    return points, sigma, owner, models


def _table(models):
    kinds, params = zip(*(model_row(model) for model in models))
    return np.array(kinds, np.int8), np.array(params)


def test_agrees_with_the_numpy_form():
    rng = np.random.default_rng(7)
    points, sigma, owner, models = _scene(rng)
    got, moved = nearer_models(points, sigma, owner, *_table(models), 3.0)
    want = _numpy_form(points, sigma, owner, models, 3.0)
    np.testing.assert_array_equal(got, want)
    assert moved == np.count_nonzero(got != owner)
    assert 0.2 * owner.size < moved < 0.5 * owner.size  # it moves some and keeps others on this scene


def test_the_margin_keeps_points_within_the_noise_where_they_are():
    rng = np.random.default_rng(8)
    points, sigma, owner, models = _scene(rng)
    kinds, params = _table(models)
    few, moved_few = nearer_models(points, sigma, owner, kinds, params, 50.0)
    many, moved_many = nearer_models(points, sigma, owner, kinds, params, 0.0)
    assert moved_few < moved_many
    assert set(np.flatnonzero(few != owner)) <= set(np.flatnonzero(many != owner))
    # a point its owner explains best never moves, whatever the margin
    again, moved = nearer_models(points, sigma, many, kinds, params, 0.0)
    assert moved == 0 and np.array_equal(again, many)
