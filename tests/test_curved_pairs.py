"""curved_pairs: a pipe 0.3 m across at 4.5 m that a Kinect-type camera (noise 1.425e-3 z^2
correlated over 9 px, depth in 1/8-px disparity steps) leaves as two plane strips is joined
under its cylinder; a box's two faces 0.3 m wide at 5.5 m, two plane regions as well, whose
union the fitter also gives a cylinder within the noise's pattern, stay apart (their planes'
pattern is ten times smaller still), and so does the wall behind them."""

from dataclasses import replace

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.curved_pairs import JOIN_RATIO, PATTERN_BOUND, curved_from_plane_pairs
from rangeseg_o3d.fitting.primitives import Cylinder, Plane
from rangeseg_o3d.fullres import region_stats
from rangeseg_o3d.plane_faces import _within_noise_along_rays, misfit_patterns, share_near_curved
from rangeseg_o3d.ray_planes import pixel_moments, ray_fits, ray_plane
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.result import INLIER_SIGMAS
from rangeseg_o3d.sensor import NoiseModel
from rangeseg_o3d.synthetic.depth_camera import KINECT_NOISE, camera_pose_scene, simulate_depth_camera
from rangeseg_o3d.synthetic.matrix import KINECT_CORRELATION_PX, KINECT_STEP
from rangeseg_o3d.synthetic.scene import Scene, box, cylinder, patch

WALL, PIPE, BOX = 1, 2, 10  # truth ids; the box's faces are BOX + 1 .. BOX + 4 (its sides)
RADIUS = 0.15
PIPE_AT, BOX_AT, BOX_SIDE = 4.5, 5.5, 0.3
NOISE = NoiseModel(sigma0=0.001, sigma_quadratic=KINECT_NOISE, correlation_px=KINECT_CORRELATION_PX,
                   step_quadratic=KINECT_STEP)
F = 320 / np.tan(np.deg2rad(31.0))  # the matrix's Kinect: 62 degrees across 640 columns
MIN_SIZE = 288


def _scan(seed):
    # world: x ahead, y left, z up; a wall 6 m ahead, a pipe (no caps) 4 m ahead on the left,
    # a box turned by 40 degrees 4 m ahead on the right, two of its sides towards the camera
    ex, ey, ez = np.eye(3)
    parts = (patch((6.0, 0.0, 1.0), ey, ez, 3.5, 2.0, first_id=WALL)
             + cylinder((PIPE_AT + RADIUS, 0.7, 0.6), (0, 0, 1), RADIUS, 0.8, caps=False, first_id=PIPE)
             + box((BOX_AT, -0.7, 1.0), (BOX_SIDE, BOX_SIDE, 0.5), yaw=np.deg2rad(40.0), first_id=BOX))
    scene = camera_pose_scene(Scene(parts), position=(0.0, 0.0, 1.0))
    return simulate_depth_camera(scene, fx=F, fy=F, cx=319.5, cy=239.5, noise_coeff=KINECT_NOISE,
                                 noise_sigma0=0.001, noise_correlation=KINECT_CORRELATION_PX,
                                 step_quadratic=KINECT_STEP, seed=seed)


def _regions(scan):
    """Plane regions as the tile grid and the recovery leave them: the wall, the pipe's left
    and right halves (split at its middle column), and each box face seen, ``(labels, fits,
    stats, sigma)``."""
    truth = scan.truth_ids
    cols = np.arange(truth.shape[1])[None, :].repeat(truth.shape[0], 0)
    pipe = truth == PIPE
    middle = np.median(cols[pipe])
    labels = np.zeros(truth.shape, np.int32)
    labels[truth == WALL] = 1
    labels[pipe & (cols < middle)] = 2
    labels[pipe & (cols >= middle)] = 3
    faces = [t for t in range(BOX, BOX + 6) if np.count_nonzero(truth == t) >= MIN_SIZE]
    for k, t in enumerate(faces, start=4):
        labels[truth == t] = k
    xyz = scan.cloud.xyz.reshape(-1, 3)
    sigma = NOISE.sigma(np.linalg.norm(scan.cloud.xyz, axis=2))
    fits = {}
    for k in range(1, int(labels.max()) + 1):
        idx = np.flatnonzero(labels.ravel() == k)
        _, a = ray_fits(pixel_moments(xyz, sigma.ravel(), idx))
        fits[k] = ray_plane(a[0], xyz[idx])
    stats = region_stats(scan.cloud.xyz, labels, fits, sigma, INLIER_SIGMAS)
    return labels, fits, stats, sigma, len(faces)


