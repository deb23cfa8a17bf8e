"""Cylinders bent over a crease become the planes of their two sides
(rangeseg_o3d.crease_planes): a ridge of two box faces, a far pipe's range streaks."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.crease_planes import _sides_along_rays, planes_for_creases
from rangeseg_o3d.fitting.primitives import Cylinder, Plane
from rangeseg_o3d.fullres import region_stats
from rangeseg_o3d.result import INLIER_SIGMAS


def _ridge_and_wall(rng, sigma=0.004):
    """A 60 x 80 grid: the left half a wall at z = 2.6, the right half two box faces meeting
    along a ridge (axis y, at x = 0.4, z = 2) turned 31 deg from the view either side;
    Gaussian noise ``sigma`` along z. Labels: 1 the wall, 2 the faces."""
    h, w = 60, 80
    v, u = np.mgrid[0:h, 0:w].astype(float)
    x = (u - w / 4) * 0.01
    xyz = np.dstack([x, (v - h / 2) * 0.01, np.full((h, w), 2.6)])
    xyz[:, w // 2:, 2] = 2.0 + 0.6 * np.abs(x[:, w // 2:] - 0.4)
    xyz[..., 2] += rng.normal(0.0, sigma, (h, w))
    labels = np.zeros((h, w), np.int32)
    labels[:, : w // 2] = 1
    labels[:, w // 2:] = 2
    return xyz, labels


def _crease_fits(xyz, labels, sigma):
    # the wall's plane, and a cylinder bent over the ridge (its axis along it, tangent there)
    wall = Plane(normal=np.array([0.0, 0.0, 1.0]), d=-2.6, rms=sigma, inliers=0)
    cylinder = Cylinder(axis=[0, 1, 0], point=[0.4, 0.0, 2.3], radius=0.3, rms=0.02, inliers=0)
    fits = {1: wall, 2: cylinder}
    return fits, region_stats(xyz, labels, fits, np.full(labels.shape, sigma), INLIER_SIGMAS)


def test_planes_for_creases_gives_a_cylinder_over_a_ridge_its_two_faces():
    rng = np.random.default_rng(5)
    xyz, labels = _ridge_and_wall(rng)
    labels[20:40, 66:72] = 1  # the wall took a patch of the far face
    fits, stats = _crease_fits(xyz, labels, 0.004)
    sigma = np.full(labels.shape, 0.004)
    out, new_fits, new_stats = planes_for_creases(rs.OrganizedCloud(xyz), labels, fits, stats, sigma=sigma,
                                                  k_sigma=3.0, inlier_factor=INLIER_SIGMAS, min_size=20)
    assert labels[30, 70] == 1 and isinstance(fits[2], Cylinder)  # the inputs are not changed
    assert set(new_fits) == {1, 2, 3} and all(isinstance(m, Plane) for m in new_fits.values())
    # each face its plane: slopes of -0.6 and +0.6 in x (normals +-31 deg from the view)
    slopes = sorted(-m.normal[0] / m.normal[2] for m in (new_fits[2], new_fits[3]))
    assert slopes == pytest.approx([-0.6, 0.6], abs=0.02)
    for k in (2, 3):
        assert new_fits[k].rms < 1.2 * 0.004
    # each face's pixels under its plane, the far face's patch taken back from the wall
    left, right = out[0, 45], out[0, 75]
    assert {left, right} == {2, 3}
    assert (out[:, 40:59] == left).all() and (out[:, 62:] == right).all()  # the ridge at column 60
    assert (out[:, :40] == 1).all()
    assert new_stats.counts[right] == (out == right).sum() and new_stats.counts[1] == 40 * 60
    assert new_stats.squares[2] < 0.1 * stats.squares[2]


def _pipe_under_range_noise(rng, sigma: float, distance: float = 6.4, radius: float = 0.075):
    # a vertical pipe ahead, its visible half sampled over 300 rays, each return moved along its ray
    angles = rng.uniform(-np.pi / 2, np.pi / 2, 600)
    heights = rng.uniform(-0.4, 0.4, 600)
    points = np.column_stack([radius * np.sin(angles), heights, distance - radius * np.cos(angles)])
    rays = points / np.linalg.norm(points, axis=1, keepdims=True)
    return points + rays * rng.normal(0.0, sigma, (600, 1))


def test_sides_along_rays_tells_a_far_pipes_range_streaks_from_faces():
    rng = np.random.default_rng(7)
    cylinder = Cylinder(axis=[0, 1, 0], point=[0.0, 0.0, 6.4], radius=0.075, rms=0.08, inliers=0)
    cut = (0.0, np.array([0.0, 0.0, -1.0]), 0.04)  # the halves left and right of the ray to the axis
    # 13 cm of range noise on a 15 cm pipe (stereo at 6.4 m): two streaks along the rays
    assert _sides_along_rays(_pipe_under_range_noise(rng, 0.13), cylinder, cut, noise=0.13)
    # the same streaks judged under 5 cm of noise spread beyond it: depth of their own
    assert not _sides_along_rays(_pipe_under_range_noise(rng, 0.13), cylinder, cut, noise=0.05)
    # under 4 mm of noise the pipe's halves face the sensor: no streaks
    assert not _sides_along_rays(_pipe_under_range_noise(rng, 0.004), cylinder, cut, noise=0.004)
