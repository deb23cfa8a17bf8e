"""The sensor section: resolution into one Sensor, who receives it, and dotted-key overrides."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.config import load_config, parse_overrides, presets
from rangeseg_o3d.pipeline import Pipeline
from rangeseg_o3d.sensor import NoiseModel, Sensor, unit_scale
from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.suite import default_scene


@pytest.fixture(scope="module")
def lms_cloud():
    return simulate_lms200(default_scene(), seed=0).cloud


@pytest.mark.parametrize("preset", presets())
def test_every_preset_has_a_sensor_section_resolved_into_one_sensor(preset):
    import yaml

    from rangeseg_o3d.config import preset_dir

    raw = yaml.safe_load((preset_dir() / f"{preset}.yaml").read_text())
    assert "sensor" in raw and {"sigma0", "sigma_quadratic", "units"} <= set(raw["sensor"])
    config = load_config(preset)
    sensor = Pipeline(config).sensor
    assert isinstance(sensor, Sensor)
    assert sensor.noise == NoiseModel(raw["sensor"]["sigma0"], raw["sensor"]["sigma_quadratic"],
                                      step_quadratic=raw["sensor"].get("step_quadratic", 0.0))
    assert sensor.units == raw["sensor"]["units"]
    # the noise is nowhere else: not in the segmenter's, fitter's or refinement's sections
    for section in (config.segmenter.params, config.fitter.params, config.refine.model_dump()):
        assert not {"sigma0", "sigma_quadratic", "rms_per_range2"} & set(section)
    with pytest.raises(AttributeError):
        sensor.units = "cm"  # immutable


def test_noise_model_is_the_documented_formula_and_averages_only_the_range_term():
    noise = NoiseModel(sigma0=0.001, sigma_quadratic=0.001425)
    ranges = np.array([1.0, 2.0, 4.0])
    np.testing.assert_allclose(noise.sigma(ranges), 0.001 + 0.001425 * ranges**2, rtol=1e-15)
    means = noise.sigma(ranges, samples=np.array([36, 36, 0]))
    np.testing.assert_allclose(means, [0.001 + 0.001425 / 6, 0.001 + 0.001425 * 4 / 6,
                                       0.001 + 0.001425 * 16], rtol=1e-15)
    with pytest.raises(ValueError, match="both be 0"):
        NoiseModel(0.0, 0.0)
    with pytest.raises(ValueError, match="sigma0"):
        NoiseModel(float("nan"))


def test_correlated_returns_average_less_noise_away():
    # a stereo camera's depths err together over its 3 x 3 matching window: a 6 x 6 tile
    # mean averages 4 independent errors, not 36
    stereo = NoiseModel(sigma0=0.001, sigma_quadratic=0.003, correlation_px=3)
    np.testing.assert_allclose(stereo.mean_scale(np.array([36, 9, 4, 0])), [0.5, 1.0, 1.0, 1.0], rtol=1e-15)
    ranges, tile = np.array([2.0]), np.array([36])
    assert stereo.sigma(ranges, samples=tile)[0] == pytest.approx(0.001 + 0.003 * 4 / 2, rel=1e-12)
    independent = NoiseModel(sigma0=0.001, sigma_quadratic=0.003)
    assert independent.sigma(ranges, samples=tile)[0] == pytest.approx(0.001 + 0.003 * 4 / 6, rel=1e-12)
    # the tile grid's own noise model: the means err independently of each other
    assert stereo.of_means(36) == NoiseModel(0.001, 0.003 / 2, 1)
    widened = independent.of_means(36, excess=1.5)
    assert widened.sigma_quadratic == pytest.approx(0.003 * 1.5 / 6, rel=1e-12)
    assert (widened.sigma0, widened.correlation_px) == (0.001, 1)
    sensor = Sensor(noise=stereo, row_spacing_deg=0.09, column_spacing_deg=0.09)
    assert sensor.of_means(36).noise == stereo.of_means(36) and sensor.of_means(36).row_spacing_deg == 0.09
    with pytest.raises(ValueError, match="correlation_px"):
        NoiseModel(0.001, correlation_px=0)
    with pytest.raises(ValueError, match="excess"):
        stereo.of_means(36, excess=0.5)
    config = load_config({"sensor": {"sigma0": 0.001, "sigma_quadratic": 0.003, "noise_correlation_px": 3}})
    assert Pipeline(config).sensor.noise == stereo
    assert Pipeline("rgbd_vga").sensor.noise.correlation_px == 1  # the default: independent returns
    with pytest.raises(ValueError, match="noise_correlation_px"):
        load_config({"sensor": {"noise_correlation_px": 0}})


def test_only_a_stereo_cameras_noise_errs_over_a_matching_window():
    # the grazing-face steps run only where the noise grows with range and errs together
    assert NoiseModel(sigma0=0.001, sigma_quadratic=0.003, correlation_px=3).matched_window
    assert not NoiseModel(sigma0=0.001, sigma_quadratic=0.003).matched_window  # a Kinect's
    assert not NoiseModel(sigma0=0.005, correlation_px=3).matched_window  # constant noise
    assert not Pipeline("rgbd_vga").sensor.noise.matched_window
    assert not Pipeline("lms200").sensor.noise.matched_window


def test_a_kinects_correlated_errors_once_stated_are_counted_and_switch_on_the_grazing_steps():
    # the real Kinect's correlation (9 px, kinect_real_640x480 states it) besides its steps
    kinect = NoiseModel(0.001, 0.001425, 9, 0.0029)
    # the statistics count it: a 6x6 tile holds fewer than one 9 x 9 block, so its mean errs
    # as one return; a pixel carries 1/81 of an independent return, a 6-px tile 0.273
    assert kinect.mean_scale(36) == 1.0
    np.testing.assert_allclose(kinect.independent_share(1), 1.0 / 81)
    np.testing.assert_allclose(kinect.independent_share(6), (254.0 / (6 * 81)) ** 2)
    # the grazing-face steps need the correlation, not a matcher's continuous depth
    assert kinect.matched_window
    assert not NoiseModel(0.001, 0.001425, 1, 0.0029).matched_window
    # rgbd_vga states the steps but not the correlation (its real frames: see the preset)
    preset = Pipeline("rgbd_vga").sensor.noise
    assert (preset.correlation_px, preset.step_quadratic, preset.matched_window) == (1, 0.0029, False)


def test_independent_returns_of_a_mask_narrower_than_the_correlation():
    # a 21 x 2 strip under a 9-px correlation: n^2 c^2 over the sum of its pairs' correlations
    # (lags beyond the strip's own size pair nothing)
    noise = NoiseModel(0.001, 0.001425, correlation_px=9)
    mask = np.zeros((30, 10), dtype=bool)
    mask[4:25, 3:5] = True
    rows, cols = np.nonzero(mask)
    dr = np.abs(rows[:, None] - rows[None, :])
    dc = np.abs(cols[:, None] - cols[None, :])
    pairs = (np.clip(9 - dr, 0, None) * np.clip(9 - dc, 0, None)).sum()
    n = rows.size
    np.testing.assert_allclose(noise.independent_returns(mask), n * n * 81 / pairs)
    tight = np.ones((21, 2), dtype=bool)
    np.testing.assert_allclose(noise.independent_returns(tight), n * n * 81 / pairs)
    assert 2.0 < noise.independent_returns(tight) < 3.0  # 42 pixels: about 21 / 9 rows' worth


def test_noise_excess_measures_how_much_more_points_scatter_than_the_model():
    from rangeseg_o3d.sensor_checks import noise_excess

    rng = np.random.default_rng(3)
    rows, cols = np.mgrid[0:64, 0:64]
    xyz = np.stack([0.01 * cols, 0.01 * rows, np.full(rows.shape, 2.0)], axis=-1)
    noisy = xyz.copy()
    noisy[..., 2] += rng.normal(0.0, 0.006, rows.shape)  # 3 x the model's 2 mm
    model = Sensor(noise=NoiseModel(sigma0=0.002))
    assert 2.5 <= noise_excess(rs.OrganizedCloud(noisy), model) <= 3.3
    xyz[..., 2] += rng.normal(0.0, 0.002, rows.shape)  # as the model says
    assert noise_excess(rs.OrganizedCloud(xyz), model) == pytest.approx(1.0, abs=0.15)
    # a model that over-states the noise is not scaled down
    assert noise_excess(rs.OrganizedCloud(xyz), Sensor(noise=NoiseModel(sigma0=0.02))) == 1.0


def test_sensor_validates_units_and_ranges():
    assert unit_scale("cm") == 0.01 and Sensor(units="mm").scale == 0.001
    with pytest.raises(ValueError, match="units must be one of"):
        Sensor(units="furlong")
    with pytest.raises(ValueError, match="min_range"):
        Sensor(min_range=5.0, max_range=1.0)
    with pytest.raises(ValueError, match="sensor.units"):
        load_config({"sensor": {"units": "furlong"}})


def test_depth_steps_growing_with_the_range_are_a_sensor_fact_of_rgbd_vga_only():
    # the Kinect's 1/8-px disparity steps, measured on the PCL / PEAC frames: 2.9e-3 z^2
    assert NoiseModel().step_quadratic == 0.0
    assert load_config("rgbd_vga").sensor.resolve().noise.step_quadratic == 0.0029
    for preset in ("lms200", "abw", "sick_3dtk", "spinning_lidar", "tls_andreashaus"):
        assert load_config(preset).sensor.resolve().noise.step_quadratic == 0.0
    for bad in (-1e-3, float("nan"), float("inf"), "0.003"):
        with pytest.raises(ValueError, match=f"step_quadratic must be a finite number >= 0 \\(1/m\\); got {bad!r}"):
            NoiseModel(0.001, 0.001425, step_quadratic=bad)
    with pytest.raises(ValueError, match="step_quadratic"):
        load_config({"sensor": {"step_quadratic": -0.5}})
    # an override of the noise alone does not need the steps restated
    quiet = load_config("rgbd_vga", overrides={"sensor.sigma_quadratic": 0.0001425}).sensor.resolve().noise
    assert (quiet.sigma_quadratic, quiet.step_quadratic) == (0.0001425, 0.0029)
    # nothing reads it: the fitter's and segmenter's noise of tile means are those without steps
    with_steps = NoiseModel(0.001, 0.001425, step_quadratic=0.0029)
    plain = NoiseModel(0.001, 0.001425)
    np.testing.assert_array_equal(with_steps.mean_scale([1, 36]), plain.mean_scale([1, 36]))
    assert with_steps.of_means(36) == plain.of_means(36)


def test_lateral_noise_is_a_sensor_fact_of_abw_only():
    # 0 (returns on their rays) unless a preset states it: ABW's camera, half a grid step
    assert Sensor().lateral_noise_px == 0.0
    assert load_config("abw").sensor.resolve().lateral_noise_px == 0.5
    assert load_config("rgbd_vga").sensor.resolve().lateral_noise_px == 0.0
    with pytest.raises(ValueError, match="lateral_noise_px"):
        Sensor(lateral_noise_px=-1.0)
    with pytest.raises(ValueError, match="lateral_noise_px"):
        load_config({"sensor": {"lateral_noise_px": -0.5}})


def test_beam_width_is_a_sensor_fact_of_the_lms200_only():
    # 0 (no return taken for mixed) unless a preset states it: the LMS200's 0.75-degree beam
    assert Sensor().beam_width_deg == 0.0
    assert load_config("lms200").sensor.resolve().beam_width_deg == 0.75
    for preset in ("spinning_lidar", "sick_3dtk", "rgbd_vga", "abw"):
        assert load_config(preset).sensor.resolve().beam_width_deg == 0.0
    with pytest.raises(ValueError, match="beam_width_deg"):
        Sensor(beam_width_deg=-0.1)
    with pytest.raises(ValueError, match="beam_width_deg"):
        Sensor(beam_width_deg=float("nan"))
    with pytest.raises(ValueError, match="beam_width_deg"):
        load_config({"sensor": {"beam_width_deg": 200.0}})


def test_the_segmenter_normalises_by_the_sensors_noise(lms_cloud):
    # constant noise: the residual scales as 1/sigma0^2
    base = Pipeline("lms200").run(lms_cloud).stages["residual"]
    doubled = Pipeline(load_config("lms200", overrides={"sensor.sigma0": 0.01})).run(lms_cloud)
    finite = np.isfinite(base)
    assert finite.sum() > 5000
    np.testing.assert_allclose(doubled.stages["residual"][finite], base[finite] / 4, rtol=1e-12)


def test_a_segmenter_declaring_sensor_receives_the_resolved_sensor(lms_cloud):
    from pydantic import BaseModel

    from rangeseg_o3d import registry

    seen = []

    def record(cloud, *, sensor):
        seen.append(sensor)
        return rs.Segmentation(labels=np.where(cloud.valid, 1, 0).astype(np.int32))

    class NoParams(BaseModel):
        pass

    registry.register("segmenter", rs.Plugin("sensor_probe_test", NoParams, record), overwrite=True)
    try:
        config = load_config({"sensor": {"sigma0": 0.02, "wrap_columns": True},
                              "segmenter": {"name": "sensor_probe_test"}})
        pipeline = Pipeline(config)
        pipeline.run(lms_cloud)
    finally:
        registry._REGISTERED["segmenter"].pop("sensor_probe_test", None)
    assert seen == [pipeline.sensor]
    assert seen[0].noise.sigma0 == 0.02 and seen[0].wrap_columns


def test_fitter_thresholds_follow_the_sensor_noise():
    # rgbd_vga keeps its former 0.0015 r^2 exactly, now as a factor on the sensor's term
    assert Pipeline("rgbd_vga").fitter.params["rms_per_range2"] == 0.0015
    assert Pipeline("lms200").fitter.params["rms_per_range2"] == 0.0
    louder = Pipeline(load_config("rgbd_vga", overrides={"sensor.sigma_quadratic": 0.002}))
    assert louder.fitter.params["rms_per_range2"] == pytest.approx(0.002 * 0.0015 / 0.001425, rel=1e-12)
    assert "range_growth" not in louder.fitter.params


def test_refinement_settings_shared_with_the_segmenter_are_resolved_once():
    lms = load_config("lms200")
    assert (lms.refine.min_region_size, lms.refine.jump_ratio, lms.refine.jump_min) == (
        lms.segmenter.params["min_region_size"], lms.segmenter.params["jump_ratio"],
        lms.segmenter.params["jump_min"])
    rg = load_config("lms200_region_growing")  # stated in the preset: what it used before
    assert (rg.refine.min_region_size, rg.refine.jump_ratio, rg.refine.jump_min) == (30, 0.08, 0.05)
    bigger = load_config("lms200", overrides={"segmenter.params.min_region_size": 50})
    assert bigger.refine.min_region_size == 50
    own = load_config("lms200", overrides={"segmenter.params.min_region_size": 50,
                                            "refine.min_region_size": 25})
    assert own.refine.min_region_size == 25
    # a loaded configuration as the source: what was resolved is resolved again
    again = load_config(lms, overrides={"segmenter.params.min_region_size": 40})
    assert again.refine.min_region_size == 40
    assert load_config(own, overrides={"segmenter.params.min_region_size": 40}).refine.min_region_size == 25


@pytest.mark.parametrize("old, new", [
    ({"segmenter": {"name": "residual_edges", "params": {"sigma_quadratic": 0.001}}}, "sensor.sigma_quadratic"),
    ({"refine": {"sigma0": 0.005}}, "sensor.sigma0"),
    ({"fitter": {"name": "primitives", "params": {"rms_per_range2": 0.0015}}}, "sensor.sigma_quadratic"),
])
def test_old_noise_keys_say_where_they_moved(old, new):
    with pytest.raises(ValueError, match=f"has moved to {new}"):
        load_config(old)


def test_overrides_set_values_by_dotted_key():
    config = load_config("lms200", overrides={"sensor.sigma0": 0.01, "refine.k_sigma": 2.5,
                                              "segmenter.params.threshold": 5, "tile": 2,
                                              "fitter.params.plane_rms": 0.02})
    assert config.sensor.sigma0 == 0.01 and config.refine.k_sigma == 2.5
    assert config.segmenter.params["threshold"] == 5 and config.tile == 2
    assert config.fitter.params["plane_rms"] == 0.02
    # the rest is the preset's
    preset = load_config("lms200")
    assert config.refine.merge_tolerance == preset.refine.merge_tolerance
    assert config.sensor.max_range == preset.sensor.max_range
    # an existing configuration is a source too, and is not changed
    again = load_config(preset, overrides={"sensor.units": "cm"})
    assert again.sensor.units == "cm" and preset.sensor.units == "m"


def test_override_of_the_segmenter_name_checks_params_against_the_new_plugin():
    config = load_config("lms200_region_growing", overrides={
        "segmenter.params.smoothness_deg": 10.0})
    assert config.segmenter.params["smoothness_deg"] == 10.0
    with pytest.raises(ValueError, match=r"unknown configuration key 'segmenter\.params\.threshold'.*"
                                         r"smoothness_deg"):
        load_config("lms200_region_growing", overrides={"segmenter.params.threshold": 5})


@pytest.mark.parametrize("key, message", [
    ("sensor.sigma", r"'sensor\.sigma': sensor has no 'sigma' \(it has sigma0, sigma_quadratic"),
    ("sensr.sigma0", r"'sensr\.sigma0': the configuration has no 'sensr'"),
    ("segmenter.params.windw", r"'segmenter\.params\.windw'.*window"),
    ("sensor.sigma0.x", r"sensor\.sigma0 is a value, not a section"),
    ("sensor", r"names a section; give one of its keys \(sensor\.sigma0"),
])
def test_unknown_override_keys_are_errors_naming_them(key, message):
    with pytest.raises(ValueError, match=message):
        load_config("lms200", overrides={key: 1})


@pytest.mark.parametrize("key, value, field", [
    ("sensor.sigma0", -1, r"sensor\.sigma0.*greater than or equal to 0.*-1"),
    ("refine.k_sigma", "many", r"refine\.k_sigma.*'many'"),
    ("sensor.max_range", float("inf"), r"sensor\.max_range"),
    ("segmenter.params.window", 4, "window must be odd"),
])
def test_bad_override_values_are_errors_naming_field_and_value(key, value, field):
    with pytest.raises(ValueError, match=field) as info:
        load_config("lms200", overrides={key: value})
    assert "with overrides" in str(info.value)


def test_parse_overrides_reads_yaml_scalars():
    assert parse_overrides(["sensor.sigma0=0.01", "refine.merge=false", "sensor.units=cm",
                            "refine.min_region_size=null", "sensor.sigma_quadratic=1e-3"]) == {
        "sensor.sigma0": 0.01, "refine.merge": False, "sensor.units": "cm",
        "refine.min_region_size": None, "sensor.sigma_quadratic": "1e-3"}
    # pydantic turns the numeric string into a float
    assert load_config("lms200", overrides={"sensor.sigma_quadratic": "1e-3"}).sensor.sigma_quadratic == 0.001
    for bad in ("sensor.sigma0", "=3", "sensor.sigma0=[1,"):
        with pytest.raises(ValueError, match="override"):
            parse_overrides([bad])


def test_compare_configs_take_the_same_overrides():
    from rangeseg_o3d.cli import build_parser
    from rangeseg_o3d.evaluation.compare import config_for

    swapped = config_for("lms200", "region_growing", overrides=["sensor.sigma0=0.01", "refine.k_sigma=2"])
    assert swapped.segmenter.name == "region_growing"
    assert swapped.sensor.sigma0 == 0.01 and swapped.refine.k_sigma == 2.0
    assert config_for("lms200", "residual_edges", overrides={"sensor.sigma0": 0.02}).sensor.sigma0 == 0.02
    with pytest.raises(ValueError, match="unknown configuration key 'refine.k'"):
        config_for("lms200", "region_growing", overrides=["refine.k=2"])
    args = build_parser().parse_args(["compare", "--quick", "--set", "sensor.sigma0=0.01",
                                      "--set", "refine.merge=false"])
    assert args.overrides == ["sensor.sigma0=0.01", "refine.merge=false"]


def test_independent_share_counts_the_tile_means_correlation_summed_over_lags():
    # Box-correlated errors (a stereo matching window of 3 px): the share is the inverse of the
    # variance inflation of a mean of many grid points, measured here on simulated tile means.
    from rangeseg_o3d.sensor import NoiseModel

    assert NoiseModel().independent_share(1) == 1.0 and NoiseModel().independent_share(6) == 1.0
    stereo = NoiseModel(0.001, 0.003, 3)
    assert stereo.independent_share(1) == pytest.approx(1 / 9, rel=1e-12)
    rng = np.random.default_rng(5)
    for tile in (1, 2, 6):
        white = rng.normal(size=(4000, 3 * 4 + 2))
        boxed = sum(white[:, j:j + white.shape[1] - 2] for j in range(3)) / 3  # 1-D box of 3
        means = boxed[:, :tile * (boxed.shape[1] // tile)].reshape(4000, -1, tile).mean(axis=2)
        inflation = means.sum(axis=1).var() / (means.shape[1] * means.var())
        assert inflation == pytest.approx(stereo.independent_share(tile) ** -0.5, rel=0.15), tile
    with pytest.raises(ValueError):
        stereo.independent_share(0)
