"""The recover step: compact leftover blobs are candidates, thin crease bands are not."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.fitting.primitives import Plane
from rangeseg_o3d.refinement.recover import (claim_occluded_strips, leftover_candidates, recover_leftovers,
                                             split_blobs)
from rangeseg_o3d.synthetic.depth_camera import camera_pose_scene
from refinement_helpers import best_overlap, folded_strip, leftover_candidates_numpy, plane_grid


def test_leftover_candidates_cut_thin_bands_and_keep_blobs():
    labels = np.ones((20, 30), np.int32)
    labels[:, 14:16] = 0          # a 2-pixel band between two regions
    labels[5:12, 3:10] = 0        # a 7x7 blob
    valid = np.ones_like(labels, bool)
    cand = leftover_candidates(labels, valid, np.zeros_like(valid), min_size=20, first_label=5)
    assert set(np.unique(cand)) == {0, 5}
    assert (cand[5:12, 3:10] == 5).all()
    assert (cand[:, 14:16] == 0).all()


def test_leftover_candidates_keep_strips_along_the_grid_border():
    # A ceiling seen only by the first two scan rows: the border is no edge, so the
    # erosion that cuts crease bands must not eat the strip; the same strip inside the
    # grid is a crease band and is cut.
    labels = np.ones((20, 60), np.int32)
    labels[0:2, 10:50] = 0
    labels[9:11, 10:50] = 0
    valid = np.ones_like(labels, bool)
    cand = leftover_candidates(labels, valid, np.zeros_like(valid), min_size=20, first_label=3)
    assert (cand[0:2, 11:49] == 3).all()
    assert not cand[9:11].any()



@pytest.mark.parametrize("seed", range(4))
def test_leftover_candidates_match_the_numpy_renumbering(seed):
    # the compiled pass (kernels.leftover_blobs) against the OpenCV and numpy steps it
    # replaced, on random leftovers with jumps and invalid pixels, blobs of many sizes
    rng = np.random.default_rng(seed)
    labels = np.where(rng.random((40, 50)) < 0.45, 0, 1).astype(np.int32)
    labels[5:15, 5:20] = 0  # one blob sure to survive the erosion
    valid = rng.random(labels.shape) > 0.05
    jumps = rng.random(labels.shape) < 0.05
    for min_size, first in ((1, 2), (9, 7), (40, 3)):
        expected = leftover_candidates_numpy(labels, valid, jumps, min_size, first)
        cand = leftover_candidates(labels, valid, jumps, min_size=min_size, first_label=first)
        assert cand.dtype == np.int32
        np.testing.assert_array_equal(cand, expected)
        assert cand.max() >= first  # (the blob at least)


def _board_in_front_of_a_wall():
    # a wall at z = 3 and a 16 x 16 pixel board tilted in front of it; the wall's region
    # stops a pixel short of the board (the edge band), the board has no region
    xyz = plane_grid(40, 60, z=3.0, noise=0.001, seed=5)
    board = (slice(12, 28), slice(36, 52))
    xyz[board + (2,)] = 2.5 + 0.3 * xyz[board + (0,)]
    labels = np.ones((40, 60), np.int32)
    labels[11:29, 35:53] = 0
    return xyz, board, labels


def test_recover_leftovers_turns_a_swallowed_board_into_a_region(context):
    xyz, board, labels = _board_in_front_of_a_wall()
    cloud = rs.OrganizedCloud(xyz)
    sigma = np.full((40, 60), 0.001)
    wall = fit_plane(xyz[labels == 1])
    out, fits = recover_leftovers(context(cloud, sigma=sigma), labels, {1: wall}, xyz=xyz, valid=cloud.valid,
                                  jumps=np.zeros((40, 60), bool), ranges=cloud.range_image(), sigma=sigma,
                                  k_sigma=3.0, jump_ratio=0.08, jump_min=0.05)
    assert (labels[11:29, 35:53] == 0).all()  # the input is left alone
    truth = np.zeros(out.shape, np.int32)
    truth[board] = 7
    board_label, share = best_overlap(out, truth, 7)
    assert share > 0.95 and fits[board_label].kind == "plane"
    assert abs(fits[board_label].normal @ wall.normal) < 0.97  # the board, tilted off the wall
    # The blob also held the wall's side of the band (a one-pixel ring): split into every
    # surface the blob holds, that ring is a piece of the wall's plane (the merge step joins
    # it to the wall), never part of the board.
    for k in set(fits) - {1, board_label}:
        assert fits[k].kind == "plane" and abs(fits[k].normal @ wall.normal) > 0.999
        assert abs(abs(fits[k].d) - abs(wall.d)) < 0.01
    # the wall's pixels stay the wall's, and the band is taken back
    assert (out[labels == 1] == 1).all() and (out[11:29, 35:53] > 0).mean() > 0.95


def _wall_behind_columns():
    # a wall at z = 3 (1 mm noise) seen between columns standing 0.5 m in front of it, the
    # whole grid high: a 2-pixel strip of wall between two of them, wall between the
    # second and a third with a 2-pixel board strip 4 cm in front of the wall in it, and a
    # 3 x 2 patch of wall boxed in by the third. The wall is two regions (not merged yet)
    # either side of the columns, stopping two pixels short of them; nothing else is labelled.
    xyz = plane_grid(40, 60, z=3.0, noise=0.001, seed=7)
    columns = np.zeros((40, 60), bool)
    columns[:, 20:26] = columns[:, 28:34] = columns[:, 44:50] = True
    xyz[..., 2][columns] = 2.5
    xyz[20:23, 46:48, 2] = 3.0  # the boxed-in patch of wall
    xyz[:, 38:40, 2] = 2.96  # the board strip
    labels = np.zeros((40, 60), np.int32)
    labels[:, :18] = 1
    labels[:, 52:] = 2
    return xyz, labels, columns


def test_claim_occluded_strips_gives_wall_strips_between_columns_to_the_wall(context):
    xyz, labels, columns = _wall_behind_columns()
    cloud = rs.OrganizedCloud(xyz)
    sigma = np.full((40, 60), 0.001)
    fits = {1: fit_plane(xyz[labels == 1]), 2: fit_plane(xyz[labels == 2])}
    before = labels.copy()
    out, new_fits = claim_occluded_strips(context(cloud, min_size=20, sigma=sigma), labels, fits,
                                          valid=cloud.valid, k_sigma=3.0)
    assert (labels == before).all()  # the input is left alone
    for strip in (out[:, 26:28], np.hstack([out[:, 34:38], out[:, 40:44]])):
        assert strip.min() > 0 and np.unique(strip).size == 1  # one wall region takes all of it
    assert (out[20:23, 46:48] == 0).all()  # 6 pixels of wall: under the size floor
    assert (out[:, 38:40] == 0).all()  # 4 cm off the wall (40 sigma): another surface
    assert (out[columns & (xyz[..., 2] < 2.9)] == 0).all()  # the columns stay free
    # the wall beside its regions is growth's to judge (with its jump test): left free here
    assert (out[:, 18:20] == 0).all() and (out[:, 50:52] == 0).all()
    assert set(new_fits) == {1, 2} and all(m.kind == "plane" for m in new_fits.values())
    for model in new_fits.values():  # the wall's model, whichever region took the strips
        assert abs(abs(model.normal[2]) - 1) < 1e-3 and abs(abs(model.d) - 3.0) < 3e-3


def test_recover_leftovers_leaves_strips_apart_free_without_claim_strips(context):
    # merge_disjoint false (SegComp's truth: each connected patch its own label): the wall
    # strips between the columns are pieces of the wall apart from its regions, left free
    xyz, labels, columns = _wall_behind_columns()
    cloud = rs.OrganizedCloud(xyz)
    sigma = np.full((40, 60), 0.001)
    fits = {1: fit_plane(xyz[labels == 1]), 2: fit_plane(xyz[labels == 2])}
    common = dict(xyz=xyz, valid=cloud.valid, jumps=columns, ranges=cloud.range_image(), sigma=sigma,
                  k_sigma=3.0, jump_ratio=0.08, jump_min=0.05)
    claimed, _ = recover_leftovers(context(cloud, min_size=20, sigma=sigma), labels, fits, **common)
    apart, apart_fits = recover_leftovers(context(cloud, min_size=20, sigma=sigma), labels, fits,
                                          claim_strips=False, **common)
    strip = (slice(None), slice(26, 28))
    assert (claimed[strip] > 0).all()  # the strip is claimed by default
    assert (apart[strip] == 0).all()
    assert set(np.unique(apart[labels > 0])) == {1, 2} and set(apart_fits) >= {1, 2}


def test_claim_occluded_strips_leaves_labels_without_planes_alone(context):
    xyz, labels, _ = _wall_behind_columns()
    cloud = rs.OrganizedCloud(xyz)
    out, fits = claim_occluded_strips(context(cloud, min_size=20, sigma=np.full((40, 60), 0.001)),
                                      labels, {1: None}, valid=cloud.valid, k_sigma=3.0)
    assert out is labels and fits == {1: None}


def test_split_blobs_gives_every_face_of_a_leftover_blob_its_region(context):
    # A blob holding three faces at 45-degree creases (what the tile grid loses when it
    # cannot see the creases): each face comes back as a region, where explaining the
    # blob by its dominant surface keeps one face and drops the others.
    xyz, truth, normals = folded_strip(noise=0.001)
    cloud = rs.OrganizedCloud(xyz)
    sigma = np.full(truth.shape, 0.001)
    labels = np.zeros(truth.shape, np.int32)
    candidates = np.full(truth.shape, 4, np.int32)
    out, fits = split_blobs(context(cloud, min_size=100, sigma=sigma), labels, {}, candidates)
    assert not labels.any()  # the input is left alone
    for face, normal in normals.items():
        label, share = best_overlap(out, truth, face)
        assert share > 0.9 and fits[label].kind == "plane"
        assert abs(fits[label].normal @ normal) > 0.999
    assert len({best_overlap(out, truth, face)[0] for face in normals}) == 3
    piece, _ = context(cloud, min_size=100, sigma=sigma).dominant_piece(np.arange(truth.size))
    assert piece.size < 0.5 * truth.size  # the dominant surface alone would keep one face


def test_split_blobs_finds_the_face_beside_a_plane_that_explains_most_of_the_blob(context):
    # A blob of a wall (2400 px) and a board 2 cm in front of it (100 px): the blob's plane
    # explains 95 % of it, the wall, and the board, over the size floor, is a surface of its
    # own (it was freed with the rest of the blob the wall's plane left)
    xyz = plane_grid(50, 50, z=3.0, noise=0.001, seed=7)
    board = (slice(2, 12), slice(2, 12))
    xyz[board + (2,)] -= 0.02
    cloud = rs.OrganizedCloud(xyz)
    truth = np.ones((50, 50), np.int32)
    truth[board] = 2
    candidates = np.full((50, 50), 4, np.int32)
    out, fits = split_blobs(context(cloud, min_size=50, sigma=np.full((50, 50), 0.001)),
                            np.zeros((50, 50), np.int32), {}, candidates)
    wall, wall_share = best_overlap(out, truth, 1)
    found, share = best_overlap(out, truth, 2)
    assert wall_share > 0.95 and share > 0.9 and found not in (0, wall)
    assert fits[found].kind == "plane" and abs(fits[wall].d - fits[found].d) == pytest.approx(0.02, abs=0.002)
    # a floor over the board's size leaves the blob to the wall's plane alone: the board is freed
    out, fits = split_blobs(context(cloud, min_size=200, sigma=np.full((50, 50), 0.001)),
                            np.zeros((50, 50), np.int32), {}, candidates)
    assert len(fits) == 1 and not out[board].any()


def test_split_blobs_frees_a_blob_no_model_explains(context):
    xyz = plane_grid(30, 30, z=3.0, noise=0.001, seed=2)
    xyz[..., 2] += np.random.default_rng(3).uniform(-0.3, 0.3, (30, 30))
    cloud = rs.OrganizedCloud(xyz)
    candidates = np.zeros((30, 30), np.int32)
    candidates[5:25, 5:25] = 9
    out, fits = split_blobs(context(cloud, min_size=50, sigma=np.full((30, 30), 0.001)),
                            np.zeros((30, 30), np.int32), {2: None}, candidates)
    assert not out.any() and 9 not in fits and 2 in fits


def test_members_in_a_box_are_the_members_of_the_grid_when_the_box_holds_them():
    from rangeseg_o3d.kernels import member_pixels
    from rangeseg_o3d.refinement.recover import _members_in_box

    rng = np.random.default_rng(4)
    labels = rng.integers(0, 6, (30, 40)).astype(np.int32)
    members = np.array([False, False, True, False, False, True])
    labels[(labels == 2) | (labels == 5)] = 1
    labels[10:14, 20:27] = np.where(rng.random((4, 7)) < 0.5, 2, 5)  # the members, in a box
    for box in ((10, 14, 20, 27), (7, 17, 17, 30), (-3, 40, -3, 50)):  # tight, grown, clipped
        assert np.array_equal(_members_in_box(labels, members, box), member_pixels(labels, members))
    assert _members_in_box(np.ones((5, 5), np.int32), members, (0, 5, 0, 5)).size == 0
    # overlapping boxes, one clipped: each member pixel once, increasing
    boxes = np.array([[8, 14, 18, 27], [10, 16, 20, 45], [-2, 3, 0, 2]], np.int64)
    assert np.array_equal(_members_in_box(labels, members, boxes), member_pixels(labels, members))


def test_differing_pixels_in_boxes_are_those_of_the_grid_and_refuse_two_shapes():
    from rangeseg_o3d.refinement.recover import differing_pixels

    rng = np.random.default_rng(6)
    a = rng.integers(0, 5, (20, 30)).astype(np.int32)
    b = a.copy()
    b[3:7, 4:9] = rng.integers(0, 5, (4, 5))
    b[12:18, 20:29] = rng.integers(0, 5, (6, 9))
    whole = np.flatnonzero(a != b)
    for where in ((0, 20, 0, 30), (-5, 50, -5, 50), np.array([[3, 7, 4, 9], [12, 18, 20, 29]]),
                  np.array([[2, 8, 3, 10], [0, 20, 18, 30], [5, 15, 0, 25]])):
        assert np.array_equal(differing_pixels(a, b, where), whole)
    assert np.array_equal(differing_pixels(a, b), whole)
    with pytest.raises(ValueError, match="one shape"):
        differing_pixels(a, b[:10], (0, 10, 0, 30))
    with pytest.raises(ValueError, match="one shape"):
        differing_pixels(a, b[:10])


def _pipe_top_lost_by_the_tiles(seed):
    # A pipe (radius 0.2 m, axis across the view) 3.7 m from a Kinect-type camera, in
    # front of a wall 4.5 m away; the tile grid kept the wall and the pipe's lower 70 %
    # (its cylinder fitted to those pixels) and left the top band, where the pipe turns
    # away from the camera, unlabelled.
    from rangeseg_o3d.scales import with_derived_refinement
    from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
    from rangeseg_o3d.synthetic.scene import Scene, cylinder, patch

    world = Scene(patch((4.5, 0.0, 0.0), (0, 1, 0), (0, 0, 1), 2.0, 1.0, first_id=1)
                  + cylinder((3.7, -0.6, 0.0), (0, 1, 0), 0.2, 1.2, caps=False, first_id=2))
    scan = simulate_depth_camera(camera_pose_scene(world), width=200, height=80, cx=99.5, cy=39.5,
                                 seed=seed)
    pipeline = rs.Pipeline("rgbd_vga")
    cloud = scan.cloud
    ranges = np.where(cloud.valid, cloud.range_image(), np.nan)
    pipe = scan.truth_ids == 2
    rows = np.nonzero(pipe.any(axis=1))[0]
    kept = pipe & (np.arange(pipe.shape[0])[:, None] >= rows.min() + 0.3 * (rows.max() - rows.min()))
    labels = np.where(scan.truth_ids == 1, 1, np.where(kept, 2, 0)).astype(np.int32)
    fits = {1: pipeline.fitter.fit(cloud.xyz[labels == 1]), 2: pipeline.fitter.fit(cloud.xyz[kept])}
    config = with_derived_refinement(pipeline.config.refine, pipeline.sensor, cloud)
    return scan, pipeline, labels, fits, config, ranges, pipeline.sensor.noise.sigma(ranges)


@pytest.mark.parametrize("seed", [0, 1])
def test_recovered_strip_of_a_pipe_rejoins_its_cylinder(seed):
    # At full resolution the lost band fits a plane within the Kinect's noise (2 cm at
    # 3.7 m): recovered alone it stayed a plane beside the cylinder (the pipe in two
    # regions of two kinds, 70/30). Refitted with the part the tiles kept, the cylinder
    # keeps its kind and fits at the noise, so the band rejoins it.
    from rangeseg_o3d.fullres import leftover_blob_labels
    from rangeseg_o3d.refinement.recover import recover_pixels

    scan, pipeline, labels, fits, config, ranges, sigma = _pipe_top_lost_by_the_tiles(seed)
    assert fits[2].kind == "cylinder"
    found = leftover_blob_labels(labels, scan.cloud.valid, min_size=100, first_label=3)
    assert found is not None
    candidates = found[0]
    out, models = recover_pixels(scan.cloud, labels, dict(fits), fitter=pipeline.fitter, config=config,
                                 sensor=pipeline.sensor, ranges=ranges, sigma=sigma,
                                 candidates=candidates, min_size=100)
    pipe = scan.truth_ids == 2
    owner, share = best_overlap(out, np.where(pipe, 7, 0), 7)
    assert share > 0.99, f"the pipe's largest region holds {share:.1%} of it"
    assert models[owner].kind == "cylinder"
    assert abs(models[owner].radius - 0.2) < 0.02
    assert np.isin(out[pipe], [0, owner]).all()  # no piece of the pipe in another region


@pytest.mark.parametrize("seed", [0, 1])
def test_recover_pixels_with_the_blobs_boxes_answers_as_without(seed):
    # with the blobs' boxes the rims, the claim and the merge look only around the blobs:
    # the same labels and models as the whole-grid passes give
    from rangeseg_o3d.fullres import leftover_blob_labels
    from rangeseg_o3d.refinement.recover import recover_pixels

    scan, pipeline, labels, fits, config, ranges, sigma = _pipe_top_lost_by_the_tiles(seed)
    candidates, boxes, _ = leftover_blob_labels(labels, scan.cloud.valid, min_size=100, first_label=3)
    answers = [recover_pixels(scan.cloud, labels, dict(fits), fitter=pipeline.fitter, config=config,
                              sensor=pipeline.sensor, ranges=ranges, sigma=sigma, candidates=candidates,
                              min_size=100, boxes=given) for given in (None, boxes)]
    (whole, whole_models), (boxed, boxed_models) = answers
    assert (whole != labels).sum() > 100  # a strip was recovered (it rejoins the pipe)
    np.testing.assert_array_equal(boxed, whole)
    assert {k: repr(m) for k, m in boxed_models.items()} == {k: repr(m) for k, m in whole_models.items()}


@pytest.mark.parametrize("seed", [0, 1])
def test_recover_pixels_numbers_new_regions_above_models_that_lost_their_pixels(seed):
    # a region can lose every pixel while its model stays (a tile region the full-resolution
    # pass gave away whole): the blobs are numbered above it, the stale model is left alone
    # and claims nothing, and the pipe is recovered as it is without the stale models
    from rangeseg_o3d.fitting.region_fitter import fresh_label
    from rangeseg_o3d.fullres import leftover_blob_labels
    from rangeseg_o3d.refinement.recover import recover_pixels

    scan, pipeline, labels, fits, config, ranges, sigma = _pipe_top_lost_by_the_tiles(seed)
    stale = {3: fits[1], 4: fits[1]}  # the wall's plane, held by two labels with no pixel
    first = fresh_label(labels, {**fits, **stale})
    assert first == 5
    candidates = leftover_blob_labels(labels, scan.cloud.valid, min_size=100, first_label=first)[0]
    out, models = recover_pixels(scan.cloud, labels, {**fits, **stale}, fitter=pipeline.fitter, config=config,
                                 sensor=pipeline.sensor, ranges=ranges, sigma=sigma,
                                 candidates=candidates, min_size=100)
    assert not np.isin(out, [3, 4]).any()
    assert models[3] is stale[3] and models[4] is stale[4]
    pipe = scan.truth_ids == 2
    owner, share = best_overlap(out, np.where(pipe, 7, 0), 7)
    assert share > 0.99, f"the pipe's largest region holds {share:.1%} of it"
    assert models[owner].kind == "cylinder"


def _floor_seen_near_grazing(seed=0):
    # a floor 10 cm below the sensor seen 1.5-2.5 degrees below the horizon (incidence
    # 87.5-88.5 degrees, 2.3-3.8 m away), range noise 5 mm along the rays; the floor is one
    # region except row 6 (free, as growth leaves it: each row is a range jump from the next)
    # and row 7, whose points sit 2 cm (~120 distance-noise sigmas) above the floor
    elevation = np.radians(np.linspace(-2.5, -1.5, 12))[:, None]
    azimuth = np.radians(np.linspace(-10.0, 10.0, 40))[None, :]
    rays = np.dstack(np.broadcast_arrays(np.sin(azimuth) * np.cos(elevation), np.sin(elevation),
                                         np.cos(azimuth) * np.cos(elevation)))
    ranges = 0.1 / -rays[..., 1]
    ranges = ranges + np.random.default_rng(seed).normal(0.0, 0.005, ranges.shape)
    xyz = rays * ranges[..., None]
    xyz[7, :, 1] += 0.02
    labels = np.ones((12, 40), np.int32)
    labels[6:8] = 0
    return xyz, labels


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_claim_occluded_strips_gives_a_grazing_row_on_the_plane_to_its_region(context, seed):
    xyz, labels = _floor_seen_near_grazing(seed)
    cloud = rs.OrganizedCloud(xyz)
    fits = {1: fit_plane(xyz[labels == 1])}
    out, new_fits = claim_occluded_strips(context(cloud, min_size=20, sigma=np.full((12, 40), 0.005)),
                                          labels, fits, valid=cloud.valid, k_sigma=3.0)
    assert (out[6] == 1).all()  # on the floor within its distance noise: joins it, whatever its size
    assert (out[7] == 0).all()  # 2 cm above it, within the range noise's 3 sigmas but not on it
    assert abs(new_fits[1].normal[1]) > np.cos(np.radians(0.5))


def _band_of_a_ball(seed=0, rows=8):
    # the top band of a ball (radius 0.4 m, 5.4 m away) seen by a 525-pixel pinhole camera
    # over ``rows`` image rows, Kinect-type range noise along the rays (4 cm there): a
    # band of a curved surface a few pixels thick. Returns (points, sigma per point).
    focal, centre, radius = 525.0, np.array([0.0, 0.0, 5.4]), 0.4
    top = -int(focal * radius / centre[2]) + 2
    v, u = np.mgrid[top:top + rows, -40:41].astype(float)
    rays = np.dstack([u / focal, v / focal, np.ones_like(u)])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    along = rays @ centre
    inside = along ** 2 - (centre @ centre - radius ** 2)
    hit = inside > 0
    ranges = along[hit] - np.sqrt(inside[hit])
    sigma = 0.001 + 1.425e-3 * ranges ** 2
    ranges = ranges + np.random.default_rng(seed).normal(0.0, sigma)
    return rays[hit] * ranges[:, None], sigma


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_plane_along_rays_refuses_the_ray_plane_of_a_thin_band_and_keeps_a_grazing_face(context, seed):
    # The band's least-squares plane lies along its viewing rays and fits it within the
    # range noise (what the fitter asks of a plane), though no plane is on the ball: its
    # rms is far beyond the noise of its distances. A floor seen 1.5-2.5 degrees from
    # grazing, the true plane of its pixels, is within that noise.
    points, sigma = _band_of_a_ball(seed)
    band = fit_plane(points)
    assert band.rms < np.sqrt(np.mean(sigma ** 2))  # within the range noise
    cloud = rs.OrganizedCloud(points.reshape(1, -1, 3))
    ctx = context(cloud, sigma=sigma.reshape(1, -1))
    assert ctx.plane_along_rays(band, np.arange(points.shape[0]))

    xyz, labels = _floor_seen_near_grazing(seed)
    floor_cloud = rs.OrganizedCloud(xyz)
    floor = np.flatnonzero((labels == 1).ravel())
    plane = fit_plane(xyz.reshape(-1, 3)[floor])
    floor_ctx = context(floor_cloud, sigma=np.full((12, 40), 0.005))
    assert not floor_ctx.plane_along_rays(plane, floor)
    assert not floor_ctx.plane_along_rays(None, floor)  # no model, nothing to refuse


def _wall_band_behind_a_box(seed=0, offset=0.0):
    # a wall 6 m away (Kinect-type noise along the rays, 5 cm) seen by a 525-pixel pinhole
    # camera; a box 2 m away hides rows 8-29; the wall above it is a free band of 8 rows
    # (plus ``offset`` metres towards the camera: another surface), the wall below it its
    # region. Returns (cloud, labels, fits, sigma).
    from rangeseg_o3d.synthetic.depth_camera import KINECT_NOISE

    focal = 525.0
    v, u = np.mgrid[-30:30, -60:60].astype(float)
    rays = np.dstack([u / focal, v / focal, np.ones_like(u)])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    depth = np.full(u.shape, 6.0)
    depth[8:30] = 2.0
    depth[:8] -= offset
    ranges = depth / rays[..., 2]
    sigma = 0.001 + KINECT_NOISE * ranges ** 2
    ranges = ranges + np.random.default_rng(seed).normal(0.0, sigma)
    xyz = rays * ranges[..., None]
    labels = np.zeros(u.shape, np.int32)
    labels[8:30] = 2
    labels[30:] = 1
    fits = {1: fit_plane(xyz[30:].reshape(-1, 3)), 2: fit_plane(xyz[8:30].reshape(-1, 3))}
    return rs.OrganizedCloud(xyz), labels, fits, sigma


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_claim_on_distance_noise_gives_a_wall_band_apart_from_its_region_to_it(context, seed):
    from rangeseg_o3d.refinement.recover import claim_on_distance_noise

    cloud, labels, fits, sigma = _wall_band_behind_a_box(seed)
    out = claim_on_distance_noise(context(cloud, min_size=200, sigma=sigma), labels.copy(), fits,
                                  np.flatnonzero(labels.ravel() == 0), k_sigma=3.0)
    assert (out[:8] == 1).mean() > 0.97  # the band is the wall's, across the box
    assert (out[8:] == labels[8:]).all()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_claim_on_distance_noise_leaves_a_band_off_the_plane_free(context, seed):
    # the band 15 cm in front of the wall (3 distance-noise sigmas) is another surface:
    # many of its pixels lie within the wall's 3 sigmas, but not the band as a whole
    from rangeseg_o3d.refinement.recover import claim_on_distance_noise

    cloud, labels, fits, sigma = _wall_band_behind_a_box(seed, offset=0.15)
    out = claim_on_distance_noise(context(cloud, min_size=200, sigma=sigma), labels.copy(), fits,
                                  np.flatnonzero(labels.ravel() == 0), k_sigma=3.0)
    assert (out[:8] == 0).all()
    # an empty pool or no plane: nothing to claim
    assert (claim_on_distance_noise(context(cloud, min_size=200, sigma=sigma), labels.copy(), {},
                                    np.flatnonzero(labels.ravel() == 0), k_sigma=3.0) == labels).all()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_claim_thin_strips_gives_each_surface_its_border_column_at_a_step(context, seed):
    # a board 0.5 m in front of a wall (2 mm noise); each region stops at its border column
    # beside the step (marked a jump there, so never grown into): the board's column goes to
    # the board, the wall's to the wall; a band 4 cm in front of the wall (20 sigma) stays
    # free, and so do the pixels of a blob (the split's to fit)
    from rangeseg_o3d.refinement.recover import claim_thin_strips

    xyz = plane_grid(40, 60, z=3.0, noise=0.002, seed=seed)
    xyz[:, 20:28, 2] -= 0.5
    xyz[:, 40:42, 2] -= 0.04
    labels = np.ones((40, 60), np.int32)
    labels[:, 19:29] = 0
    labels[:, 21:27] = 2
    labels[:, 40:42] = 0
    labels[10:17, 50:57] = 0  # a blob of the wall
    candidates = np.zeros_like(labels)
    candidates[10:17, 50:57] = 3
    cloud = rs.OrganizedCloud(xyz)
    sigma = np.full((40, 60), 0.002)
    fits = {1: fit_plane(xyz[labels == 1]), 2: fit_plane(xyz[labels == 2])}
    before = labels.copy()
    out = claim_thin_strips(context(cloud, min_size=20, sigma=sigma), labels, fits, candidates,
                            valid=cloud.valid, k_sigma=3.0)
    assert (labels == before).all()  # the input is left alone
    # (a pixel beyond 3 sigmas of its own plane stays free)
    assert (out[:, [20, 27]] == 2).mean() > 0.95 and (out[:, [19, 28]] == 1).mean() > 0.95
    assert (out[:, [20, 27]] != 1).all() and (out[:, [19, 28]] != 2).all()
    assert (out[:, 40:42] == 0).all() and (out[10:17, 50:57] == 0).all()
    assert (out[before > 0] == before[before > 0]).all()
    # recover_leftovers asks for it with thin_strips (at sensor resolution), not otherwise
    jumps = np.zeros(labels.shape, bool)
    jumps[:, 19:21] = jumps[:, 27:29] = True
    common = dict(xyz=xyz, valid=cloud.valid, jumps=jumps, ranges=cloud.range_image(), sigma=sigma,
                  k_sigma=3.0, jump_ratio=0.08, jump_min=0.05)
    no_blob = labels.copy()
    no_blob[10:17, 50:57] = 1  # (a recovered blob's rim growth would take them)
    for asked in (False, True):
        got, _ = recover_leftovers(context(cloud, min_size=20, sigma=sigma), no_blob, fits, thin_strips=asked,
                                   **common)
        assert ((got[:, [20, 27]] == 2).mean() > 0.95) == asked
    # strips under the size floor (the two columns beside each side of the step: 80 pixels) stay free
    small = claim_thin_strips(context(cloud, min_size=81, sigma=sigma), labels, fits, candidates,
                              valid=cloud.valid, k_sigma=3.0)
    assert (small == labels).all()



@pytest.mark.parametrize("seed", range(3))
def test_claim_thin_strips_offers_the_strips_numpy_keeps(context, seed, monkeypatch):
    # the pool of strips offered to the planes (kernels.member_pixels of the kept strips)
    # is numpy's flatnonzero(kept[strips]), on random leftovers of many strip sizes
    import cv2

    import rangeseg_o3d.refinement.recover as recover

    rng = np.random.default_rng(seed)
    labels = np.where(rng.random((30, 40)) < 0.3, 0, 1).astype(np.int32)
    candidates = np.where(rng.random(labels.shape) < 0.1, 7, 0).astype(np.int32)
    valid = rng.random(labels.shape) > 0.05
    xyz = plane_grid(30, 40, z=3.0, noise=0.002, seed=seed)
    offered = []
    monkeypatch.setattr(recover, "claim_on_distance_noise",
                        lambda ctx, labels, fits, pool, **kw: offered.append(pool) or labels)
    for min_size in (1, 3, 6):
        free = valid & (labels == 0) & (candidates == 0)
        n, strips = cv2.connectedComponents(free.astype(np.uint8), connectivity=4, ltype=cv2.CV_32S)
        kept = np.bincount(strips.ravel(), minlength=n) >= min_size
        kept[0] = False
        expected = np.flatnonzero(kept[strips].ravel())
        offered.clear()
        recover.claim_thin_strips(context(rs.OrganizedCloud(xyz), min_size=min_size), labels, {}, candidates,
                                  valid=valid, k_sigma=3.0)
        if expected.size:
            assert len(offered) == 1
            np.testing.assert_array_equal(offered[0], expected)
        else:
            assert not offered


def test_fresh_label_is_above_every_label_and_every_model():
    from rangeseg_o3d.fitting.region_fitter import fresh_label

    labels = np.array([[0, 2], [7, 1]], np.int32)
    assert fresh_label(labels, {}) == 8
    assert fresh_label(labels, {1: None, 12: None}) == 13
    assert fresh_label(np.zeros((3, 3), np.int32), {}) == 1


def _grazing_face_in_pieces(seed=0, lateral_px=0.5, turn_deg=0.0):
    # A face seen 86 degrees from head-on, 0.9 m away, by a 1600-pixel pinhole camera (ABW's
    # columns): a band of 5 rows x 120 columns whose depth grows by ~8 mm a row, cut by two
    # columns of jump pixels (free) into three pieces (labels 5, 6, 7), and a fourth piece
    # (label 8) beyond a third cut, on that face turned by ``turn_deg`` about the view axis.
    # Each return measures the face ``lateral_px`` pixel steps (rms) beside its ray and
    # reports it on its ray, with 0.36 mm of range noise. Returns (xyz, labels, sigma).
    focal, rng = 1600.0, np.random.default_rng(seed)
    v, u = np.mgrid[-2:3, -60:101].astype(float)
    cosine = np.cos(np.radians(86.0))

    def normal(turn):
        t = np.radians(turn)
        return np.array([-np.sqrt(1 - cosine ** 2) * np.sin(t), -np.sqrt(1 - cosine ** 2) * np.cos(t), cosine])

    rays = np.dstack([u / focal, v / focal, np.ones_like(u)])
    beside = np.dstack([(u + rng.normal(0, lateral_px, u.shape)) / focal,
                        (v + rng.normal(0, lateral_px, u.shape)) / focal, np.ones_like(u)])
    xyz = np.empty(u.shape + (3,))
    for columns, turn in ((u < 60, 0.0), (u >= 60, turn_deg)):
        n = normal(turn)
        depth = (n @ np.array([0.0, 0.0, 0.9])) / (beside[columns] @ n)  # z of the point measured
        xyz[columns] = rays[columns] * depth[:, None]
    norm = np.linalg.norm(xyz, axis=2, keepdims=True)
    xyz += xyz / norm * rng.normal(0.0, 0.00036, u.shape)[..., None]
    labels = np.select([u < -20, (u > -20) & (u < 20), (u > 20) & (u < 60), u > 60], [5, 6, 7, 8], 0)
    return xyz, labels.astype(np.int32), np.full(u.shape, 0.00036)


def _join(context, xyz, labels, sigma, pieces, lateral):
    from rangeseg_o3d.refinement.recover import _join_grazing_pieces

    cloud = rs.OrganizedCloud(xyz)
    ctx = context(cloud, min_size=60, sigma=sigma)
    fits = {k: fit_plane(xyz[labels == k]) for k in pieces}
    new = dict(fits)
    pool = np.flatnonzero(np.isin(labels, pieces).ravel())
    labels = labels.copy()
    refused = {k for k in pieces if ctx.plane_along_rays(fits[k], np.flatnonzero((labels == k).ravel()))}
    kept = _join_grazing_pieces(ctx, labels, fits, new, refused, pool, lateral)
    return refused, kept, labels, fits, new


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pieces_of_a_grazing_face_cut_by_jumps_come_back_as_one_region(context, seed):
    # Each piece alone is beyond the range noise times the incidence cosine (0.025 mm) of its
    # distances, its points scattered 0.28 mm off the face by the lateral offset: refused.
    # Joined with the lateral noise, the three pieces are one plane within it, the face's.
    xyz, labels, sigma = _grazing_face_in_pieces(seed)
    refused, kept, out, fits, new = _join(context, xyz, labels, sigma, [5, 6, 7], 0.5 / 1600)
    assert refused == {5, 6, 7}
    assert kept == set()
    assert (out[np.isin(labels, [5, 6, 7])] == 5).all() and (out[labels == 0] == 0).all()
    assert set(fits) == set(new) == {5}
    face = np.array([0.0, -np.sin(np.radians(86.0)), np.cos(np.radians(86.0))])
    assert np.degrees(np.arccos(min(1.0, abs(fits[5].normal @ face)))) < 1.0


@pytest.mark.parametrize("seed", [0, 1])
def test_grazing_pieces_stay_refused_without_lateral_noise_alone_or_across_a_turn(context, seed):
    xyz, labels, sigma = _grazing_face_in_pieces(seed, turn_deg=20.0)
    # a sensor that reports the surface on its rays: no lateral noise, nothing joins
    refused, kept, out, _, _ = _join(context, xyz, labels, sigma, [5, 6, 7], 0.0)
    assert kept == refused == {5, 6, 7}
    np.testing.assert_array_equal(out, labels)
    # one thin piece alone (what mixed pixels along an occluding contour look like too)
    refused, kept, out, _, _ = _join(context, xyz, labels, sigma, [6], 0.5 / 1600)
    assert kept == refused == {6}
    # the piece on the turned face does not join the others, which still join each other
    refused, kept, out, fits, _ = _join(context, xyz, labels, sigma, [5, 6, 7, 8], 0.5 / 1600)
    assert 8 in refused and kept == {8}
    assert (out[labels == 8] == 8).all() and (out[np.isin(labels, [5, 6, 7])] == 5).all()


def _plane_that_took_a_band(seed=0):
    # A plane found on columns 0-9 (label 5, its pixels 0.03 mm rms about z = 1 m, seen
    # head-on under 0.01 mm of range noise) whose rim and claims took columns 10-11 of the
    # plane beside it (label 1, 0.2 mm behind): refitted with them its rms is 0.1 mm.
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:10, 0:20].astype(float)
    z = np.where(cols < 10, 1.0 + rng.normal(0.0, 3e-5, cols.shape), 1.0002)
    xyz = np.dstack([0.001 * cols, 0.001 * rows, z])
    before = np.where(cols < 10, 0, 1).astype(np.int32)
    found = np.where(cols < 10, 5, 1).astype(np.int32)
    labels = np.where(cols < 12, 5, 1).astype(np.int32)
    fits = {1: Plane(normal=np.array([0.0, 0.0, 1.0]), d=1.0002, rms=3e-5, inliers=100),
            5: Plane(normal=np.array([0.0, 0.0, 1.0]), d=1.0, rms=1e-4, inliers=120)}
    return xyz, before, found, labels, fits


def test_gains_of_a_recovered_plane_are_held_to_the_rms_of_the_pixels_it_was_found_on(context):
    from rangeseg_o3d.refinement.recover import _gains_within_distance_noise

    xyz, before, found, labels, fits = _plane_that_took_a_band()
    ctx = context(rs.OrganizedCloud(xyz), sigma=np.full(labels.shape, 1e-5))
    # the band lies 0.2 mm off the plane: within three of its rms now (0.1 mm), which the
    # band itself raised, beyond three of the rms of its own pixels (0.03 mm)
    out = _gains_within_distance_noise(ctx, before, found, labels.copy(), fits, set(), below=6,
                                       found_rms={5: 3e-5})
    np.testing.assert_array_equal(out, found)  # the band goes back to the plane beside it
    # held to its rms now (the rule switched off), the plane keeps what it took
    kept = _gains_within_distance_noise(ctx, before, found, labels.copy(), fits, set(), below=6)
    np.testing.assert_array_equal(kept, labels)
    # a rms found larger than the one now does not loosen the bar
    kept = _gains_within_distance_noise(ctx, before, found, labels.copy(), fits, set(), below=6,
                                        found_rms={5: 1e-3})
    np.testing.assert_array_equal(kept, labels)


def test_a_region_that_merged_recovered_planes_is_held_to_their_rms_as_found():
    from rangeseg_o3d.refinement.recover import _merged_rms_as_found

    # planes 10 and 11 found in the blobs (pool: flat pixels 0-9); 10 merged into tile region
    # 3 since, 11 into 12 (found in the blobs too, with its own rms): each held to the largest
    # rms as found of the planes it holds
    found = np.array([10, 10, 10, 10, 11, 11, 12, 12, 0, 0, 3, 3], np.int32)
    labels = np.array([3, 3, 3, 0, 12, 12, 12, 12, 0, 0, 3, 3], np.int32)
    pool = np.arange(10)
    plane = Plane(normal=np.array([0.0, 0.0, 1.0]), d=1.0, rms=1e-4, inliers=8)
    fits = {3: plane, 12: plane}
    found_rms = {10: 3e-5, 11: 5e-5, 12: 2e-5}
    floors = _merged_rms_as_found(found_rms, fits, found, labels, pool)
    assert floors == {10: 3e-5, 11: 5e-5, 12: 5e-5, 3: 3e-5}
    # 12 merged into 11 instead: the same floor, whichever piece kept its label
    swapped = {3: plane, 11: plane}
    floors = _merged_rms_as_found(found_rms, swapped, found, np.where(labels == 12, 11, labels), pool)
    assert floors == {10: 3e-5, 11: 5e-5, 12: 2e-5, 3: 3e-5}
    # nothing merged away: the rms as found, unchanged
    assert _merged_rms_as_found({12: 2e-5}, fits, found, labels, pool) == {12: 2e-5}


def test_grouped_pixels_are_those_of_a_membership_test_by_label():
    # the flat pixels (increasing) of each wanted label, as np.isin and a comparison per label
    # give them: labels absent, wanted labels above every owner, none wanted, no pixels
    from rangeseg_o3d.refinement.recover import _grouped

    rng = np.random.default_rng(4)
    for trial in range(200):
        n = int(rng.integers(0, 2000))
        pixels = np.sort(rng.choice(10 ** 6, n, replace=False))
        owner = rng.integers(0, 40, n).astype(np.int32)
        only = set(rng.integers(0, 60, int(rng.integers(0, 8))).tolist())
        keep = np.isin(owner, list(only))
        want = {k: pixels[keep][owner[keep] == k] for k in np.unique(owner[keep]).tolist()}
        got = _grouped(pixels, owner, only)
        assert got.keys() == want.keys(), trial
        for k in want:
            np.testing.assert_array_equal(got[k], want[k])


def _ball_before_a_wall(h=60, w=60, step=0.004):
    # a ball (r 0.2 m, 3 m away) before a wall at 4 m, rays from the origin on a grid of
    # ``step`` radians: the ball's pixels within 0.12 m of its axis are its region (1), those
    # farther out (its limb) are free, the wall is region 2
    from rangeseg_o3d.fitting.primitives import Sphere

    a = (np.arange(h) - h / 2) * step
    b = (np.arange(w) - w / 2) * step
    rays = np.stack(np.broadcast_arrays(np.tan(b)[None, :], np.tan(a)[:, None], np.ones((h, w))), axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    centre, radius = np.array([0.0, 0.0, 3.0]), 0.2
    along = rays @ centre
    disc = along ** 2 - (centre @ centre - radius ** 2)
    hit = disc > 0
    t = np.where(hit, along - np.sqrt(np.where(hit, disc, 0.0)), 4.0 / rays[..., 2])
    xyz = rays * t[..., None]
    off_axis = np.linalg.norm(xyz[..., :2], axis=-1)
    labels = np.where(hit, np.where(off_axis < 0.12, 1, 0), 2).astype(np.int32)
    fits = {1: Sphere(center=centre, radius=radius, rms=0.002, inliers=int((labels == 1).sum())),
            2: Plane(normal=np.array([0.0, 0.0, 1.0]), d=4.0, rms=0.002, inliers=int((labels == 2).sum()))}
    return xyz, labels, fits, hit


def test_a_balls_free_limb_joins_its_region_within_the_pool_only(context):
    from rangeseg_o3d.refinement.recover import claim_curved_rims

    xyz, labels, fits, hit = _ball_before_a_wall()
    cloud = rs.OrganizedCloud(xyz)
    limb = hit & (labels == 0)
    assert limb.sum() > 300
    # the pool: the limb's left half, and the three columns of the wall left of the ball,
    # freed, where they touch the limb (a metre behind it)
    left_edge = int(np.flatnonzero(hit.any(axis=0))[0])
    wall_strip = (labels == 2) & (np.abs(np.arange(60) - (left_edge - 2))[None, :] <= 1) & hit.any(axis=1)[:, None]
    labels[wall_strip] = 0
    assert (wall_strip[:, left_edge - 1] & hit[:, left_edge]).any()  # the strip touches the limb
    pool_mask = (limb & (np.arange(60) < 30)[None, :]) | wall_strip
    pool = np.flatnonzero(pool_mask)
    before = labels.copy()
    out = claim_curved_rims(context(cloud), labels, fits, pool, ranges=np.linalg.norm(xyz, axis=-1), k_sigma=3.0)
    assert out is labels
    assert (out[limb & pool_mask] == 1).all()  # the limb in the pool joins the ball
    assert (out[limb & ~pool_mask] == 0).all()  # outside the pool nothing moves
    assert (out[wall_strip] == 0).all()  # a plane region does not grow here, nor the ball over the wall
    assert (out[~pool_mask] == before[~pool_mask]).all()


def test_claiming_a_limb_refuses_labels_it_cannot_change_in_place(context):
    from rangeseg_o3d.refinement.recover import claim_curved_rims

    xyz, labels, fits, _ = _ball_before_a_wall()
    strided = np.asfortranarray(labels)
    with pytest.raises(ValueError, match="C-contiguous"):
        claim_curved_rims(context(rs.OrganizedCloud(xyz)), strided, fits, np.flatnonzero(labels == 0),
                          ranges=np.linalg.norm(xyz, axis=-1), k_sigma=3.0)