def _join(scan):
    labels, fits, stats, sigma, faces = _regions(scan)
    out = curved_from_plane_pairs(scan.cloud, labels, fits, stats, sigma=sigma, fitter=rs.Pipeline("rgbd_vga").fitter,
                                  min_size=MIN_SIZE, inlier_factor=INLIER_SIGMAS,
                                  correlation_px=KINECT_CORRELATION_PX)
    return (labels, fits, faces), out


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3))
def test_a_pipe_left_as_two_plane_strips_becomes_one_cylinder_and_a_boxs_faces_stay_apart(seed):
    scan = _scan(seed)
    (labels, fits, faces), (out, out_fits, out_stats) = _join(scan)
    assert faces == 2  # two sides of the box face the camera
    # each half of the pipe is flat within the noise of its own independent returns: no step
    # that asks one region sees the bend
    ctx = Context(scan.cloud, rs.Pipeline("rgbd_vga").fitter, NOISE.sigma(np.linalg.norm(scan.cloud.xyz, axis=2)),
                  MIN_SIZE, correlation_px=KINECT_CORRELATION_PX)
    for k in (2, 3):
        assert _within_noise_along_rays(ctx, np.flatnonzero(labels.ravel() == k), KINECT_CORRELATION_PX ** 2)
    pipe = scan.truth_ids == PIPE
    joined = np.unique(out[pipe])
    assert joined.size == 1 and joined[0] in (2, 3)
    model = out_fits[int(joined[0])]
    assert isinstance(model, Cylinder)
    assert abs(model.radius - RADIUS) < 0.35 * RADIUS
    assert abs(abs(model.axis[1]) - 1.0) < 0.03  # the camera's y is down: the pipe's axis
    assert len(out_fits) == len(fits) - 1
    assert out_stats.counts[int(joined[0])] == np.count_nonzero(pipe)
    # the box's two faces and the wall keep their planes and their pixels
    for k in [1] + list(range(4, 4 + faces)):
        assert isinstance(out_fits[k], Plane)
        assert np.array_equal(out == k, labels == k)


def test_no_pair_of_plane_regions_returns_the_inputs():
    scan = _scan(0)
    labels, fits, stats, sigma, _ = _regions(scan)
    only_wall = np.where(labels == 1, 1, 0).astype(np.int32)
    kept = {1: fits[1]}
    wall_stats = region_stats(scan.cloud.xyz, only_wall, kept, sigma, INLIER_SIGMAS)
    out = curved_from_plane_pairs(scan.cloud, only_wall, kept, wall_stats, sigma=sigma,
                                  fitter=rs.Pipeline("rgbd_vga").fitter, min_size=MIN_SIZE,
                                  inlier_factor=INLIER_SIGMAS, correlation_px=KINECT_CORRELATION_PX)
    assert out[0] is only_wall and out[1] is kept and out[2] is wall_stats


def test_a_noise_image_of_another_shape_is_refused():
    scan = _scan(0)
    labels, fits, stats, sigma, _ = _regions(scan)
    with pytest.raises(ValueError, match="sigma: expected shape"):
        curved_from_plane_pairs(scan.cloud, labels, fits, stats, sigma=sigma[:-1], fitter=rs.Pipeline("rgbd_vga").fitter,
                                min_size=MIN_SIZE, inlier_factor=INLIER_SIGMAS)


def test_the_bounds_are_the_chi_square_and_f_quantiles_of_the_bins():
    # 16 bins, 4 deviations of sqrt(2 * 16) up: 16 + 4 * sqrt(32)
    assert PATTERN_BOUND == pytest.approx(16 + 4 * np.sqrt(32))
    # F(16, 16) at the upper tail of three normal deviations (0.00135)
    assert JOIN_RATIO == pytest.approx(4.94, abs=0.01)


