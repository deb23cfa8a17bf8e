"""Model normals and the noise of a point's distance to a model (range noise along the ray)."""

import numpy as np
import pytest

from rangeseg_o3d.fitting.primitives import Cylinder, Plane, Sphere
from rangeseg_o3d.fitting.robust import distance_noise, lateral_distance_noise


def test_normals_are_the_surfaces_unit_normals_at_the_points():
    plane = Plane(normal=(0, 0, 1), d=2.0, rms=0.0, inliers=0)
    points = np.array([[1.0, 2.0, 2.1], [-3.0, 0.5, 1.9]])
    np.testing.assert_allclose(plane.normals(points), [[0, 0, 1], [0, 0, 1]])
    sphere = Sphere(center=(1, 1, 1), radius=0.5, rms=0.0, inliers=0)
    np.testing.assert_allclose(sphere.normals(np.array([[1.0, 1.0, 2.0], [1.0, 0.0, 1.0]])),
                               [[0, 0, 1], [0, -1, 0]], atol=1e-12)
    cylinder = Cylinder(axis=(0, 0, 1), point=(2, 0, 0), radius=0.3, rms=0.0, inliers=0)
    # radial, whatever the height along the axis; a point on the axis has none
    np.testing.assert_allclose(cylinder.normals(np.array([[2.3, 0.0, 5.0], [2.0, -0.2, -1.0], [2.0, 0.0, 3.0]])),
                               [[1, 0, 0], [0, -1, 0], [0, 0, 0]], atol=1e-12)


def test_range_noise_moves_a_point_along_its_ray_by_the_incidence_cosine():
    # A wall 4 m ahead seen head-on keeps the whole range noise; at 60 deg incidence, half.
    wall = Plane(normal=(1, 0, 0), d=4.0, rms=0.0, inliers=0)
    head_on = np.array([[4.0, 0.0, 0.0]])
    oblique = np.array([[4.0, 4.0 * np.tan(np.deg2rad(60)), 0.0]])
    np.testing.assert_allclose(distance_noise(wall, head_on, np.array([0.02])), [0.02])
    np.testing.assert_allclose(distance_noise(wall, oblique, np.array([0.02])), [0.01], rtol=1e-12)


def _column_scatter(rng, distance, angles, sigma):
    # points of a column (axis z, r 0.3 m, ``distance`` ahead of the origin) at ``angles``
    # about its axis, their ranges disturbed by ``sigma``: the rms of their distances to it,
    # the rms distance_noise predicts, and the rms of its first-order term (sigma cos)
    column = Cylinder(axis=(0, 0, 1), point=(distance, 0, 0), radius=0.3, rms=0.0, inliers=0)
    exact = np.stack([distance + 0.3 * np.cos(angles), 0.3 * np.sin(angles),
                      rng.uniform(-1, 1, angles.size)], axis=1)
    rays = exact / np.linalg.norm(exact, axis=1, keepdims=True)
    noisy = exact + rays * rng.normal(0, sigma, angles.size)[:, None]
    noise = np.full(angles.size, sigma)
    first = noise * np.abs(np.einsum("ij,ij->i", rays, column.normals(exact)))
    return (float(np.sqrt(np.mean(column.distances(noisy) ** 2))),
            float(np.sqrt(np.mean(distance_noise(column, exact, noise) ** 2))), float(np.sqrt(np.mean(first ** 2))))


@pytest.mark.parametrize("seed", [0, 1])
def test_distance_noise_predicts_the_rms_of_noisy_points_about_their_true_model(seed):
    # Points of a column seen from the origin, their ranges disturbed by sigma: the rms of
    # their distances to the column is the rms of distance_noise, far below sigma (the
    # flanks are seen at grazing incidence).
    rng = np.random.default_rng(seed)
    angles = np.linspace(np.pi / 2 + 0.05, 3 * np.pi / 2 - 0.05, 4000)  # the half facing the origin
    measured, predicted, _ = _column_scatter(rng, 3.0, angles, 0.01)
    assert predicted < 0.85 * 0.01
    assert abs(measured - predicted) < 0.05 * predicted


