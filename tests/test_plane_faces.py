"""Plane and cylinder regions holding two faces of a far box, split at full resolution
(rangeseg_o3d.plane_faces): the crease line, the planes fitted along the rays, the gate, a
split piece joining the plane it continues, a cylinder or a sphere against two planes by their misfit
patterns, a region of three faces cut twice, a region no model fitted cut into its faces."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.plane import fit_plane
from rangeseg_o3d.fitting.cylinder import fit_cylinder
from rangeseg_o3d.fitting.primitives import Cylinder, FitFailure, Sphere
from rangeseg_o3d.fitting.sphere import fit_sphere
from rangeseg_o3d.plane_faces import (FACE_RETURNS, LINE_SEARCH_PIXELS, PATTERN_RATIO, PLANES_COVER, _continued_plane,
                                      faces_of_faces, _faces_of_leaves,
                                      misfit_patterns, _curved_residuals, crease_line, faces_of_curved, faces_of_plane, faces_of_unfitted)
from rangeseg_o3d.ray_planes import ray_fits, ray_moments, ray_plane, ray_terms
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.synthetic.depth_camera import _unit_noise

#: a stereo camera's range noise per squared metre (the sensor matrix's stereo row)
COEFF = 0.1 / (640 * 0.05)


def _box_corner(seed, *, rows=150, cols=60, crease=22, z=4.0, turn_deg=10.0, f=640.0, correlation=1):
    """A far box corner: left of column ``crease`` a face turned ``turn_deg`` from head-on,
    right of it the face at 90 degrees to it (near grazing), both through the vertical
    line the crease column's rays meet at depth ``z``; range noise ``COEFF r^2`` along
    the rays, with ``correlation`` > 1 erring together over that many pixels square (box means
    of independent draws, as the sensor matrix's stereo row simulates them). Returns ``(xyz, sigma, truth,
    normals)``, truth 0 / 1 per pixel."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - crease) / f, (v - rows / 2) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    turn = np.radians(turn_deg)
    normals = [np.array([-np.sin(turn), 0.0, -np.cos(turn)]), np.array([np.cos(turn), 0.0, -np.sin(turn)])]
    on_line = np.array([0.0, 0.0, z])  # the crease passes through it (vertical)
    truth = (u >= crease).astype(np.int64)
    ranges = np.empty((rows, cols))
    for k, normal in enumerate(normals):
        d = float(normal @ on_line)
        hit = d / (rays @ normal)
        ranges[truth == k] = hit[truth == k]
    sigma = COEFF * ranges ** 2
    noisy = ranges + _unit_noise(np.random.default_rng(seed), ranges.shape, correlation) * sigma
    return rays * noisy[..., None], sigma, truth, normals


def _context(xyz, sigma, min_size=40):
    cloud = rs.OrganizedCloud(xyz)
    return Context(cloud, rs.Pipeline("rgbd_vga").fitter, sigma, min_size)


def test_a_plane_fitted_along_the_rays_recovers_a_narrow_head_on_face_orthogonal_least_squares_tilts():
    xyz, sigma, truth, normals = _box_corner(3)
    face = truth.ravel() == 0
    points, noise = xyz.reshape(-1, 3)[face], sigma.ravel()[face]
    _, a = ray_fits(ray_moments(*ray_terms(points, noise)))
    along = ray_plane(a[0], points)
    tilt = np.degrees(np.arccos(min(1.0, abs(float(along.normal @ normals[0])))))
    orthogonal = np.degrees(np.arccos(min(1.0, abs(float(fit_plane(points).normal @ normals[0])))))
    assert tilt < 3.0 and orthogonal > 2.0 * tilt


def test_the_crease_line_cuts_a_far_box_corner_into_its_two_faces():
    xyz, sigma, truth, _ = _box_corner(5)
    ctx = _context(xyz, sigma)
    idx = np.arange(truth.size)
    _, sides = crease_line(ctx, idx)
    assert len(sides) == 2
    for side in sides:
        share = np.bincount(truth.ravel()[side], minlength=2).max() / side.size
        assert share > 0.95


