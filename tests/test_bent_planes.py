"""On a stereo camera the pipeline's last step gives a plane region that is a pipe its cylinder
(rangeseg_o3d.bent_planes.cylinders_for_bent_planes): the pipe's plane in xyz turns to the rays and
hides its bend, its inverse ranges show it; a flat face keeps its plane; labels never change."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.bent_planes import cylinders_for_bent_planes
from rangeseg_o3d.fitting.plane import fit_plane
from rangeseg_o3d.fitting.primitives import Cylinder, Plane
from rangeseg_o3d.fullres import region_stats
from rangeseg_o3d.result import INLIER_SIGMAS
from rangeseg_o3d.synthetic.depth_camera import _unit_noise

COEFF = 0.1 / (640 * 0.05)  # the sensor matrix's stereo row: range sigma per squared metre
SHARE = 1.0 / 9.0  # independent returns a pixel carries over a 3 x 3 matching window


def _scene(seed, *, radius=0.15, z=6.0, flat=False, rows=160, cols=200, f=1000.0, recede_deg=0.0):
    """A vertical pipe (or, with ``flat``, a board as wide facing the camera) ``z`` m ahead in
    front of a wall at z + 1.5 m; stereo range noise (0.003125 r^2 a sigma) erring together over
    3 x 3 pixels. ``recede_deg`` turns the pipe's axis about the x axis, away from the camera at
    the top, by that angle from the image plane. Returns ``(cloud, sigma, truth)``: 1 the pipe or
    board, 2 the wall."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / f, (v - rows / 2) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    wall = (z + 1.5) / rays[..., 2]
    if flat:
        t = z / rays[..., 2]
        hit = np.abs(rays[..., 0] * t) <= radius
    else:  # the ray's entry into the cylinder |(t ray - p) x axis| = r
        axis = np.array([0.0, np.cos(np.radians(recede_deg)), -np.sin(np.radians(recede_deg))])
        across = rays - (rays @ axis)[..., None] * axis
        origin = -np.array([0.0, 0.0, z])
        offset = origin - (origin @ axis) * axis
        a = np.sum(across * across, axis=2)
        b = 2 * across @ offset
        c = offset @ offset - radius ** 2
        disc = b * b - 4 * a * c
        t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
        hit = disc > 0
    truth = np.where(hit, 1, 2).astype(np.int32)
    ranges = np.where(hit, t, wall)
    sigma = COEFF * ranges ** 2
    noisy = ranges + _unit_noise(np.random.default_rng(seed), ranges.shape, 3) * sigma
    return rs.OrganizedCloud(rays * noisy[..., None]), sigma, truth


def _as_planes(cloud, truth, sigma):
    xyz = cloud.xyz
    fits = {k: fit_plane(xyz[truth == k]) for k in (1, 2)}
    return fits, region_stats(xyz, truth, fits, sigma, INLIER_SIGMAS)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("radius, z", [(0.15, 6.0), (0.10, 5.0)])
def test_a_pipe_held_as_a_plane_gets_its_cylinder(seed, radius, z):
    cloud, sigma, truth = _scene(seed, radius=radius, z=z)
    fits, stats = _as_planes(cloud, truth, sigma)
    # the premise: the pipe's plane in xyz lies within the range noise (the fitter's plane test passes it)
    pipe = cloud.xyz[truth == 1]
    assert np.sqrt(np.mean(fits[1].distances(pipe) ** 2)) < np.median(sigma[truth == 1])
    out, out_stats = cylinders_for_bent_planes(cloud, truth, fits, stats, sigma=sigma, share=SHARE,
                                               inlier_factor=INLIER_SIGMAS, max_radius=5.0)
    assert isinstance(out[1], Cylinder)
    assert abs(out[1].radius - radius) < 0.01  # measured: within 0.003
    assert abs(abs(out[1].axis[1]) - 1.0) < 0.05  # vertical
    assert isinstance(out[2], Plane) and out[2] is fits[2]
    assert out_stats.counts[1] == stats.counts[1]  # labels unchanged, the pipe measured again
    assert out_stats.squares[1] != stats.squares[1]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_pipe_receding_from_the_camera_gets_its_axis(seed):
    # a pipe 30 degrees from the image plane: its longest extent seen lies across the view, and
    # its axis is that direction turned into the pipe's plane along the rays. Started unturned,
    # the refit stopped 4.1 degrees off here (and 5 degrees off, its squares above the plane's,
    # on seed 23 scan 3 of the stereo matrix, where the pipe kept its plane); turned, 0.2-0.8.
    # (seed 2's pipe fails the first gate, its plane beyond the noise along the rays)
    cloud, sigma, truth = _scene(seed, radius=0.10, z=5.0, rows=300, cols=160, recede_deg=30.0)
    fits, stats = _as_planes(cloud, truth, sigma)
    out, _ = cylinders_for_bent_planes(cloud, truth, fits, stats, sigma=sigma, share=SHARE,
                                       inlier_factor=INLIER_SIGMAS, max_radius=5.0)
    assert isinstance(out[1], Cylinder)
    assert abs(out[1].radius - 0.10) < 0.01
    axis = np.array([0.0, np.cos(np.radians(30.0)), -np.sin(np.radians(30.0))])
    assert np.degrees(np.arccos(min(1.0, abs(float(np.dot(out[1].axis, axis)))))) < 2.0


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("radius, z", [(0.15, 6.0), (0.10, 5.0)])
def test_a_flat_board_as_wide_keeps_its_plane(seed, radius, z):
    cloud, sigma, truth = _scene(seed, radius=radius, z=z, flat=True)
    fits, stats = _as_planes(cloud, truth, sigma)
    out, out_stats = cylinders_for_bent_planes(cloud, truth, fits, stats, sigma=sigma, share=SHARE,
                                               inlier_factor=INLIER_SIGMAS, max_radius=5.0)
    assert out is fits and out_stats is stats


def test_bad_inputs_are_value_errors():
    cloud, sigma, truth = _scene(0)
    fits, stats = _as_planes(cloud, truth, sigma)
    with pytest.raises(ValueError, match="share"):
        cylinders_for_bent_planes(cloud, truth, fits, stats, sigma=sigma, share=0.0,
                                  inlier_factor=INLIER_SIGMAS, max_radius=5.0)
    with pytest.raises(ValueError, match="sigma"):
        cylinders_for_bent_planes(cloud, truth, fits, stats, sigma=sigma[:-1], share=SHARE,
                                  inlier_factor=INLIER_SIGMAS, max_radius=5.0)


def test_its_arc_default_is_the_fitters():
    # the step judges a cylinder outside the fitter; called without the fitter's value it holds
    # the cylinder to the same least arc as the fitter's default configuration does
    import inspect

    from rangeseg_o3d.fitting.classify import PrimitiveFitterConfig

    default = inspect.signature(cylinders_for_bent_planes).parameters["min_arc_deg"].default
    assert default == PrimitiveFitterConfig().min_arc_deg == 30.0