def test_lateral_noise_adds_its_share_by_the_incidence_sine():
    # A wall 4 m ahead: head-on the lateral offset slides a point along it (the range noise
    # alone, 2 mm); at 60 deg the range noise's half (1 mm) and the lateral 0.5 mm/m x 4 m x
    # sin 60 (1.73 mm) in quadrature; without lateral noise, distance_noise's values.
    wall = Plane(normal=(1, 0, 0), d=4.0, rms=0.0, inliers=0)
    points = np.array([[4.0, 0.0, 0.0], [4.0, 4.0 * np.tan(np.deg2rad(60)), 0.0]])
    sigma = np.array([0.002, 0.002])
    oblique_range = np.linalg.norm(points[1])
    expected = [0.002, np.hypot(0.001, 0.0005 * oblique_range * np.sin(np.deg2rad(60)))]
    np.testing.assert_allclose(lateral_distance_noise(wall, points, sigma, 0.0005), expected, rtol=1e-9)
    np.testing.assert_allclose(lateral_distance_noise(wall, points, sigma, 0.0), distance_noise(wall, points, sigma),
                               rtol=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
def test_lateral_noise_predicts_the_scatter_of_a_face_seen_near_grazing(seed):
    # Points of a wall seen 85 deg from head-on, each measured 0.3 mm/m (rms) beside its ray
    # and reported on it, with 0.3 mm of range noise: their rms about the wall is the
    # lateral noise's (about 0.3 mm at 1 m), ten times what the range noise alone predicts.
    rng = np.random.default_rng(seed)
    cosine = np.cos(np.deg2rad(85.0))
    wall = Plane(normal=(0.0, -np.sqrt(1 - cosine ** 2), cosine), d=cosine * 1.0, rms=0.0, inliers=0)
    u, v = rng.uniform(-0.02, 0.02, 4000), rng.uniform(-0.002, 0.002, 4000)
    rays = np.stack([u, v, np.ones_like(u)], axis=1)
    beside = rays + np.stack([rng.normal(0, 3e-4, u.size), rng.normal(0, 3e-4, u.size), np.zeros_like(u)], axis=1)
    depth = wall.d / (beside @ wall.normal)
    exact = rays * depth[:, None]
    noisy = exact + exact / np.linalg.norm(exact, axis=1, keepdims=True) * rng.normal(0, 3e-4, u.size)[:, None]
    sigma = np.full(u.size, 3e-4)
    measured = np.sqrt(np.mean(wall.distances(noisy) ** 2))
    predicted = np.sqrt(np.mean(lateral_distance_noise(wall, exact, sigma, 3e-4) ** 2))
    along = np.sqrt(np.mean(distance_noise(wall, exact, sigma) ** 2))
    assert measured > 8 * along
    assert abs(measured - predicted) < 0.1 * predicted


def test_a_curved_models_distance_noise_adds_the_sagitta_of_its_bend():
    # A column of radius 0.3 m 4 m ahead (axis z): head-on the ray crosses no bend (the
    # range noise whole); at a flank the ray's part across normal and axis bends the
    # distance by delta**2 c**2 / (2 r), mean square 3 (sigma**2 c**2 / (2 r))**2, in
    # quadrature with sigma cos. A ray with a part along the axis bends less (c**2 =
    # 1 - cos**2 - along**2); a ball bends every way (c = the incidence sine); a plane none.
    sigma = 0.03
    column = Cylinder(axis=(0, 0, 1), point=(4, 0, 0), radius=0.3, rms=0.0, inliers=0)
    head_on = np.array([[3.7, 0.0, 0.0]])
    np.testing.assert_allclose(distance_noise(column, head_on, np.array([sigma])), [sigma], rtol=1e-12)
    flank = np.array([[4.0, 0.3, 1.0]])
    ray = flank[0] / np.linalg.norm(flank[0])
    cos, along = abs(ray[1]), ray[2]
    sagitta = sigma ** 2 * (1 - cos ** 2 - along ** 2) / (2 * 0.3)
    np.testing.assert_allclose(distance_noise(column, flank, np.array([sigma])),
                               [np.hypot(sigma * cos, np.sqrt(3) * sagitta)], rtol=1e-12)
    ball = Sphere(center=(4, 0, 0), radius=0.3, rms=0.0, inliers=0)
    side = np.array([[4.0, 0.3, 0.0]])
    ray = side[0] / np.linalg.norm(side[0])
    np.testing.assert_allclose(distance_noise(ball, side, np.array([sigma])),
                               [np.hypot(sigma * ray[1], np.sqrt(3) * sigma ** 2 * (1 - ray[1] ** 2) / 0.6)],
                               rtol=1e-12)
    wall = Plane(normal=(0, 1, 0), d=0.3, rms=0.0, inliers=0)
    np.testing.assert_allclose(distance_noise(wall, flank, np.array([sigma])), [sigma * cos], rtol=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
def test_distance_noise_predicts_the_scatter_at_a_columns_flanks_under_a_cameras_noise(seed):
    # The flanks of a column (r 0.3 m, 4 m away) where the rays graze it, ranges disturbed
    # by 3 cm (a Kinect-type camera at 4.6 m): the first-order noise sigma cos predicts
    # half the scatter about the true column; with the sagitta term, within 8 %.
    rng = np.random.default_rng(seed)
    tangent = np.arcsin(0.3 / 4.0)
    angles = np.concatenate([rng.uniform(np.pi / 2 + tangent, np.pi / 2 + tangent + 0.08, 3000),
                             rng.uniform(3 * np.pi / 2 - tangent - 0.08, 3 * np.pi / 2 - tangent, 3000)])
    measured, predicted, first = _column_scatter(rng, 4.0, angles, 0.03)
    assert first < 0.6 * measured
    assert abs(measured - predicted) < 0.08 * predicted