def test_a_large_regions_line_is_searched_on_a_subsample_and_drawn_through_every_pixel():
    # 300 x 200 = 60 000 pixels, above LINE_SEARCH_PIXELS: the line comes from a subsample
    xyz, sigma, truth, _ = _box_corner(7, rows=300, cols=200, crease=80)
    ctx = _context(xyz, sigma)
    idx = np.arange(truth.size)
    assert idx.size > 2 * LINE_SEARCH_PIXELS
    chi2, sides, order = crease_line(ctx, idx, with_order=True)
    assert sorted(np.concatenate(sides).tolist()) == idx.tolist()  # every pixel on one side
    for side in sides:
        share = np.bincount(truth.ravel()[side], minlength=2).max() / side.size
        assert share > 0.99
    # the chi-square is that of every pixel's two planes along the rays, not the subsample's
    points, noise = xyz.reshape(-1, 3), sigma.ravel()
    every = sum(float(ray_fits(ray_moments(*ray_terms(points[s], noise[s])))[0][0]) for s in sides)
    assert chi2 == pytest.approx(every, rel=1e-6)  # the same sums in another order
    # about one unit of noise per pixel: the two faces' planes explain them
    assert 0.8 < chi2 / idx.size < 1.2
    assert np.array_equal(np.sort(idx[order[: sides[0].size]]), sides[0])


def _assert_the_two_faces(surfaces, truth, normals, share):
    # two pieces, each at least ``share`` of one face, its plane within 5 degrees of that face's
    assert len(surfaces) == 2
    for piece, plane in surfaces:
        k = int(np.bincount(truth.ravel()[piece], minlength=2).argmax())
        assert np.count_nonzero(truth.ravel()[piece] == k) > share * piece.size
        assert np.degrees(np.arccos(min(1.0, abs(float(plane.normal @ normals[k]))))) < 5.0


def test_faces_of_plane_splits_the_merged_plane_of_a_far_box_corner_and_leaves_one_face_alone():
    xyz, sigma, truth, normals = _box_corner(11)
    ctx = _context(xyz, sigma)
    idx = np.arange(truth.size)
    merged = fit_plane(xyz.reshape(-1, 3))
    _assert_the_two_faces(faces_of_plane(ctx, merged, idx, correlation_px=3), truth, normals, 0.95)
    # one face alone: no split
    one = np.flatnonzero(truth.ravel() == 1)
    assert faces_of_plane(ctx, fit_plane(xyz.reshape(-1, 3)[one]), one, correlation_px=3) == []


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_far_corner_under_a_matching_windows_noise_is_split_though_no_pixel_is_beyond_it(seed):
    # at 5.8 m a stereo camera's range noise (105 mm, erring together over 3 x 3 pixels) hides
    # the corner pixel by pixel: no connected piece of the stereo row's floor (288 pixels) is
    # beyond 4 sigmas of the merged plane. Over the faces' independent returns (a ninth of
    # their pixels) the merged plane is far beyond the noise, and the faces come apart
    from rangeseg_o3d.fitting.robust import distance_noise
    from rangeseg_o3d.plane_faces import _off_model
    from rangeseg_o3d.refinement.facets import _holds_another

    xyz, sigma, truth, normals = _box_corner(seed, cols=100, crease=40, z=5.8, turn_deg=25.0, correlation=3)
    ctx = _context(xyz, sigma, min_size=288)
    idx = np.arange(truth.size)
    points = xyz.reshape(-1, 3)
    merged = fit_plane(points)
    distances = merged.distances(points)
    rms = float(np.sqrt(np.mean(distances ** 2)))
    assert not _holds_another(ctx, merged, idx, distances, rms, count_outliers=False)  # pixel by pixel
    # the same answer from the noise faces_of_plane computes once for both gates
    noise = distance_noise(merged, points, ctx.sigma[idx])
    assert not _holds_another(ctx, merged, idx, distances, rms, count_outliers=False, noise=noise)
    assert _off_model(distances, noise, idx.size / 9.0) and not _off_model(distances, noise, 1.0)
    assert faces_of_plane(ctx, merged, idx, correlation_px=1) == []  # returns erring alone: that test only
    _assert_the_two_faces(faces_of_plane(ctx, merged, idx, correlation_px=3), truth, normals, 0.9)
    # each face alone, with its plane along the rays: within the noise, no split
    for k in (0, 1):
        one = np.flatnonzero(truth.ravel() == k)
        assert faces_of_plane(ctx, _ray_fitted(xyz, sigma, one), one, correlation_px=3) == []