@pytest.mark.parametrize("seed, scan_index, truth_id, radius", [
    # a pipe of r 0.115 m at 3.7-5.8 m (receding), left as two strips of 2360 and 2136 px whose
    # union the fitter calls a plane (its plane in xyz turned to the rays): the bend along the
    # rays gives the cylinder (bent_planes.bent_pipe)
    (1341, 2, 12, 0.1146),
    # a pipe of r 0.136 m at 4.2-4.7 m, two strips of 5078 and 2294 px whose union the fitter
    # gives r 0.10 m, its misfit pattern across the strips 12.7 times the planes': placed along
    # the rays (bent_planes.cylinder_along_rays), r 0.14 m, 2.9 times
    (1343, 3, 19, 0.1361),
])
def test_a_stereo_pipe_left_as_two_strips_is_one_cylinder(seed, scan_index, truth_id, radius):
    from matrix_helpers import matrix_result, region_holding

    scan, result = matrix_result("stereo_1280x720", seed, scan_index)
    pipe = scan.truth_ids == truth_id
    label, count = region_holding(result.labels, pipe)
    assert count >= 0.95 * pipe.sum()  # one region holds the pipe (before: 51 % and 69 %)
    assert count >= 0.9 * (result.labels == label).sum()
    feature = {f.label: f for f in result.features}[label]
    assert feature.kind == "cylinder"
    assert abs(feature.radius - radius) < 0.1 * radius  # measured: within 1.1 %


def test_a_share_of_independent_returns_out_of_range_is_refused():
    scan = _scan(0)
    labels, fits, stats, sigma, _ = _regions(scan)
    for share in (0.0, 1.5):
        with pytest.raises(ValueError, match="share: expected a number in"):
            curved_from_plane_pairs(scan.cloud, labels, fits, stats, sigma=sigma, fitter=rs.Pipeline("rgbd_vga").fitter,
                                    min_size=MIN_SIZE, inlier_factor=INLIER_SIGMAS, share=share)


def _pipe_as_cylinder_and_strip(scan, cylinder_share):
    """:func:`_regions` with the pipe's columns up to its ``cylinder_share`` quantile a cylinder
    region (label 2; its model the pipe's with a radius a fifth too large, as a tile grid's may
    be: the fitter refuses a cylinder on so short an arc under this noise) and the rest a plane
    strip (3)."""
    labels, fits, _, sigma, faces = _regions(scan)
    truth = scan.truth_ids
    cols = np.arange(truth.shape[1])[None, :].repeat(truth.shape[0], 0)
    pipe = truth == PIPE
    cut = np.quantile(cols[pipe], cylinder_share)
    labels[pipe & (cols <= cut)] = 2
    labels[pipe & (cols > cut)] = 3
    xyz = scan.cloud.xyz.reshape(-1, 3)
    fits[2] = replace(scan.truth[PIPE], radius=1.2 * RADIUS)
    strip = np.flatnonzero(labels.ravel() == 3)
    _, a = ray_fits(pixel_moments(xyz, sigma.ravel(), strip))
    fits[3] = ray_plane(a[0], xyz[strip])
    stats = region_stats(scan.cloud.xyz, labels, fits, sigma, INLIER_SIGMAS)
    return labels, fits, stats, sigma, faces


def _join_regions(scan, regions):
    labels, fits, stats, sigma, _ = regions
    return curved_from_plane_pairs(scan.cloud, labels, fits, stats, sigma=sigma, fitter=rs.Pipeline("rgbd_vga").fitter,
                                   min_size=MIN_SIZE, inlier_factor=INLIER_SIGMAS,
                                   correlation_px=KINECT_CORRELATION_PX)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3))
def test_a_plane_strip_beside_a_pipes_cylinder_region_joins_it(seed):
    scan = _scan(seed)
    regions = _pipe_as_cylinder_and_strip(scan, 0.7)
    labels, fits, _, _, faces = regions
    assert isinstance(fits[2], Cylinder) and isinstance(fits[3], Plane)
    out, out_fits, out_stats = _join_regions(scan, regions)
    pipe = scan.truth_ids == PIPE
    assert np.array_equal(np.unique(out[pipe]), [2])  # under the cylinder region's label
    model = out_fits[2]
    assert isinstance(model, Cylinder)
    assert abs(model.radius - RADIUS) < 0.35 * RADIUS
    assert abs(abs(model.axis[1]) - 1.0) < 0.03
    assert 3 not in out_fits and out_stats.counts[2] == np.count_nonzero(pipe)
    # the wall beside the pipe (a larger plane: not asked) and the box's faces are untouched
    for k in [1] + list(range(4, 4 + faces)):
        assert out_fits[k] is fits[k] and np.array_equal(out == k, labels == k)


