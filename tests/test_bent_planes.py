"""On a stereo camera the pipeline's last step gives a plane region that is a pipe its cylinder
(rangeseg_o3d.bent_planes.cylinders_for_bent_planes): the pipe's plane in xyz turns to the rays and
hides its bend, its inverse ranges show it; a flat face keeps its plane; labels never change."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.bent_planes import cylinder_along_rays, cylinders_for_bent_planes
from rangeseg_o3d.fitting.plane import fit_plane
from rangeseg_o3d.fitting.primitives import Cylinder, Plane
from rangeseg_o3d.fullres import region_stats
from rangeseg_o3d.result import INLIER_SIGMAS
from stereo_helpers import SHARE, stereo_pipe_scene

def _as_planes(cloud, truth, sigma):
    xyz = cloud.xyz
    fits = {k: fit_plane(xyz[truth == k]) for k in (1, 2)}
    return fits, region_stats(xyz, truth, fits, sigma, INLIER_SIGMAS)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("radius, z", [(0.15, 6.0), (0.10, 5.0)])
def test_a_pipe_held_as_a_plane_gets_its_cylinder(seed, radius, z):
    cloud, sigma, truth = stereo_pipe_scene(seed, radius=radius, z=z)
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
    cloud, sigma, truth = stereo_pipe_scene(seed, radius=0.10, z=5.0, rows=300, cols=160, recede_deg=30.0)
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
    cloud, sigma, truth = stereo_pipe_scene(seed, radius=radius, z=z, flat=True)
    fits, stats = _as_planes(cloud, truth, sigma)
    out, out_stats = cylinders_for_bent_planes(cloud, truth, fits, stats, sigma=sigma, share=SHARE,
                                               inlier_factor=INLIER_SIGMAS, max_radius=5.0)
    assert out is fits and out_stats is stats


def test_bad_inputs_are_value_errors():
    cloud, sigma, truth = stereo_pipe_scene(0)
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


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_cylinder_placed_off_the_pipe_is_placed_along_the_rays(seed):
    # a start 30 % under the pipe's radius and 3 cm off its axis, as the fitter's cylinder by the
    # points' distances comes out under a stereo camera's noise along the rays
    cloud, sigma, truth = stereo_pipe_scene(seed, radius=0.12, z=4.5)
    points, noise = cloud.xyz[truth == 1], sigma[truth == 1]
    start = Cylinder(axis=np.array([0.0, 1.0, 0.0]), point=np.array([0.03, 0.0, 4.5 + 0.084]), radius=0.084,
                     rms=0.0, inliers=len(points))
    fitted = cylinder_along_rays(start, points, noise, max_radius=5.0)
    assert isinstance(fitted, Cylinder)
    assert abs(fitted.radius - 0.12) < 0.012  # the pipe's, within a tenth
    assert abs(abs(fitted.axis[1]) - 1.0) < 0.01
    assert fitted.inliers == len(points)
    # its rms is that of the residuals along the rays, in metres: about the range noise there
    assert 0.5 * np.median(noise) < fitted.rms < 1.5 * np.median(noise)


def test_a_cylinder_along_the_rays_refuses_bad_inputs_and_too_large_a_radius():
    cloud, sigma, truth = stereo_pipe_scene(0, radius=0.12, z=4.5)
    points, noise = cloud.xyz[truth == 1], sigma[truth == 1]
    start = Cylinder(axis=np.array([0.0, 1.0, 0.0]), point=np.array([0.0, 0.0, 4.62]), radius=0.12, rms=0.0,
                     inliers=len(points))
    with pytest.raises(ValueError, match=r"\(N, 3\) points and \(N,\) noise"):
        cylinder_along_rays(start, points, noise[:-1])
    with pytest.raises(ValueError, match=r"\(N, 3\) points"):
        cylinder_along_rays(start, points[:, :2], noise)
    assert cylinder_along_rays(start, points[:5], noise[:5]) is None  # too few to place five parameters
    assert cylinder_along_rays(start, points, np.zeros_like(noise)) is None  # no noise to weigh them by
    assert cylinder_along_rays(start, points, noise, max_radius=0.05) is None  # a pipe wider than allowed