def _face_with_a_step(seed, *, rows=150, cols=100, z=5.8, step=0.3, patch=(30, 20), f=640.0, correlation=3):
    """A far face turned 10 degrees from head-on whose top right corner (``patch`` rows x
    columns) is a parallel surface ``step`` metres behind it; the stereo row's range noise,
    erring together over ``correlation`` pixels square. Returns ``(xyz, sigma, truth)``."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / f, (v - rows / 2) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    normal = np.array([-np.sin(np.radians(10.0)), 0.0, -np.cos(np.radians(10.0))])
    truth = ((v < patch[0]) & (u >= cols - patch[1])).astype(np.int64)
    ranges = np.empty((rows, cols))
    for k, behind in ((0, 0.0), (1, step)):
        hit = float(normal @ np.array([0.0, 0.0, z + behind])) / (rays @ normal)
        ranges[truth == k] = hit[truth == k]
    sigma = COEFF * ranges ** 2
    unit = _unit_noise(np.random.default_rng(seed), ranges.shape, correlation)
    return rays * (ranges + unit * sigma)[..., None], sigma, truth


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_far_face_with_a_corner_of_another_surface_is_not_cut_where_the_sides_misfit_their_planes(seed, monkeypatch):
    # one face at 5.8 m with a 30 x 20 pixel corner of a surface 0.3 m behind it: the merged
    # plane is beyond the noise over the independent returns, but no straight line cuts the
    # corner off; the best one cuts a piece of the face with it, whose plane along the rays
    # leaves that piece beyond the range noise: no split
    import rangeseg_o3d.plane_faces as plane_faces

    xyz, sigma, truth = _face_with_a_step(seed)
    ctx = _context(xyz, sigma, min_size=288)
    idx = np.arange(truth.size)
    merged = fit_plane(xyz.reshape(-1, 3))
    assert faces_of_plane(ctx, merged, idx, correlation_px=3) == []
    # without the sides' test the face is cut: a piece mostly of the face goes with the corner
    monkeypatch.setattr(plane_faces, "_within_noise_along_rays", lambda *args: True)
    surfaces = faces_of_plane(ctx, merged, idx, correlation_px=3)
    assert len(surfaces) == 2
    corner_piece = max(surfaces, key=lambda s: np.count_nonzero(truth.ravel()[s[0]]))[0]
    assert np.count_nonzero(truth.ravel()[corner_piece] == 0) > 0.5 * corner_piece.size


def _ray_fitted(xyz, sigma, idx):
    points = xyz.reshape(-1, 3)[idx]
    _, a = ray_fits(ray_moments(*ray_terms(points, sigma.ravel()[idx])))
    return ray_plane(a[0], points)


def test_a_split_piece_on_a_touching_plane_joins_it_and_a_face_at_an_angle_does_not():
    # the grazing face (truth 1) is a region of its own but for a strip of columns beside the
    # crease, which a split left as a piece; the head-on face (truth 0) is the other piece
    xyz, sigma, truth, _ = _box_corner(7)
    ctx = _context(xyz, sigma)
    cols = np.arange(truth.size) % truth.shape[1]
    strip = np.flatnonzero((truth.ravel() == 1) & (cols < 30))
    wall = np.flatnonzero((truth.ravel() == 1) & (cols >= 30))
    face = np.flatnonzero(truth.ravel() == 0)
    labels = np.zeros(truth.shape, np.int32)
    labels.ravel()[wall] = 4
    fits = {4: _ray_fitted(xyz, sigma, wall)}
    walls = {}
    assert _continued_plane(ctx, labels, fits, strip, _ray_fitted(xyz, sigma, strip), walls) == 4
    # the face at 90 degrees touches the strip, not the wall: with the strip on the wall's
    # label it touches the wall and is still left apart
    labels.ravel()[strip] = 4
    walls.clear()
    assert _continued_plane(ctx, labels, fits, face, _ray_fitted(xyz, sigma, face), walls) == 0
    # a label in ``skip`` is never offered
    assert _continued_plane(ctx, labels, fits, strip, _ray_fitted(xyz, sigma, strip), {}, skip={4}) == 0


def _pipe(seed, *, rows=150, cols=80, z=4.0, radius=0.15, f=640.0):
    """A vertical pipe of ``radius`` whose axis passes ``z`` ahead of the camera, range noise
    ``COEFF r^2`` along the rays: ``(xyz, sigma, idx, cylinder)``, ``idx`` the flat pixels on
    it (others at the origin)."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / f, (v - rows / 2) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    centre, axis = np.array([0.0, 0.0, z]), np.array([0.0, 1.0, 0.0])
    across = rays - (rays @ axis)[..., None] * axis
    a = np.sum(across * across, axis=2)
    b = -2.0 * across @ centre
    disc = b * b - 4.0 * a * (centre @ centre - radius ** 2)
    hit = disc >= 0
    ranges = np.where(hit, (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a), 0.0)
    sigma = np.where(hit, COEFF * ranges ** 2, 1.0)
    noisy = ranges + np.random.default_rng(seed).normal(0.0, 1.0, ranges.shape) * np.where(hit, sigma, 0.0)
    return (rays * noisy[..., None], sigma, np.flatnonzero(hit.ravel()),
            Cylinder(axis=axis, point=centre, radius=radius, rms=0.0, inliers=0))


