"""Two pieces of one far wall that something nearer cuts apart on a stereo camera's grid, each
under a tile model turned from the wall's, join across the occluder
(rangeseg_o3d.occluded_planes.join_across_occluders); a parallel face a few range sigmas behind,
or two coplanar pieces with a farther surface between them, stay apart."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.primitives import Plane
from rangeseg_o3d.fullres import region_stats
from rangeseg_o3d.occluded_planes import join_across_occluders
from rangeseg_o3d.result import INLIER_SIGMAS
from rangeseg_o3d.synthetic.depth_camera import _unit_noise

#: a stereo camera's range noise per squared metre (the sensor matrix's stereo row)
COEFF = 0.1 / (640 * 0.05)
CORRELATION = 3  # its matching window, pixels square


def _wall_behind_a_post(seed, *, post_z=3.0, offset_sigmas=0.0, band_sigmas=0.0, turn_deg=8.0, z=5.0, rows=120,
                        cols=160, f=640.0):
    """A head-on wall at ``z`` (5 m: range sigma ~0.08 m a pixel, erring together over 3 x 3
    pixels) seen beside a post at ``post_z`` over columns 70-89 (region 2, its own plane). The
    wall's pieces left (region 1, columns 0-69) and right (region 3, columns 90-159) have tile
    models turned ``turn_deg`` about the vertical, one each way. ``offset_sigmas`` moves the right
    piece's returns that many range sigmas back along their rays (a face of its own), and
    ``band_sigmas`` its rows 60-119 that many range sigmas back and forth, row by row (returns
    of other surfaces the piece's region holds, beyond the noise but not off its plane on the
    whole). Returns
    ``(cloud, labels, fits, stats, sigma)``."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / f, (v - rows / 2) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    normal = np.array([0.0, 0.0, 1.0])
    post = (u >= 70) & (u < 90)
    right = u >= 90
    ranges = np.where(post, post_z, z) / (rays @ normal)
    sigma = COEFF * ranges ** 2
    scatter = np.where(v % 2 == 0, band_sigmas, -band_sigmas) * sigma
    ranges = ranges + np.where(right, offset_sigmas * sigma, 0.0) + np.where(right & (v >= 60), scatter, 0.0)
    noisy = ranges + _unit_noise(np.random.default_rng(seed), ranges.shape, CORRELATION) * sigma
    xyz = rays * noisy[..., None]
    labels = np.where(post, 2, np.where(right, 3, 1)).astype(np.int32)
    fits = {2: Plane(normal=normal, d=post_z, rms=0.0, inliers=1)}
    for k, sign in ((1, 1.0), (3, -1.0)):
        turn = np.radians(sign * turn_deg)
        tilted = np.array([np.sin(turn), 0.0, np.cos(turn)])
        fits[k] = Plane(normal=tilted, d=float(tilted @ xyz[labels == k].mean(axis=0)), rms=0.0, inliers=1)
    cloud = rs.OrganizedCloud(xyz)
    return cloud, labels, fits, region_stats(cloud.xyz, labels, fits, sigma, INLIER_SIGMAS), sigma


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_pieces_of_a_wall_behind_a_post_join_under_their_joint_plane(seed):
    cloud, labels, fits, stats, sigma = _wall_behind_a_post(seed)
    out, out_fits, out_stats = join_across_occluders(cloud, labels, fits, stats, sigma=sigma,
                                                     inlier_factor=INLIER_SIGMAS, correlation_px=CORRELATION)
    # the pieces are the same size (8400 px): the first label keeps the wall, the post stays
    assert set(out_fits) == {1, 2} and out_fits[2] is fits[2]
    assert np.all(out[labels != 2] == 1) and np.all(out[labels == 2] == 2)
    # the wall's model is the plane of both pieces, not either turned tile model
    wall = out_fits[1]
    assert np.degrees(np.arccos(abs(wall.normal[2]))) < 1.0 and abs(abs(wall.d) - 5.0) < 0.05
    assert out_stats.counts[1] == np.count_nonzero(labels != 2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_parallel_face_one_range_sigma_behind_stays_apart(seed):
    # one plane tilted between the two fits both within 0.1 chi-square a pixel (the growth,
    # 670-870 over the two 8400-px pieces on seeds 0 and 1, is under one a pixel), but over
    # their ~1870 independent returns that is 74-96 against the 12.8 noise allows
    cloud, labels, fits, stats, sigma = _wall_behind_a_post(seed, offset_sigmas=1.0)
    out, out_fits, out_stats = join_across_occluders(cloud, labels, fits, stats, sigma=sigma,
                                                     inlier_factor=INLIER_SIGMAS, correlation_px=CORRELATION)
    assert out is labels and out_fits is fits and out_stats is stats


@pytest.mark.parametrize("seed", [0, 1])
def test_coplanar_pieces_with_a_farther_surface_between_them_stay_apart(seed):
    # the strip between lies 3 m behind the pieces' plane: nothing there hides the wall
    cloud, labels, fits, stats, sigma = _wall_behind_a_post(seed, post_z=8.0)
    out, out_fits, _ = join_across_occluders(cloud, labels, fits, stats, sigma=sigma,
                                             inlier_factor=INLIER_SIGMAS, correlation_px=CORRELATION)
    assert out is labels and out_fits is fits


def test_a_piece_holding_returns_beyond_the_noise_does_not_widen_the_test():
    # a face 0.3 sigma behind the wall whose rows 60-119 scatter 3 sigmas back and forth: its
    # chi-square grows by ~330 joined to the wall, over the 115 the noise allows their ~1870
    # independent returns. The scatter raises its own residuals 5-fold: taken as the noise's
    # variance they would allow 365, and it would join
    cloud, labels, fits, stats, sigma = _wall_behind_a_post(0, offset_sigmas=0.3, band_sigmas=3.0)
    out, out_fits, _ = join_across_occluders(cloud, labels, fits, stats, sigma=sigma,
                                             inlier_factor=INLIER_SIGMAS, correlation_px=CORRELATION)
    assert out is labels and out_fits is fits
