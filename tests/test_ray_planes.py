"""Planes fitted along the viewing rays (rangeseg_o3d.ray_planes): the exact plane of exact
points, the robust fit's own tests are with the strips it serves (tests/test_strips.py), and
whether a plane is seen near grazing."""

import numpy as np
import pytest

from rangeseg_o3d.ray_planes import ray_fits, ray_moments, ray_plane, ray_terms, seen_near_grazing
from rangeseg_o3d.scales import GRAZING_COSINE


def _on_plane(normal, d, rows=20, cols=30):
    # points of the plane n . p = d along a pinhole camera's rays (f = 100 px, centred grid)
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / 100.0, (v - rows / 2) / 100.0, np.ones((rows, cols))]).reshape(-1, 3)
    return rays * (d / (rays @ normal))[:, None]


def test_the_plane_of_exact_points_is_their_plane_with_no_residual():
    normal = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    d = 5.0
    points = _on_plane(normal, d)
    rays, inverse, weight = ray_terms(points, np.full(len(points), 0.01))
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(inverse, 1.0 / np.linalg.norm(points, axis=1), rtol=1e-12)
    chi2, a = ray_fits(ray_moments(rays, inverse, weight))
    np.testing.assert_allclose(a[0], normal / d, rtol=1e-8)
    assert chi2[0] < 1e-6 * float(np.sum(weight * inverse ** 2))  # (against the sum it starts from)
    plane = ray_plane(a[0], points)
    np.testing.assert_allclose(plane.normal, normal, atol=1e-8)
    assert plane.d == pytest.approx(d, rel=1e-8) and plane.rms < 1e-8 * d and plane.inliers == len(points)


def test_no_plane_from_a_zero_or_undefined_a():
    points = np.ones((5, 3))
    assert ray_plane(np.zeros(3), points) is None
    assert ray_plane(np.array([np.nan, 0.0, 1.0]), points) is None


def test_a_far_floor_is_seen_near_grazing_and_a_head_on_wall_is_not():
    # a floor 0.5 m under the camera seen 4-6 m off (its rays meet it at cosines of about
    # 0.1), a wall 5 m ahead, seen head-on (cosines near 1)
    x, z = np.meshgrid(np.linspace(-1.0, 1.0, 30), np.linspace(4.0, 6.0, 20))
    floor = np.column_stack([x.ravel(), np.full(x.size, 0.5), z.ravel()])
    cosines = np.abs(floor[:, 1]) / np.linalg.norm(floor, axis=1)
    assert np.median(cosines) < GRAZING_COSINE  # the premise
    assert seen_near_grazing(np.array([0.0, 1.0, 0.0]) / 0.5, floor)
    wall = _on_plane(np.array([0.0, 0.0, 1.0]), 5.0)
    assert not seen_near_grazing(np.array([0.0, 0.0, 1.0]) / 5.0, wall)
    # the same floor 1.2 m under the camera: cosines 0.2-0.3, over the grazing bound
    nearer = floor * np.array([1.0, 1.2 / 0.5, 1.0])
    assert np.median(np.abs(nearer[:, 1]) / np.linalg.norm(nearer, axis=1)) > GRAZING_COSINE  # the premise
    assert not seen_near_grazing(np.array([0.0, 1.0, 0.0]) / 1.2, nearer)