@pytest.mark.parametrize("fit, kind", [(fit_cylinder, Cylinder), (fit_sphere, Sphere)])
def test_a_cylinder_or_sphere_over_a_far_box_corner_gives_way_to_its_two_faces(fit, kind):
    # (a sphere: kinect_real_640x480 seed 1105 scan 0, a box's faces 5.6 m away were one
    # sphere region of the tile grid)
    xyz, sigma, truth, normals = _box_corner(5, z=5.0)
    model = fit(xyz.reshape(-1, 3))
    assert isinstance(model, kind)  # the tile grid's view: one curved model over both faces
    ctx = _context(xyz, sigma)
    curved, planes, inliers, _, _ = misfit_patterns(ctx, model, np.arange(truth.size), 1)
    assert curved > PATTERN_RATIO * planes and inliers[1] > PLANES_COVER
    surfaces = faces_of_curved(ctx, model, np.arange(truth.size))
    assert len(surfaces) == 2
    for piece, plane in surfaces:
        k = int(np.bincount(truth.ravel()[piece], minlength=2).argmax())
        assert np.count_nonzero(truth.ravel()[piece] == k) > 0.95 * piece.size
        assert np.degrees(np.arccos(min(1.0, abs(float(plane.normal @ normals[k]))))) < 5.0


def test_a_far_pipe_keeps_its_cylinder_right_or_fitted_a_little_off():
    # two planes fit a far pipe's pixels about as closely as its cylinder, and closer than a
    # cylinder fitted with a radius 16 % short: their misfit patterns keep it a cylinder
    xyz, sigma, idx, model = _pipe(3)
    ctx = _context(xyz, sigma)
    fitted = fit_cylinder(xyz.reshape(-1, 3)[idx])
    assert isinstance(fitted, Cylinder)
    for cylinder in (model, fitted):
        assert faces_of_curved(ctx, cylinder, idx) == []
    assert faces_of_curved(ctx, fit_plane(xyz.reshape(-1, 3)[idx]), idx) == []  # a plane is no cylinder


