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
