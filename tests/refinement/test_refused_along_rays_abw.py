"""recover.fits_refused_along_rays: the planes recover_pixels refuses are fitted along their
pixels' rays where the depths come in steps (ABW's 8-bit structured light) as where a stereo
camera's noise errs over its matching window; on a grazing face simulated as the tabletop_abw
row simulates ABW's camera whose blob holds a
few pixels of its neighbour, that fit finds the face the least-squares plane missed."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.config import load_config
from rangeseg_o3d.fitting.primitives import Plane
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.refinement.recover import fits_refused_along_rays, planes_fitted_along_rays
from rangeseg_o3d.sensor import NoiseModel, Sensor

LABEL = 7
SIGMA = 0.0005    # the tabletop_abw row's range noise (m): 0.25 mm of noise and the depth steps
STEP = 0.00126    # ABW's depth step (m)
F = 1586.0        # ABW's |F| (pixels)


def test_which_sensors_fit_refused_planes_along_the_rays():
    assert fits_refused_along_rays(Sensor(noise=NoiseModel(sigma0=SIGMA), depth_step=STEP))
    assert fits_refused_along_rays(rs.Pipeline(load_config("configs/abw.yaml")).sensor)
    stereo = NoiseModel(sigma0=0.001, sigma_quadratic=0.003, correlation_px=3)
    assert fits_refused_along_rays(Sensor(noise=stereo))
    # a laser's single returns, a Kinect-type camera (noise growing with range, pixel by pixel)
    assert not fits_refused_along_rays(Sensor(noise=NoiseModel(sigma0=0.005)))
    assert not fits_refused_along_rays(Sensor(noise=NoiseModel(sigma0=0.001, sigma_quadratic=0.0014)))
    assert not fits_refused_along_rays(rs.Pipeline("rgbd_vga").sensor)


def _grazing_face(seed, *, incidence_deg=88.0, rows=40, cols=4, foreign=3, z=0.9):
    """A face ``cols`` columns wide seen ``incidence_deg`` from head-on (its normal turned about
    the vertical) at depth ``z``, ABW's pinhole, depths quantised in STEP and noisy by SIGMA along
    the rays; the first ``foreign`` pixels of the last column are a neighbour's, 1.5 mm off the
    face (a block's top face beside the crease). Returns ``(cloud, sigma, normal, foreign_mask)``."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / F, (v - rows / 2) / (F * 1.45), np.ones((rows, cols))])
    turn = np.radians(incidence_deg)
    normal = np.array([np.sin(turn), 0.0, np.cos(turn)])
    depth = (normal[2] * z) / (rays @ normal)           # z along each ray (rays have z = 1)
    depth = depth + np.random.default_rng(seed).normal(scale=0.25e-3, size=depth.shape)
    depth = np.round(depth / STEP) * STEP               # the 8-bit depth byte: steps along the rays
    xyz = rays * depth[..., None]
    mask = np.zeros((rows, cols), bool)
    mask[:foreign, -1] = True
    xyz[mask] -= 0.0015 * normal                        # a neighbouring face's pixels, 1.5 mm off the face
    ranges = np.linalg.norm(xyz, axis=2)
    return rs.OrganizedCloud(xyz), np.full(ranges.shape, SIGMA), normal, mask


def _least_squares_plane(points):
    centre = points.mean(axis=0)
    normal = np.linalg.svd(points - centre, full_matrices=False)[2][-1]
    normal = normal if normal @ centre > 0 else -normal
    d = float(normal @ centre)
    return Plane(normal=normal, d=d, rms=float(np.sqrt(np.mean((points @ normal - d) ** 2))), inliers=len(points))


def _degrees(a, b):
    return float(np.degrees(np.arccos(min(1.0, abs(float(a @ b))))))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_grazing_face_holding_a_neighbours_pixels_is_found_along_its_rays(seed):
    cloud, sigma, normal, foreign = _grazing_face(seed)
    ctx = Context(cloud, rs.Pipeline(load_config("configs/abw.yaml")).fitter, sigma, 80)
    labels = np.full(cloud.valid.shape, LABEL, np.int32)
    pool = np.arange(labels.size)
    first = _least_squares_plane(cloud.xyz.reshape(-1, 3))
    # the neighbour's 3 pixels pull the least-squares plane beyond the noise of its distances
    assert ctx.plane_along_rays(first, pool)
    fits = {LABEL: first}
    new = dict(fits)
    assert planes_fitted_along_rays(ctx, labels, fits, new, {LABEL}, pool) == set()
    plane = fits[LABEL]
    assert new[LABEL] is plane and plane.kind == "plane"
    assert _degrees(plane.normal, normal) < 1.0
    # the neighbour's pixels go free, the face keeps every one of its own
    assert (labels[foreign] == 0).all()
    assert (labels[~foreign] == LABEL).all()
    assert not ctx.plane_along_rays(plane, np.flatnonzero(labels == LABEL))