def _ball(seed, *, rows=120, cols=120, z=4.0, radius=0.3, f=640.0):
    """A ball of ``radius`` whose centre lies ``z`` ahead of the camera, range noise ``COEFF
    r^2`` along the rays: ``(xyz, sigma, idx, sphere)`` as :func:`_pipe` gives them."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / f, (v - rows / 2) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    centre = np.array([0.0, 0.0, z])
    along = rays @ centre
    disc = along * along - centre @ centre + radius ** 2
    hit = disc >= 0
    ranges = np.where(hit, along - np.sqrt(np.maximum(disc, 0.0)), 0.0)
    sigma = np.where(hit, COEFF * ranges ** 2, 1.0)
    noisy = ranges + np.random.default_rng(seed).normal(0.0, 1.0, ranges.shape) * np.where(hit, sigma, 0.0)
    return (rays * noisy[..., None], sigma, np.flatnonzero(hit.ravel()),
            Sphere(center=centre, radius=radius, rms=0.0, inliers=0))


def test_sphere_residuals_are_range_errors_along_the_rays_in_noise_units():
    centre, radius = np.array([0.3, -0.2, 4.0]), 0.5
    sphere = Sphere(center=centre, radius=radius, rms=0.0, inliers=0)
    rays = np.array([[0.3, -0.2, 4.0], [0.35, -0.2, 4.0], [2.0, 0.0, 4.0]])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    along = rays @ centre
    near = along - np.sqrt(np.maximum(along ** 2 - centre @ centre + radius ** 2, 0.0))
    assert near[0] == pytest.approx(np.linalg.norm(centre) - radius)
    sigma = np.array([0.02, 0.05, 0.01])
    moved = np.array([0.03, -0.1, 0.0])
    got = _curved_residuals(sphere, rays * (near + moved)[:, None], sigma)
    # on the two rays that meet it: the move along the ray over the noise; the third ray
    # passes by, and is measured from its closest approach to the centre
    assert got[:2] == pytest.approx(moved[:2] / sigma[:2], rel=1e-9)
    assert along[2] ** 2 < centre @ centre - radius ** 2
    assert got[2] == pytest.approx((near[2] - along[2]) / sigma[2], abs=1e-9)


def test_a_far_boxs_faces_the_tile_grid_fitted_as_one_sphere_are_planes_in_the_end():
    # kinect_real_640x480 seed 1105 scan 0: a box 5.6-5.7 m away (faces of 389, 3908 and
    # 906 px) was one sphere region of 4873 px; its largest face is a plane region now
    from matrix_helpers import matrix_result, region_holding

    scan, result = matrix_result("kinect_real_640x480", 1105, 0)
    kinds = {f.label: f.kind for f in result.features}
    face = scan.truth_ids == 13
    label, count = region_holding(result.labels, face)
    assert kinds.get(label) == "plane" and count >= 0.9 * face.sum()
    assert (result.labels == label).sum() <= 1.15 * face.sum()
    for other in (11, 13, 15):  # no sphere holds a face of the box
        label, _ = region_holding(result.labels, scan.truth_ids == other)
        assert kinds.get(label) != "sphere"


@pytest.mark.parametrize("crease", [0, 60])
def test_a_sphere_over_one_far_face_leaves_it_whole(crease):
    # two planes across any line beat a sphere's misfit on one face too (kinect_real seed 1106
    # scan 1: a face of 1465 px was cut in two): a region one plane explains along the rays
    # is left to the steps that decide its kind
    xyz, sigma, truth, normals = _box_corner(5, z=5.0, crease=crease)
    assert np.unique(truth).size == 1  # one face: the grazing one (crease 0) or the near head-on one
    points = xyz.reshape(-1, 3)
    normal = normals[int(truth.flat[0])]
    centre = points.mean(axis=0) - 2.0 * normal * np.sign(normal @ points.mean(axis=0))  # on the camera's side
    sphere = Sphere(center=centre, radius=float(np.median(np.linalg.norm(points - centre, axis=1))), rms=0.0,
                    inliers=0)
    assert faces_of_curved(_context(xyz, sigma), sphere, np.arange(truth.size)) == []


@pytest.mark.parametrize("seed", [3, 4])
def test_a_far_ball_keeps_its_sphere(seed):
    xyz, sigma, idx, model = _ball(seed)
    ctx = _context(xyz, sigma)
    fitted = fit_sphere(xyz.reshape(-1, 3)[idx])
    assert isinstance(fitted, Sphere)
    for sphere in (model, fitted):
        assert faces_of_curved(ctx, sphere, idx) == []


def _corner_regions(labels_from, turn_deg=5.0):
    # a far box corner (face 0 head-on, face 1 near grazing) labelled: region 1 face 0 and
    # face 1's first ``labels_from`` columns beside the crease, region 2 the rest of face 1;
    # their models the true planes; returns what claim_along_rays takes
    from rangeseg_o3d.fitting.primitives import Plane
    from rangeseg_o3d.fullres import region_stats
    from rangeseg_o3d.result import INLIER_SIGMAS

    xyz, sigma, truth, normals = _box_corner(5, turn_deg=turn_deg)
    on_line = np.array([0.0, 0.0, 4.0])
    fits = {k + 1: Plane(normal=n, d=float(n @ on_line), rms=0.0, inliers=1) for k, n in enumerate(normals)}
    cols = np.arange(truth.shape[1])[None, :].repeat(truth.shape[0], 0)
    labels = np.where((truth == 0) | (cols < 22 + labels_from), 1, 2).astype(np.int32)
    cloud = rs.OrganizedCloud(xyz)
    stats = region_stats(cloud.xyz, labels, fits, sigma, INLIER_SIGMAS)
    return cloud, labels, fits, stats, sigma, truth, cols


def test_a_grazing_face_takes_back_the_pixels_its_rays_meet_nearer_than_the_head_on_face_beside_it():
    # the head-on face's region holds face 1's 3 columns beside the crease (450 px), within
    # its noise in distances; along the rays they are nearer face 1's plane: most go back to
    # it, and the head-on face keeps its own pixels
    from rangeseg_o3d.plane_faces import claim_along_rays
    from rangeseg_o3d.result import INLIER_SIGMAS

    cloud, labels, fits, stats, sigma, truth, cols = _corner_regions(3)
    out, out_fits, out_stats = claim_along_rays(cloud, labels, fits, stats, sigma=sigma, min_size=40,
                                                inlier_factor=INLIER_SIGMAS)
    moved = (truth == 1) & (cols < 25)
    assert moved.sum() == 450 and (labels[moved] == 1).all()
    # (at the crease both planes meet a ray at the same range: its column is a coin toss,
    # the next ones go back more and more)
    assert np.mean(out[moved] == 2) > 0.6 and np.mean(out[:, 24] == 2) > 0.85
    assert np.mean(out[truth == 0] == 2) < 0.02
    assert out_stats.counts[2] == np.count_nonzero(out == 2)
    # the region that claimed reports the plane it claimed by; the other keeps its model
    assert out_fits is not fits and out_fits[1] is fits[1]
    assert abs(out_fits[2].normal @ fits[2].normal) > np.cos(np.radians(1.0))
    # (the plane's foot from the camera, the same whichever way its normal points)
    foot = out_fits[2].normal * out_fits[2].d - fits[2].normal * fits[2].d
    # within a few range-noise sigmas of the mean over the region's pixels
    assert np.linalg.norm(foot) < 5 * float(np.median(sigma[out == 2])) / np.sqrt(np.count_nonzero(out == 2))


def test_no_claim_from_a_face_not_seen_near_grazing():
    # the corner turned 20 degrees: face 1 is seen at cosine 0.34, beyond scales.GRAZING_COSINE,
    # and its region claims nothing (the step returns its inputs)
    from rangeseg_o3d.plane_faces import claim_along_rays
    from rangeseg_o3d.result import INLIER_SIGMAS

    cloud, labels, fits, stats, sigma, _, _ = _corner_regions(3, turn_deg=20.0)
    out = claim_along_rays(cloud, labels, fits, stats, sigma=sigma, min_size=40, inlier_factor=INLIER_SIGMAS)
    assert out[0] is labels and out[1] is fits and out[2] is stats


def test_a_grazing_regions_plane_along_the_rays_comes_from_its_pixels_not_its_tile_model():
    # face 1's region under a tile model that passes 1 cm from the camera (a plane along the
    # rays: none of its pixels within the noise of it) claims as under the true plane
    from rangeseg_o3d.fitting.primitives import Plane
    from rangeseg_o3d.fullres import region_stats
    from rangeseg_o3d.plane_faces import claim_along_rays
    from rangeseg_o3d.result import INLIER_SIGMAS

    cloud, labels, fits, stats, sigma, truth, cols = _corner_regions(3)
    expected = claim_along_rays(cloud, labels, fits, stats, sigma=sigma, min_size=40, inlier_factor=INLIER_SIGMAS)[0]
    along = dict(fits)
    along[2] = Plane(normal=fits[2].normal, d=0.01, rms=0.0, inliers=1)
    stats = region_stats(cloud.xyz, labels, along, sigma, INLIER_SIGMAS)
    out = claim_along_rays(cloud, labels, along, stats, sigma=sigma, min_size=40, inlier_factor=INLIER_SIGMAS)[0]
    moved = (truth == 1) & (cols < 25)
    assert np.mean(out[moved] == 2) > 0.6 and np.mean(out == expected) > 0.995
    # and the region is reported with that plane, not the tile model it came with
    model = claim_along_rays(cloud, labels, along, stats, sigma=sigma, min_size=40, inlier_factor=INLIER_SIGMAS)[1][2]
    assert abs(model.normal @ fits[2].normal) > np.cos(np.radians(1.0))
    foot = model.normal * model.d - fits[2].normal * fits[2].d
    assert np.linalg.norm(foot) < 5 * float(np.median(sigma[out == 2])) / np.sqrt(np.count_nonzero(out == 2))


def _wall_band(offset_sigmas=0.0):
    # a far box corner (face 0 turned 5 degrees from head-on, face 1 near grazing): region 1
    # face 0 but for a band of its rows 60-79 (440 px), region 3, whose model is face 1's
    # plane (seen near grazing, as a tile model bent along the band's rays); region 2 face 1.
    # ``offset_sigmas`` moves the band's returns that many range-noise sigmas back along
    # their rays (another surface behind the wall's plane)
    from rangeseg_o3d.fitting.primitives import Plane
    from rangeseg_o3d.fullres import region_stats
    from rangeseg_o3d.result import INLIER_SIGMAS

    xyz, sigma, truth, normals = _box_corner(7, turn_deg=5.0)
    rows = np.arange(truth.shape[0])[:, None].repeat(truth.shape[1], 1)
    band = (truth == 0) & (rows >= 60) & (rows < 80)
    ranges = np.linalg.norm(xyz, axis=2)
    xyz = xyz * np.where(band, 1.0 + offset_sigmas * sigma / ranges, 1.0)[..., None]
    on_line = np.array([0.0, 0.0, 4.0])
    fits = {k + 1: Plane(normal=n, d=float(n @ on_line), rms=0.0, inliers=1) for k, n in enumerate(normals)}
    fits[3] = fits[2]
    labels = np.where(band, 3, truth + 1).astype(np.int32)
    cloud = rs.OrganizedCloud(xyz)
    return cloud, labels, fits, region_stats(cloud.xyz, labels, fits, sigma, INLIER_SIGMAS), sigma, band


def test_a_band_of_a_head_on_wall_under_a_model_along_its_rays_goes_back_to_the_wall():
    # the band's plane refitted along its rays is face 0's (not seen near grazing, so it
    # claims nothing); face 0's plane keeps its pixels within their noise along the rays:
    # they go back to region 1, and region 3 is gone from the labels and the models
    from rangeseg_o3d.plane_faces import claim_along_rays
    from rangeseg_o3d.result import INLIER_SIGMAS

    cloud, labels, fits, stats, sigma, band = _wall_band()
    assert band.sum() == 440
    out, out_fits, out_stats = claim_along_rays(cloud, labels, fits, stats, sigma=sigma, min_size=40,
                                                inlier_factor=INLIER_SIGMAS, correlation_px=1)
    # (3 sigmas along the rays keep all but about 0.3 % of the returns; beside the crease
    # the grazing face then claims the pixels its rays meet nearer, as it does of the wall's)
    cols = np.arange(out.shape[1])[None, :].repeat(out.shape[0], 0)
    assert np.mean(out[band & (cols < 18)] == 1) > 0.98 and not (out == 3).any()
    assert np.all(out[band] != 0) and np.all((out[band] == 1) | (cols[band] >= 18))
    assert 3 not in out_fits and out_fits[1] is fits[1]
    assert out_stats.counts[1] == np.count_nonzero(out == 1) and out_stats.counts[2] == np.count_nonzero(out == 2)
    # the grazing face keeps its own pixels
    assert np.mean(out[labels == 2] == 2) > 0.98


def test_a_band_behind_the_walls_plane_by_several_sigmas_stays_a_region():
    # the same band moved 5 range-noise sigmas back along its rays: face 0's plane leaves
    # nearly all of it beyond 3 sigmas, and the band keeps its label
    from rangeseg_o3d.plane_faces import claim_along_rays
    from rangeseg_o3d.result import INLIER_SIGMAS

    cloud, labels, fits, stats, sigma, band = _wall_band(offset_sigmas=5.0)
    out, out_fits, _ = claim_along_rays(cloud, labels, fits, stats, sigma=sigma, min_size=40,
                                        inlier_factor=INLIER_SIGMAS, correlation_px=1)
    assert (out[band] == 3).all() and out_fits[3] is fits[3]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_split_gate_answers_as_its_numpy_form(seed):
    # _beyond_distance_noise takes the noise's sum of squares from one compiled pass: the
    # answer of numpy's distance_noise, on a far box corner (two faces: beyond) and on one face
    # alone, each counted over all its pixels and over a ninth of them
    from rangeseg_o3d.fitting.robust import beyond_noise, distance_noise
    from rangeseg_o3d.plane_faces import _beyond_distance_noise

    xyz, sigma, truth, _ = _box_corner(seed, turn_deg=20.0)
    points, noise = xyz.reshape(-1, 3), sigma.ravel()
    answers = []
    for part in (np.arange(truth.size), np.flatnonzero(truth.ravel() == 0)):
        for independent in (part.size, part.size / 9.0):
            plane = fit_plane(points[part])
            each = distance_noise(plane, points[part], noise[part])
            want = beyond_noise(plane.rms, float(np.sqrt(np.mean(each * each))), max(int(independent), 1))
            assert _beyond_distance_noise(points[part], noise[part], independent) == want
            answers.append(bool(want))
    assert answers[0] is True  # the two faces under one plane


def _folded_faces(seed, *, rows=120, creases=(30, 60), cols=90, z=4.0, turns_deg=(10.0, 75.0, 10.0), f=640.0,
                  correlation=3):
    """Three vertical faces side by side, split at the ``creases`` columns, each turned
    ``turns_deg`` about the vertical from head-on (the middle one near grazing), each meeting
    the next on its crease column's ray, the first through the point ``z`` ahead; a stereo
    camera's range noise ``COEFF r^2`` erring together over ``correlation`` pixels square.
    Returns ``(xyz, sigma, truth, normals)``, truth 0 / 1 / 2 per pixel."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / f, (v - rows / 2) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    normals = [np.array([np.sin(np.radians(t)), 0.0, -np.cos(np.radians(t))]) for t in turns_deg]
    truth = np.searchsorted(np.asarray(creases), u, side="right")
    ranges = np.empty((rows, cols))
    point = np.array([0.0, 0.0, z])
    for k, normal in enumerate(normals):
        d = float(normal @ point)
        ranges[truth == k] = (d / (rays @ normal))[truth == k]
        if k < len(creases):  # the next face passes through this one's crease line
            ray = np.array([(creases[k] - cols / 2) / f, 0.0, 1.0])
            point = ray * d / float(ray @ normal)
    sigma = COEFF * ranges ** 2
    noisy = ranges + _unit_noise(np.random.default_rng(seed), ranges.shape, correlation) * sigma
    return rays * noisy[..., None], sigma, truth, normals