def test_a_plane_region_larger_than_the_curved_one_is_not_joined_to_it():
    # the strip a step cut off a curved region is the smaller part; a wall or a floor beside
    # a pipe is larger, and asking each of them costs a crease search over both. The price,
    # shown here: a pipe whose plane part is the larger stays two regions (asked, this pair
    # would join)
    scan = _scan(0)
    regions = _pipe_as_cylinder_and_strip(scan, 0.3)
    labels, fits, stats, _, _ = regions
    assert stats.counts[3] > stats.counts[2]
    out, out_fits, _ = _join_regions(scan, regions)
    assert np.array_equal(out, labels) and out_fits.keys() == fits.keys()


@pytest.mark.parametrize("row, seed, scan_index, truth_id, kind, radius, tolerance", [
    # a pipe of r 0.21 m at 6.2-6.8 m: the recovery's two planes, the larger turned a cylinder by
    # the bend test (2590 px), the other a strip beside it (1006 px). Under 61 mm of noise that
    # errs together over 9 x 9 px the fitted radius is 0.17 m (0.1719 with 3596 px, 0.1702 with
    # 3711 since free pixels grow at full resolution), its block-jackknife standard error over
    # 9 x 9 blocks 11 mm: 25 %
    ("kinect_real_640x480", 1353, 0, 17, "cylinder", 0.2137, 0.25),
    # a ball of r 0.35 m at 4.4-5.1 m the fitter called a cylinder, an end cap cut off its side
    # (3236 and 359 px): joined under the sphere, which fits as closely with one parameter fewer
    ("stereo_1280x720", 1370, 3, 8, "sphere", 0.3461, 0.2),
    # a pipe of r 0.20 m at 2.7-3.3 m the crease search cut in two plane faces, each turned a
    # cylinder by the bend test (r 0.117 and 0.177 m; 4656 and 3210 px): over their union the
    # fitter's cylinder does not beat the plane by its curvature gain, and is asked without it
    ("kinect_real_640x480", 1376, 2, 9, "cylinder", 0.1997, 0.2),
])
def test_pieces_of_one_curved_surface_join_on_the_matrix(row, seed, scan_index, truth_id, kind, radius, tolerance):
    from matrix_helpers import matrix_result, region_holding

    scan, result = matrix_result(row, seed, scan_index)
    surface = scan.truth_ids == truth_id
    label, count = region_holding(result.labels, surface)
    assert count >= 0.9 * surface.sum()  # one region holds it (before: 69 %, 83 % and 59 %)
    assert count >= 0.9 * (result.labels == label).sum()
    feature = {f.label: f for f in result.features}[label]
    assert feature.kind == kind
    assert abs(feature.radius - radius) < tolerance * radius


def test_the_cheap_share_near_a_curved_model_is_the_patterns_own():
    # (curved_pairs asks it before the crease search: it must say what the patterns would)
    scan = _scan(0)
    sigma = NOISE.sigma(np.linalg.norm(scan.cloud.xyz, axis=2))
    ctx = Context(scan.cloud, rs.Pipeline("rgbd_vga").fitter, sigma, MIN_SIZE, correlation_px=KINECT_CORRELATION_PX)
    pipe = np.flatnonzero(scan.truth_ids.ravel() == PIPE)
    pipe_and_wall = np.flatnonzero(np.isin(scan.truth_ids.ravel(), (PIPE, WALL)))
    for model in (scan.truth[PIPE], replace(scan.truth[PIPE], radius=2.0 * RADIUS)):
        for idx in (pipe, pipe_and_wall):
            share = share_near_curved(ctx, model, idx)
            assert share == misfit_patterns(ctx, model, idx, KINECT_CORRELATION_PX)[2][0]
    assert share_near_curved(ctx, scan.truth[PIPE], pipe) > 0.95  # the noise's 3 sigmas
    assert share_near_curved(ctx, scan.truth[PIPE], pipe_and_wall) < 0.5  # the wall is far off it


def test_a_pipes_end_cap_beside_it_is_not_joined_to_it():
    # a stereo pipe of r 0.15 m at 3.7-5.1 m (18307 px) and its end cap seen at 76 degrees
    # (540 px): the cap is 3 % of the union, and the pattern's equal-count bins dilute its
    # misfit; its plane lies across the pipe's axis (held-out seed 1889 scan 0, traced after the
    # join took the cap: 17079 + 540 px in one cylinder region, both surfaces lost)
    from matrix_helpers import matrix_result, region_holding

    scan, result = matrix_result("stereo_1280x720", 1889, 0)
    pipe, cap = scan.truth_ids == 7, scan.truth_ids == 9
    pipe_label, pipe_count = region_holding(result.labels, pipe)
    cap_label, cap_count = region_holding(result.labels, cap)
    assert pipe_label != cap_label
    assert pipe_count >= 0.9 * pipe.sum() and cap_count >= 0.9 * cap.sum()
    features = {f.label: f for f in result.features}
    assert features[pipe_label].kind == "cylinder" and features[cap_label].kind == "plane"


