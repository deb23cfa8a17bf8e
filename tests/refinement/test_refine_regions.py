"""The refinement as a whole: its steps in run order, each timed, the inputs left alone."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.fitting.primitives import FitFailure
from rangeseg_o3d.refinement import refine_regions
from rangeseg_o3d.result import Regions
from refinement_helpers import best_overlap, folded_strip

STEPS = ["refine.split", "refine.grow", "refine.recover", "refine.facets", "refine.merge", "refine.settle",
         "refine.dissolve", "refine.polish", "refine.rays"]


def _refine_one_failed_region(pipeline, cloud, timings=None):
    labels = np.ones(cloud.shape, np.int32)  # the segmenter saw no crease at all
    fits = {1: FitFailure("plane", "rms over the limit")}
    ranges = cloud.range_image()
    sigma = pipeline.sensor.noise.sigma(ranges)
    out = refine_regions(cloud, Regions(labels, fits), fitter=pipeline.fitter, config=pipeline.config.refine,
                         sensor=pipeline.sensor, ranges=ranges, sigma=sigma, jumps=None,
                         timings={} if timings is None else timings)
    assert (labels == 1).all() and not fits[1] and list(fits) == [1]  # inputs unchanged
    return out.labels, out.models


def test_three_planes_leaking_into_one_region_come_back_as_three(pipeline):
    xyz, truth, normals = folded_strip(noise=0.001)
    timings = {}
    labels, fits = _refine_one_failed_region(pipeline, rs.OrganizedCloud(xyz), timings)
    found = {}
    for k in (1, 2, 3):
        best, share = best_overlap(labels, truth, k)
        assert best > 0, f"plane {k} left unlabelled"
        # most of the surface in one region, and that region mostly this surface
        assert share >= 0.9
        assert (truth[labels == best] == k).mean() >= 0.9
        model = fits[best]
        assert model and model.kind == "plane"
        assert abs(float(model.normal @ normals[k])) >= np.cos(np.radians(1.0))
        found[k] = best
    assert len(set(found.values())) == 3
    # every step timed under its own name, in run order
    assert list(timings) == STEPS and all(t >= 0 for t in timings.values())


def test_steps_switched_off_still_report_their_time(pipeline):
    config = pipeline.config.refine.model_copy(update={"merge": False, "recover_leftovers": False})
    cloud = rs.OrganizedCloud(folded_strip(noise=0.001)[0])
    ranges = cloud.range_image()
    timings = {}
    refine_regions(cloud, Regions(np.ones(cloud.shape, np.int32), {1: FitFailure("plane", "x")}),
                   fitter=pipeline.fitter, config=config, sensor=pipeline.sensor, ranges=ranges,
                   sigma=pipeline.sensor.noise.sigma(ranges), jumps=None, timings=timings)
    assert list(timings) == STEPS


def test_a_region_of_pure_noise_stays_an_unfitted_failure(pipeline):
    rng = np.random.default_rng(1)
    v, u = np.mgrid[0:30, 0:30].astype(float)
    xyz = np.dstack([u * 0.02, v * 0.02, 3.0 + rng.uniform(-0.3, 0.3, u.shape)])
    labels, fits = _refine_one_failed_region(pipeline, rs.OrganizedCloud(xyz))
    assert not fits[1]
    assert set(np.unique(labels)) == {1}


def test_bend_samples_counts_a_stated_correlation_and_keeps_the_bend_test_to_laser_returns_otherwise():
    import pytest

    from rangeseg_o3d.refinement import bend_samples
    from rangeseg_o3d.sensor import NoiseModel, Sensor

    def sensor(sigma_quadratic=0.0, correlation=1):
        return Sensor(noise=NoiseModel(0.01, sigma_quadratic, correlation))

    # a laser's single returns: one sample each; its tile means and a camera's returns: no test
    assert bend_samples(sensor(), 1) == 1.0
    assert bend_samples(sensor(), 2) == 0.0
    assert bend_samples(sensor(0.0014), 1) == 0.0 and bend_samples(sensor(0.0014), 6) == 0.0
    # a stereo camera's 3-px matching window: what the correlation leaves of each point
    stereo = sensor(0.003, 3)
    assert bend_samples(stereo, 1) == pytest.approx(1 / 9)
    assert bend_samples(stereo, 6) == pytest.approx(stereo.noise.independent_share(6))
    assert 0.7 < bend_samples(stereo, 6) < 0.75


def test_polish_fits_along_the_rays_for_a_lasers_single_returns_only_not_a_cameras_on_a_tile_of_one(
        pipeline, monkeypatch):
    # a structured-light camera (the ABW preset's model: constant noise, uncorrelated, depth
    # steps and a lateral noise) on a grid of single returns: its model says camera, and the
    # range-residual polish is not asked for, as it is for a laser of the same noise
    import rangeseg_o3d.refinement as refinement
    from rangeseg_o3d.refinement import single_returns
    from rangeseg_o3d.sensor import NoiseModel, Sensor

    laser = Sensor(noise=NoiseModel(0.00036, 0.0, 1))
    cameras = [Sensor(noise=NoiseModel(0.00036, 0.0, 1), depth_step=0.00129, lateral_noise_px=0.5),
               Sensor(noise=NoiseModel(0.00036, 0.0, 1), depth_step=0.00129),
               Sensor(noise=NoiseModel(0.00036, 0.0, 1), lateral_noise_px=0.5)]
    assert single_returns(laser, 1) and not single_returns(laser, 2)
    assert not any(single_returns(camera, 1) for camera in cameras)
    asked = []
    polish = refinement.polish_models

    def spy(*args, **kwargs):
        asked.append(kwargs["along_rays"])
        return polish(*args, **kwargs)

    monkeypatch.setattr(refinement, "polish_models", spy)
    xyz = folded_strip(noise=0.001)[0]
    cloud = rs.OrganizedCloud(xyz)
    ranges = cloud.range_image()
    assert cloud.tile == 1
    for sensor in [laser, *cameras]:
        refine_regions(cloud, Regions(np.ones(cloud.shape, np.int32), {1: FitFailure("plane", "x")}),
                       fitter=pipeline.fitter, config=pipeline.config.refine, sensor=sensor, ranges=ranges,
                       sigma=sensor.noise.sigma(ranges), jumps=None, timings={})
    assert asked == [True, False, False, False]


@pytest.mark.parametrize("seed", [1, 2])
def test_a_column_whose_halves_become_its_cylinder_joins_its_other_curved_piece(seed):
    # a column of radius 0.25 m 3 m away (axis along y, over 100 degrees, 40 x 60 grid) under
    # 2 cm range noise along the rays: rows 0-19 as two planes (its halves), rows 20-39 one
    # cylinder region. The halves become a cylinder only after the merge of same-kind
    # regions (planes_into_curved), which then meets the other piece, a cylinder too.
    noise = 0.02
    pipe = rs.Pipeline(rs.load_config("lms200", overrides={"sensor.sigma0": noise}))
    v, u = np.mgrid[0:40, 0:60].astype(float)
    angle = np.radians(-50.0 + 100.0 * u / 59.0)
    surface = np.dstack([0.25 * np.sin(angle), (v - 19.5) * 0.02, 3.0 - 0.25 * np.cos(angle)])
    ranges = np.linalg.norm(surface, axis=-1, keepdims=True)
    xyz = surface * (1.0 + np.random.default_rng(seed).normal(0.0, noise, ranges.shape) / ranges)
    labels = np.where(u < 30, 1, 2).astype(np.int32)
    labels[20:] = 3
    fits = {k: fit_plane(xyz[labels == k]) for k in (1, 2)}
    fits[3] = pipe.fitter.fit(xyz[labels == 3])
    assert fits[3].kind == "cylinder"  # the premise
    cloud = rs.OrganizedCloud(xyz)
    out = refine_regions(cloud, Regions(labels, fits), fitter=pipe.fitter, config=pipe.config.refine,
                         sensor=pipe.sensor, ranges=cloud.range_image(), sigma=np.full(cloud.shape, noise),
                         jumps=None, timings={})
    assert len(out.models) == 1 and (out.labels > 0).all() and len(np.unique(out.labels)) == 1
    (model,) = out.models.values()
    assert model.kind == "cylinder" and abs(model.radius - 0.25) < 0.05 and abs(model.axis[1]) > np.cos(np.radians(3))
