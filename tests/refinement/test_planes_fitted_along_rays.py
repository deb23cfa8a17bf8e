"""recover.planes_fitted_along_rays: a blob's plane refused because the orthogonal least
squares turned it towards the rays is fitted along the rays instead, on far faces under a
stereo camera's range noise (COEFF r^2, erring together over a 3 x 3 matching window), and on
a grazing face in ABW's 8-bit depth steps whose blob holds a few pixels of its neighbour
(recover.fits_refused_along_rays: which sensors fit refused planes along the rays)."""

import numpy as np
import pytest
from scipy import ndimage

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.primitives import Plane
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.config import load_config
from rangeseg_o3d.refinement.recover import along_rays_max_cosine, fits_refused_along_rays, planes_fitted_along_rays
from rangeseg_o3d.scales import GRAZING_COSINE
from rangeseg_o3d.sensor import NoiseModel, Sensor

#: a stereo camera's range noise per squared metre (the sensor matrix's stereo row)
COEFF = 0.1 / (640 * 0.05)
LABEL = 5


def _faces(seed, *, rows=90, cols=20, crease=None, turn_deg=40.0, z=4.9, f=900.0, behind=None):
    """A face ``cols`` pixels wide at ``z`` m, its normal turned ``turn_deg`` about the
    vertical; with ``crease``, the columns from it on are a second face turned the other
    way (a convex crease); with ``behind`` (a column), the columns from it on lie 0.5 m
    further along their rays (a surface behind the face). Range noise ``COEFF r^2`` along
    the rays, the mean of a 3 x 3 window of independent errors. Returns ``(cloud, sigma,
    normal)``, ``normal`` the first face's."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / f, (v - rows / 2) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    turn = np.radians(turn_deg)
    normal = np.array([np.sin(turn), 0.0, np.cos(turn)])
    ranges = normal[2] * z / (rays @ normal)
    if crease is not None:
        other = np.array([-np.sin(turn), 0.0, np.cos(turn)])
        ranges = np.where(u >= crease, other[2] * z / (rays @ other), ranges)
    if behind is not None:
        ranges = np.where(u >= behind, ranges + 0.5, ranges)
    sigma = COEFF * ranges ** 2
    window = 3.0 * ndimage.uniform_filter(np.random.default_rng(seed).normal(size=ranges.shape), 3, mode="reflect")
    return rs.OrganizedCloud(rays * (ranges + window * sigma)[..., None]), sigma, normal


def _least_squares_plane(points):
    # the plane of least orthogonal squares, as the fitter's plane is
    centre = points.mean(axis=0)
    normal = np.linalg.svd(points - centre, full_matrices=False)[2][-1]
    normal = normal if normal @ centre > 0 else -normal
    d = float(normal @ centre)
    return Plane(normal=normal, d=d, rms=float(np.sqrt(np.mean((points @ normal - d) ** 2))), inliers=len(points))


def _refused_blob(cloud, sigma, min_size=288):
    # the whole grid as one blob, region LABEL with its least-squares plane
    ctx = Context(cloud, rs.Pipeline("rgbd_vga").fitter, sigma, min_size)
    labels = np.full(cloud.valid.shape, LABEL, np.int32)
    plane = _least_squares_plane(cloud.xyz.reshape(-1, 3))
    return ctx, labels, {LABEL: plane}, np.arange(labels.size)


def _degrees(a, b):
    return float(np.degrees(np.arccos(min(1.0, abs(float(a @ b))))))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_far_face_narrower_than_its_range_noise_takes_the_plane_along_its_rays(seed):
    cloud, sigma, normal = _faces(seed)
    ctx, labels, fits, pool = _refused_blob(cloud, sigma)
    first = fits[LABEL]
    # the least-squares plane turned towards the rays and lies beyond the noise of its distances
    assert _degrees(first.normal, normal) > 30.0
    assert ctx.plane_along_rays(first, pool)
    new = dict(fits)
    assert planes_fitted_along_rays(ctx, labels, fits, new, {LABEL}, pool) == set()
    plane = fits[LABEL]
    assert new[LABEL] is plane and plane.kind == "plane"
    # the face's own plane, within the noise of the distances, to the normal's spread over
    # about 200 independent returns 0.1 m across (about 10 degrees)
    assert _degrees(plane.normal, normal) < 15.0
    assert not ctx.plane_along_rays(plane, np.flatnonzero(labels == LABEL))
    assert (labels == LABEL).sum() > 0.97 * labels.size


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_band_over_a_crease_the_noise_resolves_stays_refused(seed):
    # two faces 20 columns wide each at 90 degrees: no one plane meets both within the noise
    cloud, sigma, _ = _faces(seed, cols=40, crease=20, turn_deg=45.0)
    ctx, labels, fits, pool = _refused_blob(cloud, sigma)
    first = fits[LABEL]
    before = labels.copy()
    new = dict(fits)
    assert planes_fitted_along_rays(ctx, labels, fits, new, {LABEL}, pool) == {LABEL}
    assert fits[LABEL] is first and new[LABEL] is first
    assert np.array_equal(labels, before)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_pixels_of_a_surface_behind_the_face_are_left_free(seed):
    # the last 2 of 22 columns lie 0.5 m behind (about 6 range sigmas): the robust fit leaves them out
    cloud, sigma, normal = _faces(seed, cols=22, behind=20)
    ctx, labels, fits, pool = _refused_blob(cloud, sigma)
    new = dict(fits)
    assert planes_fitted_along_rays(ctx, labels, fits, new, {LABEL}, pool) == set()
    assert _degrees(fits[LABEL].normal, normal) < 15.0
    free = labels == 0
    assert free[:, 20:].mean() > 0.9 and free[:, :19].mean() < 0.03


def test_a_face_under_the_size_floor_or_without_pixels_stays_refused():
    cloud, sigma, _ = _faces(0)
    # the face's pixels are fewer than the floor
    ctx, labels, fits, pool = _refused_blob(cloud, sigma, min_size=cloud.valid.size + 1)
    first = fits[LABEL]
    assert planes_fitted_along_rays(ctx, labels, fits, dict(fits), {LABEL}, pool) == {LABEL}
    assert fits[LABEL] is first
    # a refused label with no pixel in the pool, and one with too few for the robust fit
    ctx, labels, fits, pool = _refused_blob(cloud, sigma)
    first = fits[LABEL]
    assert planes_fitted_along_rays(ctx, labels, fits, dict(fits), {LABEL, 9}, pool[:0]) == {LABEL, 9}
    assert planes_fitted_along_rays(ctx, labels, fits, dict(fits), {LABEL}, pool[:10]) == {LABEL}
    assert fits[LABEL] is first and (labels == LABEL).all()



def test_labels_it_cannot_change_in_place_are_refused_with_a_value_error():
    cloud, sigma, _ = _faces(0)
    ctx, labels, fits, pool = _refused_blob(cloud, sigma)
    with pytest.raises(ValueError, match="C-ordered"):
        planes_fitted_along_rays(ctx, np.asfortranarray(labels), fits, dict(fits), {LABEL}, pool)
    with pytest.raises(ValueError, match="C-ordered"):
        planes_fitted_along_rays(ctx, labels.ravel(), fits, dict(fits), {LABEL}, pool)
    with pytest.raises(ValueError, match=r"max_cosine must be None or a cosine in \[0, 1\], got 1.5"):
        planes_fitted_along_rays(ctx, labels, fits, dict(fits), {LABEL}, pool, max_cosine=1.5)


#: the tabletop_abw row's range noise (m): 0.25 mm of noise and the depth steps
ABW_SIGMA = 0.0005
#: ABW's depth step (m) and |F| (pixels)
ABW_STEP = 0.00126
ABW_F = 1586.0


def test_which_sensors_fit_refused_planes_along_the_rays():
    assert fits_refused_along_rays(Sensor(noise=NoiseModel(sigma0=ABW_SIGMA), depth_step=ABW_STEP))
    assert fits_refused_along_rays(rs.Pipeline(load_config("configs/abw.yaml")).sensor)
    stereo = NoiseModel(sigma0=0.001, sigma_quadratic=0.003, correlation_px=3)
    assert fits_refused_along_rays(Sensor(noise=stereo))
    # a Kinect-type camera (noise growing with range, pixel by pixel) whose noise exceeds its
    # grid's footprint: 1 mm + 1.4e-3 r^2 over 0.11-degree steps (under 0.136 degrees)
    kinect = NoiseModel(sigma0=0.001, sigma_quadratic=0.0014)
    assert fits_refused_along_rays(Sensor(noise=kinect, row_spacing_deg=0.11, column_spacing_deg=0.11))
    assert fits_refused_along_rays(rs.Pipeline("rgbd_vga").sensor)
    # ...its grid step measured on the cloud where the sensor states none
    assert not fits_refused_along_rays(Sensor(noise=kinect))
    cloud, _, _ = _faces(0, rows=20, cols=20, f=1.0 / np.radians(0.11))
    assert fits_refused_along_rays(Sensor(noise=kinect), cloud)
    # a laser's single returns, constant or under its footprint (a SICK at 0.5 degrees, 3 mm + 1e-3 r^2)
    assert not fits_refused_along_rays(Sensor(noise=NoiseModel(sigma0=0.005)))
    laser = NoiseModel(sigma0=0.003, sigma_quadratic=0.001)
    assert not fits_refused_along_rays(Sensor(noise=laser, row_spacing_deg=0.5, column_spacing_deg=0.5))
    # depth steps: faces seen near grazing only (about 80.5 degrees on); stereo and the
    # Kinect-type camera: any incidence
    assert along_rays_max_cosine(Sensor(noise=NoiseModel(sigma0=ABW_SIGMA), depth_step=ABW_STEP)) == GRAZING_COSINE
    assert 0.16 < GRAZING_COSINE < 0.17
    assert along_rays_max_cosine(Sensor(noise=stereo)) is None
    assert along_rays_max_cosine(Sensor(noise=kinect, row_spacing_deg=0.11, column_spacing_deg=0.11)) is None
    assert along_rays_max_cosine(Sensor(noise=kinect)) == GRAZING_COSINE
    assert along_rays_max_cosine(Sensor(noise=kinect), cloud) is None


def _grazing_face(seed, *, incidence_deg=88.0, rows=40, cols=4, foreign=3, z=0.9):
    """A face ``cols`` columns wide seen ``incidence_deg`` from head-on (its normal turned about
    the vertical) at depth ``z``, ABW's pinhole, depths quantised in ABW_STEP steps along the
    rays after 0.25 mm of noise (as the tabletop_abw row simulates); the first ``foreign`` pixels of the last column are a neighbour's, 1.5 mm off the
    face (a block's top face beside the crease). Returns ``(cloud, sigma, normal, foreign_mask)``."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / ABW_F, (v - rows / 2) / (ABW_F * 1.45), np.ones((rows, cols))])
    turn = np.radians(incidence_deg)
    normal = np.array([np.sin(turn), 0.0, np.cos(turn)])
    depth = (normal[2] * z) / (rays @ normal)           # z along each ray (rays have z = 1)
    depth = depth + np.random.default_rng(seed).normal(scale=0.25e-3, size=depth.shape)
    depth = np.round(depth / ABW_STEP) * ABW_STEP       # the 8-bit depth byte: steps along the rays
    xyz = rays * depth[..., None]
    mask = np.zeros((rows, cols), bool)
    mask[:foreign, -1] = True
    xyz[mask] -= 0.0015 * normal                        # a neighbouring face's pixels, 1.5 mm off the face
    ranges = np.linalg.norm(xyz, axis=2)
    return rs.OrganizedCloud(xyz), np.full(ranges.shape, ABW_SIGMA), normal, mask


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


@pytest.mark.parametrize("seed", [0, 1])
def test_on_depth_steps_a_face_fitted_along_its_rays_must_be_seen_near_grazing(seed):
    # the same 88-degree face (cosine 0.035): found under the grazing bound, refused under a tighter one
    for bound, found in ((GRAZING_COSINE, True), (0.02, False)):
        cloud, sigma, normal, foreign = _grazing_face(seed)
        ctx = Context(cloud, rs.Pipeline(load_config("configs/abw.yaml")).fitter, sigma, 80)
        labels = np.full(cloud.valid.shape, LABEL, np.int32)
        first = _least_squares_plane(cloud.xyz.reshape(-1, 3))
        fits = {LABEL: first}
        kept = planes_fitted_along_rays(ctx, labels, fits, dict(fits), {LABEL}, np.arange(labels.size),
                                        max_cosine=bound)
        assert kept == (set() if found else {LABEL})
        if found:
            assert _degrees(fits[LABEL].normal, normal) < 1.0 and (labels[foreign] == 0).all()
        else:
            assert fits[LABEL] is first and (labels == LABEL).all()
