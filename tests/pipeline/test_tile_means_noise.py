"""On a tile grid the fitter judges means of tile x tile returns by their own noise.

The thresholds follow :meth:`rangeseg_o3d.sensor.Sensor.of_means`: the range-dependent
noise divided by the square root of the independent returns a tile averages (fewer when
the sensor's returns err together), widened by the measured excess when the means scatter
more than the model says (:func:`rangeseg_o3d.sensor.noise_excess`).
"""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.sensor_checks import noise_excess
from rangeseg_o3d.synthetic.depth_camera import KINECT_NOISE, simulate_depth_camera
from rangeseg_o3d.synthetic.suite import rgbd_scenes


@pytest.fixture(scope="module")
def kinect_frame():
    return simulate_depth_camera(rgbd_scenes()[0][1], seed=2).cloud


def _means_threshold_growth(config, cloud) -> float:
    pipe = rs.Pipeline(config)
    work = cloud.tile_means(pipe.config.tile)
    return pipe._fitter_for(work).params["rms_per_range2"]


def test_tile_fitter_thresholds_follow_the_noise_of_the_means(kinect_frame):
    config = rs.load_config("rgbd_vga")
    growth = config.fitter.params["range_growth"] * KINECT_NOISE
    tile = config.tile
    assert rs.Pipeline(config).fitter.params["rms_per_range2"] == pytest.approx(growth, rel=1e-12)
    # the simulated Kinect's returns are independent, as the model says: no excess
    assert _means_threshold_growth(config, kinect_frame) == pytest.approx(growth / tile, rel=1e-12)
    # returns that err together over 3 x 3 pixels: a 6 x 6 tile averages 4 of them
    stereo = rs.load_config("rgbd_vga", overrides={"sensor.noise_correlation_px": 3})
    assert _means_threshold_growth(stereo, kinect_frame) == pytest.approx(growth * 3 / tile, rel=1e-12)
    # a model that under-states the noise ten times: the means' thresholds widen by the
    # measured excess (the means' true scatter over the model's)
    quiet = rs.load_config("rgbd_vga", overrides={"sensor.sigma_quadratic": KINECT_NOISE / 10,
                                                  "sensor.sigma0": 0.0001})
    excess = noise_excess(kinect_frame.tile_means(tile), rs.Pipeline(quiet).sensor)
    assert excess > 2.0
    widened = _means_threshold_growth(quiet, kinect_frame)
    assert widened == pytest.approx(config.fitter.params["range_growth"] * KINECT_NOISE / 10 / tile * excess,
                                    rel=1e-12)


def test_full_resolution_presets_keep_their_fitter():
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    pipe = rs.Pipeline("lms200")
    cloud = simulate_lms200(default_scene(), seed=0).cloud
    assert pipe._fitter_for(cloud) is pipe.fitter
    result = pipe.run(cloud)
    assert {f.kind for f in result.features} == {"plane", "cylinder", "sphere"}
    assert np.count_nonzero(result.labels) > 0.8 * cloud.n_valid
