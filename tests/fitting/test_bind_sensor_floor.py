"""The fitter's rms thresholds follow the sensor's noise."""

from rangeseg_o3d.fitting.classify import RMS_NOISE_FACTOR, PrimitiveFitterConfig, bind_sensor
from rangeseg_o3d.sensor import NoiseModel, Sensor


def test_thresholds_are_at_least_the_constant_noise():
    params = PrimitiveFitterConfig().model_dump()
    quiet = bind_sensor(params, Sensor(noise=NoiseModel(sigma0=0.002)))
    noisy = bind_sensor(params, Sensor(noise=NoiseModel(sigma0=0.02)))
    assert quiet["plane_rms"] == params["plane_rms"]  # the preset's 1 cm already covers 2 mm
    for key in ("plane_rms", "cylinder_rms", "sphere_rms"):
        assert noisy[key] == RMS_NOISE_FACTOR * 0.02
    assert noisy["rms_per_range2"] == 0.0
