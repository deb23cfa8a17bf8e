"""On a stereo camera (NoiseModel.matched_window) the pipeline ends by settling the pixels
beside a cylinder's end cap by the rays (rangeseg_o3d.fullres.settle_caps): the band of the cap
that the pipe's region took within the noise goes back to the cap, and the pipe's pixels the
cap took go back to the pipe; a plane that is no cap takes nothing."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.primitives import Cylinder, Plane
from rangeseg_o3d.fullres import region_stats, settle_caps
from rangeseg_o3d.result import INLIER_SIGMAS
from rangeseg_o3d.synthetic.depth_camera import _unit_noise

COEFF = 0.1 / (640 * 0.05)  # the sensor matrix's stereo row: range sigma per squared metre
RADIUS = 0.2


def _capped_pipe(seed, *, rows=100, cols=240, f=640.0, z=4.0):
    """A pipe of radius 0.2 m whose end cap's centre lies 4 m straight ahead, its axis turned 60
    degrees from the rays (the cap seen at cos 0.5, as seed 3 scan 3's), the pipe running off to
    the right; range sigma 5 cm a pixel, erring together over 3 x 3 pixels. Returns
    ``(cloud, sigma, truth, fits)``, truth 1 the cap, 2 the pipe, 0 no return."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - 60) / f, (v - rows / 2) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    axis = np.array([np.sin(np.radians(60)), 0.0, np.cos(np.radians(60))])
    centre = np.array([0.0, 0.0, z])
    normal = -axis  # the cap faces the sensor
    d = float(normal @ centre)
    # the ray's entry into the infinite cylinder and its exit
    across = rays - (rays @ axis)[..., None] * axis
    off = -centre - (-centre @ axis) * axis
    a, b, c = np.sum(across * across, axis=2), 2 * (across @ off), off @ off - RADIUS ** 2
    disc = b * b - 4 * a * c
    root = np.sqrt(np.maximum(disc, 0))
    near, far = (-b - root) / (2 * a), (-b + root) / (2 * a)
    t_plane = d / (rays @ normal)
    entry = np.maximum(near, t_plane)  # the solid: the cylinder behind the cap's plane
    hit = (disc > 0) & (entry < far) & (entry > 0)
    truth = np.where(hit, np.where(t_plane > near, 1, 2), 0)
    ranges = np.where(hit, entry, np.nan)
    sigma = COEFF * np.nan_to_num(ranges) ** 2
    noisy = ranges + _unit_noise(np.random.default_rng(seed), ranges.shape, 3) * sigma
    fits = {1: Plane(normal=normal, d=d, rms=0.0, inliers=1),
            # (a fitted cylinder's point is the axis point nearest its pixels' centroid: along the pipe)
            2: Cylinder(axis=axis, point=centre + 0.5 * axis, radius=RADIUS, rms=0.0, inliers=1)}
    return rs.OrganizedCloud(rays * noisy[..., None]), sigma, truth, fits


def _rim(truth, side, width):
    """The pixels of truth ``side`` within ``width`` columns of the other side's."""
    other = 3 - side
    near = np.zeros_like(truth, bool)
    for step in range(1, width + 1):
        near[:, :-step] |= truth[:, step:] == other
        near[:, step:] |= truth[:, :-step] == other
    return near & (truth == side)


def _explained(xyz, sigma, model, mask):
    return np.mean(np.abs(model.distances(xyz[mask])) <= 3 * sigma[mask])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_caps_band_the_pipe_took_goes_back_and_the_pipes_band_the_cap_took(seed):
    cloud, sigma, truth, fits = _capped_pipe(seed)
    xyz = cloud.xyz
    cap_band, pipe_band = _rim(truth, 1, 3), _rim(truth, 2, 3)
    assert cap_band.sum() > 60 and pipe_band.sum() > 60
    # the premise: each band lies within 3 range sigmas of the other surface's model (the noise
    # cannot tell), the rays can
    assert _explained(xyz, sigma, fits[2], cap_band) > 0.9 and _explained(xyz, sigma, fits[1], pipe_band) > 0.9
    for band, wrong in ((cap_band, 2), (pipe_band, 1)):
        labels = np.where(band, wrong, truth).astype(np.int32)
        stats = region_stats(xyz, labels, fits, sigma, INLIER_SIGMAS)
        out, out_stats = settle_caps(cloud, labels, fits, stats, sigma=sigma, k_sigma=3.0,
                                     inlier_factor=INLIER_SIGMAS)
        assert np.mean(out[band] == truth[band]) > 0.95
        assert np.mean(out[truth > 0] == truth[truth > 0]) > 0.99
        assert np.mean(out[~band] == labels[~band]) > 0.995  # little else moves
        for k in (1, 2):
            assert out_stats.counts[k] == np.count_nonzero(out == k)


def test_a_plane_that_is_no_cap_takes_nothing():
    cloud, sigma, truth, fits = _capped_pipe(0)
    xyz = cloud.xyz
    band = _rim(truth, 1, 3)
    labels = np.where(band, 2, truth).astype(np.int32)
    stats = region_stats(xyz, labels, fits, sigma, INLIER_SIGMAS)
    # the same plane, but the pipe lying in front of it (the cylinder region's centroid on the
    # sensor's side of the plane: no convex solid), and a plane facing across the axis
    moved_plane = Plane(normal=fits[1].normal, d=fits[1].d + 2.0, rms=0.0, inliers=1)
    across = Plane(normal=np.array([0.0, 1.0, 0.0]), d=0.0, rms=0.0, inliers=1)
    for plane in (moved_plane, across):
        out, out_stats = settle_caps(cloud, labels, {1: plane, 2: fits[2]}, stats, sigma=sigma, k_sigma=3.0,
                                     inlier_factor=INLIER_SIGMAS)
        assert out is labels and out_stats is stats


def test_no_cylinder_or_no_plane_returns_the_inputs_and_bad_sigma_raises():
    cloud, sigma, truth, fits = _capped_pipe(0)
    labels = truth.astype(np.int32)
    stats = region_stats(cloud.xyz, labels, fits, sigma, INLIER_SIGMAS)
    for only in ({1: fits[1]}, {2: fits[2]}):
        out, out_stats = settle_caps(cloud, labels, only, stats, sigma=sigma, k_sigma=3.0, inlier_factor=INLIER_SIGMAS)
        assert out is labels and out_stats is stats
    with pytest.raises(ValueError, match="one value a pixel"):
        settle_caps(cloud, labels, fits, stats, sigma=sigma[:-1], k_sigma=3.0, inlier_factor=INLIER_SIGMAS)


def test_a_plane_in_front_of_the_pipes_middle_is_not_asked():
    # the cylinder's model point on the sensor's side of the plane (a pipe standing out of a
    # wall): no cap, though the regions' pixels alone would not say so in a crop
    cloud, sigma, truth, fits = _capped_pipe(0)
    band = _rim(truth, 1, 3)
    labels = np.where(band, 2, truth).astype(np.int32)
    stats = region_stats(cloud.xyz, labels, fits, sigma, INLIER_SIGMAS)
    pipe = fits[2]
    out, _ = settle_caps(cloud, labels, {1: fits[1], 2: Cylinder(axis=pipe.axis, point=pipe.point - 1.0 * pipe.axis,
                                                                   radius=RADIUS, rms=0.0, inliers=1)},
                         stats, sigma=sigma, k_sigma=3.0, inlier_factor=INLIER_SIGMAS)
    assert out is labels
