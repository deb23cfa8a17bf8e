"""The leftover strips recovered in one batched step (rangeseg_o3d.strips): each joins a
region it touches that explains it, becomes a plane of its own, or stays free."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.primitives import Plane
from rangeseg_o3d.fullres import label_pixels, region_stats
from rangeseg_o3d.result import INLIER_SIGMAS
from rangeseg_o3d.strips import recover_strips

NOISE = 0.002


def _wall(h, w, z=2.0):
    v, u = np.mgrid[0:h, 0:w].astype(float)
    return np.dstack([(u - w / 2) * 0.01, (v - h / 2) * 0.01, np.full((h, w), z)])


def _wall_labelled_with_boards(boards, *, noisy=True, seed=0):
    # A wall 2 m away (range noise 2 mm) on a 6-px tile grid that one plane region holds,
    # with boards in front of it (``boards``: (mask, depth) pairs, their depths with the
    # range noise unless not ``noisy``) its tile model leaves free; returns the cloud, the
    # labelled pixels, the model and statistics, and the arguments the recovery takes
    rng = np.random.default_rng(seed)
    xyz = _wall(48, 60)
    for mask, depth in boards:
        xyz[mask, 2] = depth + (rng.normal(0.0, NOISE, int(mask.sum())) if noisy else 0.0)
    cloud = rs.OrganizedCloud(xyz)
    cfg = rs.load_config({"tile": 6, "sensor": {"sigma0": NOISE}, "refine": {"min_region_size": 300}})
    pipe = rs.Pipeline(cfg)
    fits = {1: Plane([0, 0, 1], 2.0, 0.0, 1)}
    sigma = np.full(cloud.shape, NOISE)
    labels, stats = label_pixels(cloud, np.ones((8, 10), np.int32), fits, tile=6, sigma=sigma,
                                 k_sigma=3.0, inlier_factor=INLIER_SIGMAS)
    common = dict(fitter=pipe.fitter, config=cfg.refine, sensor=pipe.sensor, ranges=cloud.range_image(),
                  sigma=sigma, inlier_factor=INLIER_SIGMAS)
    return cloud, labels, fits, stats, common


def _columns(first, last):
    mask = np.zeros((48, 60), bool)
    mask[:, first:last] = True
    return mask


def test_a_strip_off_the_wall_becomes_its_plane_and_nothing_else_changes():
    # A two-column board (96 px, no 3x3 core) 0.3 m in front of the wall and a 20 x 20 board
    # face (a cored blob, the blob recovery's) 0.5 m in front: the strip becomes a plane at
    # the board's distance; the face's blob stays free and the wall keeps every pixel.
    strip = _columns(30, 32)
    face = np.zeros((48, 60), bool)
    face[10:30, 40:60] = True
    cloud, labels, fits, stats, common = _wall_labelled_with_boards([(strip, 1.7), (face, 1.5)])
    assert (labels[strip | face] == 0).all() and (labels[~(strip | face)] == 1).all()
    out, out_fits, out_stats = recover_strips(cloud, labels, fits, stats, **common)
    assert (out[~strip] == labels[~strip]).all()
    (found,) = np.unique(out[strip])
    assert found > 1
    model = out_fits[int(found)]
    assert model.kind == "plane" and abs(abs(model.normal[2]) - 1.0) < 0.05
    assert abs(abs(model.d) - 1.7) < 3 * NOISE
    # the statistics of every region are those a measure of the new labels gives
    fresh = region_stats(cloud.xyz, out, out_fits, common["sigma"], INLIER_SIGMAS)
    assert np.array_equal(out_stats.counts, fresh.counts) and np.array_equal(out_stats.inliers, fresh.inliers)
    assert np.allclose(out_stats.squares, fresh.squares, rtol=1e-9, atol=1e-12)


def test_a_strip_on_one_depth_level_is_no_face():
    # the same board strip without noise: every pixel at one depth, a plane of rms 0 where
    # the range noise is 2 mm. A quantised depth's terrace, not a surface: it stays free.
    strip = _columns(30, 32)
    cloud, labels, fits, stats, common = _wall_labelled_with_boards([(strip, 1.7)], noisy=False)
    out = recover_strips(cloud, labels, fits, stats, **common)
    assert out[0] is labels and out[1] is fits and out[2] is stats


def test_a_strip_on_the_wall_joins_it():
    # two columns of the wall's own surface (with the range noise) that the labelling left
    # free: the wall's plane explains them, so they join it and no region is made
    strip = _columns(30, 32)
    cloud, _, fits, stats, common = _wall_labelled_with_boards([(strip, 2.0)])
    labels = np.ones((48, 60), np.int32)
    labels[strip] = 0
    stats = region_stats(cloud.xyz, labels, fits, common["sigma"], INLIER_SIGMAS)
    out, out_fits, out_stats = recover_strips(cloud, labels, fits, stats, **common)
    assert (out == 1).all() and set(out_fits) == {1}
    assert out_stats.counts[1] == 48 * 60


@pytest.mark.parametrize("apart", [True, False])
def test_a_strip_of_the_wall_beside_none_of_its_pixels_joins_it_where_pieces_apart_are_one_region(apart):
    # two columns of the wall's surface left free between two boards 0.5 m before it (one
    # plane region, label 2), so beside none of the wall's pixels: with merge_disjoint (pieces
    # of one surface apart are one region) the wall's plane explains them and they join it;
    # without, they become a plane of their own at the wall's distance
    strip = _columns(30, 32)
    boards = _columns(24, 30) | _columns(32, 38)
    cloud, _, fits, stats, common = _wall_labelled_with_boards([(strip, 2.0), (boards, 1.5)])
    labels = np.where(boards, 2, 1).astype(np.int32)
    labels[strip] = 0
    fits = {1: fits[1], 2: Plane([0, 0, 1], 1.5, 0.0, 1)}
    stats = region_stats(cloud.xyz, labels, fits, common["sigma"], INLIER_SIGMAS)
    common["config"] = common["config"].model_copy(update={"merge_disjoint": apart})
    out, out_fits, _ = recover_strips(cloud, labels, fits, stats, **common)
    assert (out[~strip] == labels[~strip]).all()
    (found,) = np.unique(out[strip])
    if apart:
        assert found == 1 and set(out_fits) == {1, 2}
    else:
        assert found > 2 and out_fits[int(found)].kind == "plane"
        assert abs(abs(out_fits[int(found)].d) - 2.0) < 3 * NOISE


def test_the_strip_step_returns_its_inputs_when_no_strip_is_left_over():
    # a cored 20 x 20 face left over and no strip: nothing for the strip step; nor on a frame
    # with nothing left over, nor with a strip under the pixel floor (2 x 5 < MIN_PIXELS)
    face = np.zeros((48, 60), bool)
    face[10:30, 20:40] = True
    short = np.zeros((48, 60), bool)
    short[:5, 50:52] = True
    cloud, labels, fits, stats, common = _wall_labelled_with_boards([(face, 1.5), (short, 1.7)])
    assert (labels[face | short] == 0).all()
    out = recover_strips(cloud, labels, fits, stats, **common)
    assert out[0] is labels and out[1] is fits and out[2] is stats
    full = np.ones_like(labels)
    assert recover_strips(cloud, full, fits, stats, **common)[0] is full


# A stereo camera's grazing face (rangeseg_o3d.strips._Strips.faces_along_rays): a box's top seen
# a few degrees off its plane, two rows high, between a far wall and the box's front face.
STEREO_F, STEREO_ROWS, STEREO_COLS = 640.0, 60, 240
STEREO_COEFF = 0.1 / (STEREO_F * 0.05)  # 0.1 px of disparity noise over a 5 cm baseline


def _box_top_strip(seed=0, top=0.6, near=3.3, far=3.355, wall=5.0):
    # (xyz, truth, sigma): the wall (1), the top y = top between depths near and far (2),
    # the front face z = near (3); range noise 1 mm + COEFF r^2 along the rays, erring
    # together over 3 x 3 pixels (the matrix's stereo row)
    from rangeseg_o3d.synthetic.depth_camera import _unit_noise

    v, u = np.mgrid[0:STEREO_ROWS, 0:STEREO_COLS].astype(float)
    rays = np.dstack([(u - STEREO_COLS / 2) / STEREO_F, (v + 89) / STEREO_F, np.ones(v.shape)])
    depth_top = top / rays[..., 1]
    truth = np.where((depth_top >= near) & (depth_top <= far), 2, np.where(depth_top < near, 3, 1))
    depth = np.select([truth == 1, truth == 2], [np.full(v.shape, wall), depth_top], near)
    points = rays * depth[..., None]
    ranges = np.linalg.norm(points, axis=-1)
    sigma = 0.001 + STEREO_COEFF * ranges ** 2
    noisy = ranges + sigma * _unit_noise(np.random.default_rng(seed), v.shape, 3)
    return points * (noisy / ranges)[..., None], truth, sigma


def _stereo_strip_step(correlation_px, inset=0, crop=False, **sensor):
    # (``inset``: the strip's first and last ``inset`` columns given to the front face, so
    # that the free strip does not reach the frame's edges; ``crop``: the frame ends at the
    # strip's last row, the front face below cut off, and keeps the middle 120 columns, so
    # that the strip (240 px) is under the smallest region: at the edge, the grid's border
    # replicated, its two rows have a blob's 3x3 core; ``sensor``: facts stated besides)
    xyz, truth, sigma = _box_top_strip()
    if crop:
        end, cols = int(np.flatnonzero((truth == 2).any(axis=1)).max()) + 1, slice(60, 180)
        xyz, truth, sigma = (np.ascontiguousarray(a[:end, cols]) for a in (xyz, truth, sigma))
    cloud = rs.OrganizedCloud(xyz)
    cfg = rs.load_config({"tile": 6, "sensor": {"sigma0": 0.001, "sigma_quadratic": STEREO_COEFF,
                                                "noise_correlation_px": correlation_px, **sensor},
                          "refine": {"min_region_size": 300}})
    pipe = rs.Pipeline(cfg)
    fits = {1: Plane([0, 0, 1.0], 5.0, 0.0, 1), 3: Plane([0, 0, 1.0], 3.3, 0.0, 1)}
    labels = np.where(truth == 2, 0, truth).astype(np.int32)
    cols = np.arange(truth.shape[1])[None, :]
    labels[(truth == 2) & ((cols < inset) | (cols >= truth.shape[1] - inset))] = 3
    stats = region_stats(cloud.xyz, labels, fits, sigma, INLIER_SIGMAS)
    common = dict(fitter=pipe.fitter, config=cfg.refine, sensor=pipe.sensor, ranges=cloud.range_image(),
                  sigma=sigma, inlier_factor=INLIER_SIGMAS)
    return truth, labels, fits, stats, recover_strips(cloud, labels, fits, stats, **common)


def test_a_stereo_cameras_grazing_strip_becomes_the_faces_plane_fitted_along_its_rays():
    # the top (480 px, 2 rows, seen at 10 degrees) spans 5.5 cm of depth where the range noise
    # is 3.5 cm: its least-squares plane turns towards the rays (the strip is refused as one),
    # the plane of its inverse ranges is the top's; every pixel of it joins that plane
    from rangeseg_o3d.strips import _Strips

    truth, labels, fits, _, (out, out_fits, _) = _stereo_strip_step(3)
    xyz, _, sigma = _box_top_strip()
    idx = np.flatnonzero(truth.ravel() == 2)
    strips = _Strips(np.ascontiguousarray(xyz.reshape(-1, 3)), sigma.ravel(), idx, np.array([0, idx.size]), 3.0)
    assert idx.size == 480 and not strips.across_rays()[0]
    (found,) = np.unique(out[truth == 2])
    assert found not in fits
    model = out_fits[int(found)]
    assert model.kind == "plane" and abs(model.normal[1]) > np.cos(np.radians(3.0))


def test_a_grazing_strip_stays_free_where_the_noise_errs_alone():
    # the same strip, inside the frame, on a camera whose returns err one by one (a
    # Kinect-type camera): the step is the one before it, the strip refused and left free
    truth, labels, fits, stats, out = _stereo_strip_step(1, inset=8)
    assert out[0] is labels and out[1] is fits and out[2] is stats


def test_a_strip_the_frames_edge_cuts_becomes_its_plane_fitted_along_its_rays_on_a_kinect():
    # the same strip where the frame's bottom edge runs along it (the front face below cut
    # off), on a Kinect-type camera (range noise growing with the range, returns erring one by
    # one): a face the edge cuts is left a few pixels wide in the partial tiles there, so its
    # plane is fitted along its rays too
    truth, labels, fits, _, (out, out_fits, _) = _stereo_strip_step(1, crop=True)
    assert (truth[-1] == 2).all() and not (truth == 3).any()
    found, counts = np.unique(out[truth == 2], return_counts=True)
    new = int(found[np.argmax(counts)])
    assert new not in fits and counts.max() >= 0.9 * (truth == 2).sum()
    model = out_fits[new]
    assert model.kind == "plane" and abs(model.normal[1]) > np.cos(np.radians(3.0))
    assert np.all(out[truth == 1] == 1)  # (the wall keeps its pixels)


def test_a_strip_across_the_frames_edges_stays_free_on_a_kinect():
    # the uncut strip reaches the frame's left and right edges but runs across them (2 rows
    # by 240 columns): no edge cut it thin (as a pipe's limb from the top edge down), so on a
    # Kinect-type camera it is refused as one inside the frame is
    truth, labels, fits, stats, out = _stereo_strip_step(1)
    assert (truth[:, 0] == 2).any() and (truth[:, -1] == 2).any()
    assert out[0] is labels and out[1] is fits and out[2] is stats


def test_along_the_frames_edge_boxes():
    from rangeseg_o3d.strips import _along_the_frames_edge

    boxes = np.array([[256, 282, 0, 5],     # the left edge's 5 columns, 26 rows: along it
                      [200, 230, 635, 640],  # the right edge's: along it
                      [0, 157, 323, 324],    # a limb from the top edge down: across it
                      [0, 3, 100, 140],      # the top edge's 3 rows: along it
                      [470, 480, 0, 4],      # the bottom-left corner, taller than wide: along the left
                      [100, 130, 5, 10]])    # inside the frame
    assert _along_the_frames_edge(boxes, 480, 640).tolist() == [True, True, False, True, True, False]


def test_a_strip_the_frames_edge_cuts_stays_free_where_the_noise_is_under_the_grids_footprint():
    # the same edge strip where the sensor states a grid of 0.5 deg (a laser whose noise is
    # stated growing with the range: noise_spans_the_grid false): the step before, left free
    truth, labels, fits, stats, out = _stereo_strip_step(1, row_spacing_deg=0.5, column_spacing_deg=0.5)
    assert out[0] is labels and out[1] is fits and out[2] is stats


def test_noise_spans_the_grid_on_the_presets():
    # a Kinect's noise exceeds its 0.11-deg footprint at every range (0.11 deg = 1.92 mrad,
    # 1.92e-3^2 = 3.7e-6 < 4 x 1e-3 x 1.425e-3 = 5.7e-6); the SICK of the 3DTK scans (0.517 deg:
    # 8.1e-5 > 4 x 3e-3 x 1e-3 = 1.2e-5) and every laser of constant noise do not
    from rangeseg_o3d.scales import noise_spans_the_grid

    def sensor(preset):
        return rs.Pipeline(rs.load_config(preset)).sensor

    assert noise_spans_the_grid(sensor("rgbd_vga"))
    for preset in ("sick_3dtk", "lms200", "spinning_lidar", "abw"):
        assert not noise_spans_the_grid(sensor(preset)), preset
    # the bound itself: a Kinect's noise at a grid just finer / coarser than sqrt(4 s0 sq)
    limit = np.degrees(np.sqrt(4 * 0.001 * 0.001425))
    for step, expected in ((0.99 * limit, True), (1.01 * limit, False)):
        cfg = rs.load_config({"sensor": {"sigma0": 0.001, "sigma_quadratic": 0.001425,
                                         "row_spacing_deg": step, "column_spacing_deg": step}})
        assert noise_spans_the_grid(rs.Pipeline(cfg).sensor) is expected
    # no spacing stated: measured on the cloud (1/640 rad here), else false
    xyz, _, _ = _box_top_strip()
    bare = rs.Pipeline(rs.load_config({"sensor": {"sigma0": 0.001, "sigma_quadratic": 0.001425}})).sensor
    assert noise_spans_the_grid(bare, rs.OrganizedCloud(xyz)) and not noise_spans_the_grid(bare)


def test_a_strip_at_the_frames_edge_that_a_found_surface_explains_is_no_face():
    # a strip of the wall itself, cut from its region at the frame's edge: the wall's model
    # explains it within the range noise (_on_a_found_surface), so no face is made of it
    from rangeseg_o3d.strips import _on_a_found_surface

    xyz, truth, sigma = _box_top_strip()
    flat, noise = np.ascontiguousarray(xyz.reshape(-1, 3)), sigma.ravel()
    fits = {1: Plane([0, 0, 1.0], 5.0, 0.0, 1), 3: Plane([0, 0, 1.0], 3.3, 0.0, 1)}
    wall = np.flatnonzero(truth.ravel() == 1)[:200]
    top = np.flatnonzero(truth.ravel() == 2)
    assert _on_a_found_surface(flat, noise, fits, wall)
    assert not _on_a_found_surface(flat, noise, fits, top)


def test_a_strips_plane_along_its_rays_leaves_out_the_pixels_of_another_surface_at_its_end():
    # the top's strip with 40 pixels of the wall behind at its left end: one least-squares
    # fit over all of them turns the plane; the robust fit (pieces left out, truncated
    # chi-square) finds the top's and keeps those pixels out
    from rangeseg_o3d.ray_planes import ray_fits, ray_moments, ray_terms, robust_ray_plane

    xyz, truth, sigma = _box_top_strip()
    top = truth == 2
    wall = np.zeros_like(top)
    wall[24:26, :20] = True  # two rows of the wall above the strip's left end
    idx = np.flatnonzero((top | wall).ravel())
    rays, inverse, weight = ray_terms(xyz.reshape(-1, 3)[idx], sigma.ravel()[idx])
    a, keep, mean_square = robust_ray_plane(rays, inverse, weight, *np.divmod(idx, STEREO_COLS))
    plain = ray_fits(ray_moments(rays, inverse, weight))[1][0]
    true_a = np.array([0.0, 1.0 / 0.6, 0.0])
    assert np.linalg.norm(a - true_a) < 0.25 * np.linalg.norm(true_a)
    assert np.linalg.norm(plain - true_a) > 2 * np.linalg.norm(a - true_a)
    on_wall = wall.ravel()[idx]
    assert keep[~on_wall].mean() > 0.95 and keep[on_wall].mean() < 0.5
    assert mean_square < 1.5