def _assert_the_three_faces(surfaces, truth, normals, share, degrees):
    # a piece on each face, each at least ``share`` of one face, its plane within ``degrees`` of that face's
    assert len(surfaces) == 3
    faces = []
    for piece, plane in surfaces:
        counts = np.bincount(truth.ravel()[piece], minlength=3)
        k = int(counts.argmax())
        faces.append(k)
        assert counts[k] >= share * piece.size
        assert np.degrees(np.arccos(min(1.0, abs(float(plane.normal @ normals[k]))))) < degrees
    assert sorted(faces) == [0, 1, 2]


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_the_leaves_of_a_crease_line_through_the_middle_face_come_back_as_its_three_faces(seed):
    # the first line cuts the grazing middle face in two; each side is cut again at its own
    # crease, and the middle face's two halves, which continue one plane, are joined
    xyz, sigma, truth, normals = _folded_faces(seed, z=2.5)
    ctx = _context(xyz, sigma)
    idx = np.arange(truth.size)
    _, sides = crease_line(ctx, idx)
    assert all(np.unique(truth.ravel()[side]).size >= 2 for side in sides)  # one side holds two faces
    # two planes holding 87 % within TRIM_SIGMAS, the cylinder 60 % (as study seed 7 scan 3's region)
    surfaces = _faces_of_leaves(ctx, idx, (0.0, 0.0, (0.6, 0.87), (9.0, 2.0), sides), 3, 3.0)
    _assert_the_three_faces(surfaces, truth, normals, 0.95, 5.0)
    # a cylinder closer to the pixels it keeps within TRIM_SIGMAS than the leaves' planes: no split
    assert _faces_of_leaves(ctx, idx, (0.0, 0.0, (0.6, 0.87), (0.1, 2.0), sides), 3, 3.0) == []


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_split_piece_that_holds_two_faces_is_split_again_and_a_face_is_left_whole(seed):
    # a region's split left the first two faces in one piece (as a cylinder over a far box's
    # corner is cut along one crease line, its third face in the piece beside it: stereo
    # study seed 1293 scan 3): that piece comes back as its two faces, the third stays
    xyz, sigma, truth, normals = _folded_faces(seed, z=2.5)
    ctx = _context(xyz, sigma)
    flat = truth.ravel()
    two, one = np.flatnonzero(flat <= 1), np.flatnonzero(flat == 2)
    surfaces = faces_of_faces(ctx, [(two, _ray_fitted(xyz, sigma, two)), (one, _ray_fitted(xyz, sigma, one))],
                               9.0, 3, 3.0)
    _assert_the_three_faces(surfaces, truth, normals, 0.95, 5.0)
    assert any(piece is one for piece, _ in surfaces)  # the single face untouched
    # nor where a face would hold fewer than FACE_RETURNS independent returns
    few = faces_of_faces(ctx, [(two, _ray_fitted(xyz, sigma, two))], two.size / (2.0 * FACE_RETURNS) + 1.0, 3, 3.0)
    assert len(few) == 1 and few[0][0] is two
    # a piece under two faces' floor of pixels is not asked
    small = _context(xyz, sigma, min_size=two.size // 2 + 1)
    kept = faces_of_faces(small, [(two, _ray_fitted(xyz, sigma, two))], 9.0, 3, 3.0)
    assert len(kept) == 1 and kept[0][0] is two


def test_a_region_no_model_fitted_over_three_faces_is_cut_into_them_and_one_face_is_not():
    xyz, sigma, truth, normals = _folded_faces(2)
    ctx = _context(xyz, sigma)
    failure = FitFailure(kind="primitive", reason="no model explains it")
    _assert_the_three_faces(faces_of_unfitted(ctx, failure, np.arange(truth.size), correlation_px=3,
                                              min_angle_deg=3.0), truth, normals, 0.95, 5.0)
    one = np.flatnonzero(truth.ravel() == 0)
    assert faces_of_unfitted(ctx, failure, one, correlation_px=3, min_angle_deg=3.0) == []
    # only a region no model fitted
    assert faces_of_unfitted(ctx, fit_plane(xyz.reshape(-1, 3)), np.arange(truth.size), correlation_px=3) == []


@pytest.mark.parametrize("z", [2.5, 4.0])
def test_a_far_pipe_no_model_fitted_is_not_cut_into_facets(z):
    # its facets fit within the noise (four at 2.5 m, two at 4 m); a cylinder fits it, and
    # its misfit pattern against the planes' keeps it whole
    for seed in range(3):
        xyz, sigma, idx, _ = _pipe(seed, z=z)
        ctx = _context(xyz, sigma)
        assert faces_of_unfitted(ctx, FitFailure(kind="primitive", reason="refused"), idx, correlation_px=3,
                                 min_angle_deg=3.0) == []