def test_a_plane_across_a_cylinders_axis_is_its_cap():
    from rangeseg_o3d.curved_pairs import _cap_of
    from rangeseg_o3d.fitting.primitives import Sphere

    axis = np.array([0.0, 0.0, 1.0])
    pipe = Cylinder(axis=axis, point=np.zeros(3), radius=0.1, rms=0.0, inliers=0)
    for degrees, cap in ((0.0, True), (40.0, True), (50.0, False), (90.0, False)):
        turned = np.radians(degrees)
        normal = np.array([np.sin(turned), 0.0, np.cos(turned)])
        assert _cap_of(Plane(normal=normal, d=1.0, rms=0.0, inliers=0), pipe) is cap
    ball = Sphere(center=np.zeros(3), radius=0.1, rms=0.0, inliers=0)
    assert _cap_of(Plane(normal=axis, d=1.0, rms=0.0, inliers=0), ball) is False


def _pipe_as_two_cylinders(scan, box_as_cylinders=False):
    """:func:`_regions` with each half of the pipe a cylinder region (labels 2 and 3), their
    models the pipe's with radii 0.7 and 1.2 times its own, as the bend test may place each
    half's under this noise; with ``box_as_cylinders`` the box's two faces too carry
    cylinders (of 1 m radius along the box's vertical edges, touching each face at its
    centroid, as a bend test fooled by the noise might leave them)."""
    labels, fits, _, sigma, faces = _regions(scan)
    fits[2] = replace(scan.truth[PIPE], radius=0.7 * RADIUS)
    fits[3] = replace(scan.truth[PIPE], radius=1.2 * RADIUS)
    if box_as_cylinders:
        xyz = scan.cloud.xyz.reshape(-1, 3)
        vertical = np.asarray(scan.truth[PIPE].axis, dtype=float)  # the pipe stands as the box's edges do
        for k in range(4, 4 + faces):
            face = fits[k]
            centroid = xyz[labels.ravel() == k].mean(axis=0)
            fits[k] = Cylinder(axis=vertical, point=centroid + 1.0 * np.asarray(face.normal), radius=1.0,
                               rms=0.0, inliers=0)
    stats = region_stats(scan.cloud.xyz, labels, fits, sigma, INLIER_SIGMAS)
    return labels, fits, stats, sigma, faces


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3))
def test_a_pipe_left_as_two_cylinder_regions_becomes_one(seed):
    # each half a cylinder of its own radius: no model of either is the other's, and the
    # union's cylinder (the larger half's refitted to both) leaves the noise's pattern
    scan = _scan(seed)
    regions = _pipe_as_two_cylinders(scan)
    labels, fits, stats, _, faces = regions
    out, out_fits, out_stats = _join_regions(scan, regions)
    pipe = scan.truth_ids == PIPE
    larger = 2 if stats.counts[2] >= stats.counts[3] else 3
    assert np.array_equal(np.unique(out[pipe]), [larger])
    model = out_fits[larger]
    assert isinstance(model, Cylinder)
    assert abs(model.radius - RADIUS) < 0.35 * RADIUS
    assert abs(abs(model.axis[1]) - 1.0) < 0.03
    assert (5 - larger) not in out_fits and out_stats.counts[larger] == np.count_nonzero(pipe)
    for k in [1] + list(range(4, 4 + faces)):
        assert out_fits[k] is fits[k] and np.array_equal(out == k, labels == k)


def test_a_boxs_two_faces_under_cylinders_stay_apart():
    # the box's two faces 0.3 m wide at 5.5 m, each under a cylinder: their union's cylinder
    # misses the crease along whole bands, and the pair is refused as two planes' is
    scan = _scan(0)
    regions = _pipe_as_two_cylinders(scan, box_as_cylinders=True)
    labels, fits, _, _, faces = regions
    assert faces == 2 and all(isinstance(fits[k], Cylinder) for k in (4, 5))
    out, out_fits, _ = _join_regions(scan, regions)
    for k in (4, 5):
        assert out_fits[k] is fits[k] and np.array_equal(out == k, labels == k)

