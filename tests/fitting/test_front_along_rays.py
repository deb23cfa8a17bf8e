"""Where rays first meet a cylinder or a sphere (fitting.primitives.front_along_rays)."""

import numpy as np
import pytest

from rangeseg_o3d.fitting.primitives import Cylinder, Plane, Sphere, front_along_rays


def test_a_vertical_pipe_ahead_is_met_on_its_near_side_and_a_ray_beside_it_at_its_closest_approach():
    pipe = Cylinder(axis=[0.0, 0.0, 1.0], point=[3.0, 0.0, 0.0], radius=0.5, rms=0.0, inliers=0)
    points = np.array([[4.0, 0.0, 0.7],    # behind the pipe, straight ahead
                       [3.0, 2.0, 0.0]])  # beside it: the ray passes at 3 sin(atan(2/3)) from the axis
    rays, ranges, front, hit = front_along_rays(pipe, points)
    np.testing.assert_allclose(rays, points / np.linalg.norm(points, axis=1)[:, None])
    np.testing.assert_allclose(ranges, np.linalg.norm(points, axis=1))
    # straight ahead: the near side at x = 2.5, along a ray that rises 0.7 over 4
    assert front[0] == pytest.approx(2.5 * np.hypot(4.0, 0.7) / 4.0, rel=1e-12)
    gap = 3.0 * np.sin(np.arctan2(2.0, 3.0))
    assert gap > 0.5  # (premise: the second ray misses)
    assert front[1] == pytest.approx(3.0 * np.cos(np.arctan2(2.0, 3.0)), rel=1e-12)
    assert hit.tolist() == [True, False]


def test_a_ball_met_from_a_start_off_the_origin_and_from_inside():
    ball = Sphere(center=[0.0, 5.0, 0.0], radius=1.0, rms=0.0, inliers=0)
    points = np.array([[0.0, 7.0, 0.0], [0.0, 7.0, 0.0]])
    starts = np.array([[0.0, 1.0, 0.0], [0.0, 5.0, 0.0]])  # the second start inside the ball
    _, ranges, front, hit = front_along_rays(ball, points, starts)
    np.testing.assert_allclose(ranges, [6.0, 2.0])
    assert front[0] == pytest.approx(3.0) and hit[0]
    assert front[1] == pytest.approx(-1.0) and not hit[1]  # the near crossing lies behind the start


def test_a_plane_has_no_front_to_meet():
    with pytest.raises(ValueError, match="model must be a Cylinder or a Sphere; got Plane"):
        front_along_rays(Plane(normal=np.array([0.0, 0.0, 1.0]), d=1.0, rms=0.0, inliers=0), np.ones((2, 3)))
