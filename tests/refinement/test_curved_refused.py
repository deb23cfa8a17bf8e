"""A recovered plane refused beyond the noise of its distances becomes the curved model
the fitter finds when asked to resolve its bend (rangeseg_o3d.refinement.curved_refused,
called from recover_pixels): a pillar the tile grid left whole, a pillar's piece apart."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.synthetic.depth_camera import camera_pose_scene
from refinement_helpers import best_overlap


def _pillar_left_by_the_tiles(seed, kept_rows=0):
    # A pillar (radius 0.14 m, upright) 3.1 m from a Kinect-type camera, in front of a wall
    # 4 m away, its left half hidden by a board 2.1 m away: the tile grid kept the wall, the
    # board and, with ``kept_rows``, the pillar's lowest rows (its cylinder fitted to them,
    # six rows above left out as by a box before it), and left the rest of the pillar
    # unlabelled, every tile mean straddling its bend.
    from rangeseg_o3d.fitting import fit_cylinder
    from rangeseg_o3d.scales import with_derived_refinement
    from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
    from rangeseg_o3d.synthetic.scene import Scene, cylinder, patch

    world = Scene(patch((4.0, 0.0, 0.0), (0, 1, 0), (0, 0, 1), 2.0, 1.0, first_id=1)
                  + cylinder((3.1, 0.0, -0.6), (0, 0, 1), 0.14, 1.2, caps=False, first_id=2)
                  + patch((2.1, 0.5, 0.0), (0, 1, 0), (0, 0, 1), 0.5, 1.0, first_id=3))
    scan = simulate_depth_camera(camera_pose_scene(world), width=200, height=80, cx=99.5, cy=39.5, seed=seed)
    pipeline = rs.Pipeline("rgbd_vga")
    cloud = scan.cloud
    ranges = np.where(cloud.valid, cloud.range_image(), np.nan)
    pillar = scan.truth_ids == 2
    labels = np.where(scan.truth_ids == 1, 1, np.where(scan.truth_ids == 3, 3, 0)).astype(np.int32)
    fits = {k: pipeline.fitter.fit(cloud.xyz[labels == k]) for k in (1, 3)}
    if kept_rows:
        kept = pillar & (np.arange(pillar.shape[0])[:, None] >= pillar.shape[0] - kept_rows)
        labels[kept] = 2
        fits[2] = fit_cylinder(cloud.xyz[kept])
        labels[pillar & ~kept & (np.arange(pillar.shape[0])[:, None] >= pillar.shape[0] - kept_rows - 6)] = 1
    config = with_derived_refinement(pipeline.config.refine, pipeline.sensor, cloud)
    return scan, pipeline, labels, fits, config, ranges, pipeline.sensor.noise.sigma(ranges)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_pillar_the_tiles_left_whole_is_recovered_as_its_cylinder(seed):
    # At full resolution a plane fits the pillar within the Kinect's range noise (the
    # fitter's threshold at 3.1 m), but beyond the noise of its distances to that plane:
    # refused, the pillar was freed whole. Asked to resolve its bend over its independent
    # returns, the fitter finds the cylinder, which holds its pixels within that noise.
    from rangeseg_o3d.fullres import leftover_blob_labels
    from rangeseg_o3d.refinement.curved_refused import full_resolution_samples
    from rangeseg_o3d.refinement.recover import recover_pixels

    scan, pipeline, labels, fits, config, ranges, sigma = _pillar_left_by_the_tiles(seed)
    pillar = scan.truth_ids == 2
    assert pipeline.fitter.fit(scan.cloud.xyz[pillar]).kind == "plane"  # the fitter's first answer
    assert full_resolution_samples(pipeline.sensor) == 1.0
    candidates = leftover_blob_labels(labels, scan.cloud.valid, min_size=100, first_label=4)[0]
    out, models = recover_pixels(scan.cloud, labels, dict(fits), fitter=pipeline.fitter, config=config,
                                 sensor=pipeline.sensor, ranges=ranges, sigma=sigma,
                                 candidates=candidates, min_size=100)
    owner, share = best_overlap(out, np.where(pillar, 7, 0), 7)
    assert share > 0.95, f"the pillar's largest region holds {share:.1%} of it"
    assert models[owner].kind == "cylinder"
    assert abs(models[owner].radius - 0.14) < 0.03


@pytest.mark.parametrize("seed", [0, 1])
def test_a_pillars_piece_apart_joins_the_pillars_cylinder(seed):
    # The pillar's lowest rows are a cylinder region already, six rows above them another
    # surface's: the piece above, recovered as a cylinder of its own, is the same surface
    # (similar models, the region's cylinder fits it within the merge's rms factor) and
    # joins that region, its model kept.
    from rangeseg_o3d.fullres import leftover_blob_labels
    from rangeseg_o3d.refinement.recover import recover_pixels

    scan, pipeline, labels, fits, config, ranges, sigma = _pillar_left_by_the_tiles(seed, kept_rows=30)
    assert fits[2].kind == "cylinder"
    candidates = leftover_blob_labels(labels, scan.cloud.valid, min_size=100, first_label=4)[0]
    out, models = recover_pixels(scan.cloud, labels, dict(fits), fitter=pipeline.fitter, config=config,
                                 sensor=pipeline.sensor, ranges=ranges, sigma=sigma,
                                 candidates=candidates, min_size=100)
    above = (scan.truth_ids == 2) & (labels == 0)
    assert (out[above] == 2).mean() > 0.95
    assert models[2] is fits[2] and set(models) == {1, 2, 3}


def test_full_resolution_samples_follow_the_sensors_noise():
    from rangeseg_o3d.refinement.curved_refused import full_resolution_samples
    from rangeseg_o3d.sensor import NoiseModel, Sensor

    assert full_resolution_samples(Sensor(NoiseModel(0.001, 0.001425))) == 1.0
    assert full_resolution_samples(Sensor(NoiseModel(0.001, 0.0002, correlation_px=3))) == pytest.approx(1 / 9)
    assert full_resolution_samples(Sensor(NoiseModel(0.0005), depth_step=0.00126)) == 0.0


def _pipe_half_hidden(seed, edge):
    # A pipe (radius 0.13 m, upright) 4 m from a Kinect-type camera before a wall 5 m away, a
    # board 3 m away hiding it left of ``edge`` (m, at the board): 12-8 columns of the pipe are
    # seen, its range noise (24 mm) about three pixel footprints. No tile model holds it.
    from rangeseg_o3d.scales import with_derived_refinement
    from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
    from rangeseg_o3d.synthetic.scene import Scene, cylinder, patch

    world = Scene(patch((5.0, 0.0, 0.0), (0, 1, 0), (0, 0, 1), 2.0, 1.0, first_id=1)
                  + cylinder((4.0, 0.0, -0.6), (0, 0, 1), 0.13, 1.2, caps=False, first_id=2)
                  + patch((3.0, 0.5 + edge, 0.0), (0, 1, 0), (0, 0, 1), 0.5, 1.0, first_id=3))
    scan = simulate_depth_camera(camera_pose_scene(world), width=200, height=160, cx=99.5, cy=79.5, seed=seed)
    pipeline = rs.Pipeline("rgbd_vga")
    cloud = scan.cloud
    ranges = np.where(cloud.valid, cloud.range_image(), np.nan)
    labels = np.where(scan.truth_ids == 1, 1, np.where(scan.truth_ids == 3, 3, 0)).astype(np.int32)
    fits = {k: pipeline.fitter.fit(cloud.xyz[labels == k]) for k in (1, 3)}
    config = with_derived_refinement(pipeline.config.refine, pipeline.sensor, cloud)
    return scan, pipeline, labels, fits, config, ranges, pipeline.sensor.noise.sigma(ranges)


@pytest.mark.parametrize("edge, radius_error", [(-0.03, 0.03), (-0.05, 0.07)])
def test_a_pipe_seen_on_a_narrow_arc_under_kinect_noise_is_fitted_on_its_range_means(edge, radius_error, monkeypatch):
    # Its pixels' plane leaves them beyond the noise of their distances (refused), the fitter
    # calls them a plane, and the geometric cylinder fit started from their spread along the
    # rays does not converge: the pipe was freed. Fitted on its means over 3 x 3 blocks of its
    # own pixels, the cylinder holds the pixels within that noise.
    import rangeseg_o3d.refinement.recover as recover
    from rangeseg_o3d.fullres import leftover_blob_labels

    scan, pipeline, labels, fits, config, ranges, sigma = _pipe_half_hidden(0, edge)
    pipe = scan.truth_ids == 2
    assert pipeline.fitter.fit(scan.cloud.xyz[pipe]).kind == "plane"
    step = recover._means_step(pipeline.sensor, scan.cloud)
    assert step == pytest.approx(np.radians(0.11))

    def recovered():
        candidates = leftover_blob_labels(labels, scan.cloud.valid, min_size=100, first_label=4)[0]
        return recover.recover_pixels(scan.cloud, labels, dict(fits), fitter=pipeline.fitter, config=config,
                                      sensor=pipeline.sensor, ranges=ranges, sigma=sigma,
                                      candidates=candidates, min_size=100)

    out, models = recovered()
    owner, share = best_overlap(out, np.where(pipe, 7, 0), 7)
    assert owner > 0 and share > 0.95, f"the pipe's largest region holds {share:.1%} of it"
    assert models[owner].kind == "cylinder"
    assert abs(models[owner].radius - 0.13) < radius_error
    monkeypatch.setattr(recover, "_means_step", lambda sensor, cloud: 0.0)  # without the means: no cylinder
    out, models = recovered()
    owner, _ = best_overlap(out, np.where(pipe, 7, 0), 7)
    # (freed before planes were fitted along the rays on this sensor; now the plane along the
    # rays explains the pipe within the noise: why the bend test on the means is asked first)
    assert owner > 0 and models[owner].kind == "plane"


def test_means_step_only_where_the_noise_spans_the_grid_and_errs_pixel_by_pixel():
    import rangeseg_o3d.refinement.recover as recover

    kinect = rs.Pipeline("rgbd_vga").sensor
    cloud = rs.OrganizedCloud(np.dstack([np.zeros((4, 4)), np.zeros((4, 4)), np.ones((4, 4))]))
    assert recover._means_step(kinect, cloud) == pytest.approx(np.radians(0.11))
    for preset in ("lms200", "abw", "spinning_lidar"):
        assert recover._means_step(rs.Pipeline(preset).sensor, cloud) == 0.0
    stereo = rs.load_config("rgbd_vga", overrides={"sensor.noise_correlation_px": 3})
    assert recover._means_step(rs.Pipeline(stereo).sensor, cloud) == 0.0


def test_mean_window_and_block_means():
    from rangeseg_o3d._numeric import rows_at
    from rangeseg_o3d.refinement.curved_refused import block_means, mean_window

    step = np.radians(0.11)
    # a Kinect at 2-5 m: the noise is 1.8-3.9 footprints, the 3 x 3 mean's under its 3
    for r in (2.0, 4.0, 5.0):
        assert mean_window(0.001 + 1.425e-3 * r * r, r, step) == 3
    assert mean_window(0.5, 4.0, step) == 9  # 0.5 / (4 step) = 65: sqrt 8.1 -> 9
    assert mean_window(1e-6, 4.0, step) == 3
    with pytest.raises(ValueError, match="positive"):
        mean_window(0.0, 4.0, step)
    # a 5 x 6 grid of points (column, row, 10 * column + row)
    h, w = 5, 6
    r, c = np.mgrid[0:h, 0:w].astype(float)
    xyz = np.dstack([c, r, 10 * c + r]).reshape(-1, 3)
    idx = np.array([7, 8, 9, 13, 14, 15, 27])  # a 2 x 3 block and a lone pixel
    out = block_means(xyz, w, idx, 3)
    # blocks from row 1, column 1: rows 1-3 x columns 1-3 holds the six (kept: >= 4.5 of 9),
    # rows 4-6 the lone pixel 27 (dropped)
    assert out.shape == (1, 3)
    assert np.allclose(out[0], rows_at(xyz, idx[:6]).mean(axis=0))
    assert np.array_equal(block_means(xyz, w, idx, 1), rows_at(xyz, idx))
    assert block_means(xyz, w, idx[:0], 3).shape == (0, 3)
    with pytest.raises(ValueError, match="window"):
        block_means(xyz, w, idx, 0)


@pytest.mark.parametrize("edge", [-0.03, -0.05])
def test_planes_for_unresolved_keeps_a_narrow_pipes_cylinder_its_plane_does_not_explain(edge):
    # The pipe's pixels' plane, turned towards the rays, leaves fewer squared distances than
    # its cylinder (the F-test calls the bend unresolved and gave the pipe that plane); by the
    # noise of their distances only the cylinder explains them, so on a camera whose noise
    # spans the grid (by_distance_noise) the cylinder stays.
    from rangeseg_o3d.fullres import leftover_blob_labels, planes_for_unresolved, region_stats
    from rangeseg_o3d.refinement.recover import recover_pixels
    from rangeseg_o3d.result import INLIER_SIGMAS

    scan, pipeline, labels, fits, config, ranges, sigma = _pipe_half_hidden(0, edge)
    pipe = scan.truth_ids == 2
    candidates = leftover_blob_labels(labels, scan.cloud.valid, min_size=100, first_label=4)[0]
    out, models = recover_pixels(scan.cloud, labels, dict(fits), fitter=pipeline.fitter, config=config,
                                 sensor=pipeline.sensor, ranges=ranges, sigma=sigma, candidates=candidates,
                                 min_size=100)
    owner, _ = best_overlap(out, np.where(pipe, 7, 0), 7)
    assert models[owner].kind == "cylinder"
    stats = region_stats(scan.cloud.xyz, out, models, sigma, INLIER_SIGMAS)
    plain, _ = planes_for_unresolved(scan.cloud, out, models, stats, sigma=sigma, inlier_factor=INLIER_SIGMAS)
    assert plain[owner].kind == "plane"
    kept, kept_stats = planes_for_unresolved(scan.cloud, out, models, stats, sigma=sigma,
                                             inlier_factor=INLIER_SIGMAS, by_distance_noise=True)
    assert kept[owner] is models[owner] and kept_stats.squares[owner] == stats.squares[owner]
    # the wall and the board (planes) are untouched either way
    assert kept[1] is models[1] and kept[3] is models[3]
