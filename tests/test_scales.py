"""Scale-dependent settings follow the sensor (rangeseg_o3d.scales), as its docstring documents."""

import math
from dataclasses import replace

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.config import load_config
from rangeseg_o3d.scales import (GRAZING_TAN, JUMP_SIGMAS, MAX_TILE, MERGE_SIGMAS, MIN_CELLS,
                                 MIN_GRID_CELLS, MIN_PIXELS, TILE_NOISE_RATIO, WINDOW_STEPS, derive_scales,
                                 measured_spacing, scales_for_cloud)
from rangeseg_o3d.sensor import NoiseModel, Sensor
from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.suite import default_scene

LMS200 = Sensor(noise=NoiseModel(0.005), row_spacing_deg=0.58, column_spacing_deg=1.0)


def _with(sensor: Sensor, **noise) -> Sensor:
    from dataclasses import replace

    return replace(sensor, noise=NoiseModel(**{"sigma0": sensor.noise.sigma0,
                                               "sigma_quadratic": sensor.noise.sigma_quadratic, **noise}))


def test_doubling_sigma0_doubles_the_noise_scaled_thresholds_and_leaves_the_rest():
    one = derive_scales(LMS200, typical_range=3.5)
    two = derive_scales(_with(LMS200, sigma0=0.010), typical_range=3.5)
    assert two.jump_min == pytest.approx(2 * one.jump_min, rel=1e-12)
    assert two.merge_tolerance == pytest.approx(2 * one.merge_tolerance, rel=1e-12)
    assert one.jump_min == pytest.approx(JUMP_SIGMAS * 0.005)
    assert one.merge_tolerance == pytest.approx(MERGE_SIGMAS * 0.005)
    # the geometric ones follow the grid, not the noise
    assert two.jump_ratio == one.jump_ratio
    assert (one.tile, two.tile) == (1, 1)  # 1 deg at 3.5 m: 4.6 cm spacing, above 5 and 10 mm noise
    assert one.min_region_size == two.min_region_size == MIN_PIXELS


def test_the_lms200_values_are_those_the_preset_was_tuned_with():
    scales = derive_scales(LMS200, typical_range=3.5)
    assert scales.jump_ratio == pytest.approx(0.08, abs=0.001)
    assert scales.jump_min == pytest.approx(0.05)
    assert scales.merge_tolerance == pytest.approx(0.05)
    assert scales.min_region_size == 20


def test_jump_ratio_follows_the_angular_step():
    coarse = derive_scales(LMS200, typical_range=3.0)
    fine = derive_scales(Sensor(noise=LMS200.noise, row_spacing_deg=0.29, column_spacing_deg=0.5),
                         typical_range=3.0)
    assert fine.jump_ratio == pytest.approx(coarse.jump_ratio / 2, rel=1e-12)
    delta = math.sqrt(math.radians(0.58) * math.radians(1.0))
    assert coarse.jump_ratio == pytest.approx(delta / GRAZING_TAN)


def test_tile_grows_where_the_noise_hides_creases():
    kinect = Sensor(noise=NoiseModel(0.001, 0.001425), row_spacing_deg=0.11, column_spacing_deg=0.11)
    near, far = (derive_scales(kinect, typical_range=r, shape=(480, 640)) for r in (0.5, 3.0))
    # 0.5 m: sigma 1.4 mm, spacing 1.0 mm -> tiles; 3 m: sigma 13.8 mm, spacing 5.8 mm -> larger tiles
    assert 1 < near.tile < far.tile <= MAX_TILE
    for s in (near, far):
        spacing = s.typical_range * math.radians(0.11)
        # the documented rule: the smallest t with sigma / t <= TILE_NOISE_RATIO * t * spacing
        assert s.sigma / s.tile <= TILE_NOISE_RATIO * s.tile * spacing * (1 + 1e-9)
        assert s.sigma / (s.tile - 1) > TILE_NOISE_RATIO * (s.tile - 1) * spacing
        assert s.min_region_size == max(MIN_PIXELS, MIN_CELLS * s.tile ** 2)
    # the merge tolerance is in the noise of the tile means the models are fitted to
    assert far.merge_tolerance == pytest.approx(
        MERGE_SIGMAS * (0.001 + 0.001425 * 9.0 / far.tile), rel=1e-9)


def test_tile_keeps_enough_cells_across_a_short_grid():
    lidar = Sensor(noise=NoiseModel(0.05), row_spacing_deg=0.7, column_spacing_deg=0.35)
    assert derive_scales(lidar, typical_range=2.0).tile > 1     # 5 cm noise over 1.7 cm spacing
    assert derive_scales(lidar, typical_range=2.0, shape=(64, 1024)).tile == 64 // MIN_GRID_CELLS
    assert derive_scales(lidar, typical_range=2.0, shape=(32, 1024)).tile == 1


def test_a_quantised_depth_asks_for_a_window_that_spans_one_step():
    # ABW's camera: 0.025 x 0.036 deg pixels, 0.36 mm quantisation rms in 1.29 mm steps
    plain = Sensor(noise=NoiseModel(0.00036), row_spacing_deg=0.025, column_spacing_deg=0.036)
    stepped = replace(plain, depth_step=0.00129)
    spacing = 0.95 * math.sqrt(math.radians(0.025) * math.radians(0.036))  # 0.50 mm at 0.95 m
    assert derive_scales(plain, typical_range=0.95).tile == 1  # the rms is under the spacing
    tile = derive_scales(stepped, typical_range=0.95).tile
    assert tile == math.ceil(0.00129 / (WINDOW_STEPS * spacing)) == 2
    # the window of tiles spans a step; one tile less does not
    assert WINDOW_STEPS * tile * spacing >= 0.00129 > WINDOW_STEPS * (tile - 1) * spacing
    # over ABW's working ranges (0.77-1.11 m) the rule gives the same tile
    assert {derive_scales(stepped, typical_range=r).tile for r in (0.77, 0.9, 1.11)} == {2}
    # a coarser step asks for more; the noise rule still wins where it asks for more
    assert derive_scales(replace(plain, depth_step=0.0035), typical_range=0.95).tile == 4  # 3.5 / 1.0 mm
    noisy = replace(stepped, noise=NoiseModel(0.002))
    assert derive_scales(noisy, typical_range=0.95).tile == derive_scales(
        replace(noisy, depth_step=0.0), typical_range=0.95).tile > 2
    assert load_config("abw").sensor.resolve().depth_step == pytest.approx(0.00129)
    with pytest.raises(ValueError, match="depth_step"):
        Sensor(depth_step=-0.001)


def test_a_preset_value_wins_over_the_derived_one():
    assert derive_scales(LMS200, typical_range=3.0, tile=3).min_region_size == MIN_CELLS * 9
    config = load_config("lms200", overrides={"segmenter.params.jump_min": 0.2, "tile": 2})
    pipe = rs.Pipeline(config)
    cloud = simulate_lms200(default_scene(), seed=0).cloud
    tile, args, refine = pipe._with_scales(pipe.scales(cloud))
    assert (tile, args["jump_min"], refine.jump_min) == (2, 0.2, 0.2)
    assert args["jump_ratio"] == pytest.approx(derive_scales(config.sensor.resolve(), typical_range=3.0).jump_ratio)


def test_spacing_is_measured_from_the_cloud_when_the_sensor_gives_none():
    cloud = simulate_lms200(default_scene(), seed=0).cloud
    rows, cols = measured_spacing(cloud)
    # the scene's grid: 1 deg beams; 0.7 rad of tilt over 70 rows, which moves a beam at
    # angle b from the scan plane's axis by tilt step * sin(b) (b in 25..155 deg)
    assert cols == pytest.approx(math.radians(1.0), rel=0.05)
    assert 0.7 * 0.7 / 69 < rows < 0.7 / 69
    given = scales_for_cloud(LMS200, cloud)
    measured = scales_for_cloud(Sensor(noise=LMS200.noise), cloud)
    assert measured.jump_ratio == pytest.approx(given.jump_ratio, rel=0.15)
    # a grid of tile means measures the sensor's spacing, not the tile's
    assert measured_spacing(cloud.tile_means(2))[1] == pytest.approx(cols, rel=0.05)


def _jittered_grid(rows: int, cols: int, seed: int = 0) -> np.ndarray:
    # A spherical grid whose column steps vary column by column (a terrestrial scanner's
    # jittery azimuth: 1.1-1.8 mrad) and whose row steps are 1.4 mrad; ranges 2-12 m.
    rng = np.random.default_rng(seed)
    azimuth = np.cumsum(rng.uniform(1.1e-3, 1.8e-3, cols))
    elevation = 1.4e-3 * np.arange(rows) - 0.3
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    r = rng.uniform(2.0, 12.0, (rows, cols))
    return np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=-1)


def test_measured_spacing_from_a_sample_matches_the_whole_grid_median():
    from rangeseg_o3d.segmentation.edges import angular_steps

    xyz = _jittered_grid(400, 513)
    xyz[:40, :60] = np.nan  # an invalid corner
    whole = [float(np.median(s[np.isfinite(s) & (s > 0)])) for s in angular_steps(xyz)]
    sampled = measured_spacing(rs.OrganizedCloud(xyz))
    # a few thousand of the ~200k steps: within 0.5 % though the column steps spread over 50 %
    assert sampled[0] == pytest.approx(whole[0], rel=1e-3)
    assert sampled[1] == pytest.approx(whole[1], rel=5e-3)


def test_measured_spacing_of_thin_and_tiny_grids():
    line = rs.OrganizedCloud(_jittered_grid(1, 300))  # one row: its column step stands for both
    rows, cols = measured_spacing(line)
    assert rows == cols and 1.1e-3 < cols < 1.8e-3
    column = rs.OrganizedCloud(_jittered_grid(300, 1))
    rows, cols = measured_spacing(column)
    assert rows == cols == pytest.approx(1.4e-3, rel=1e-3)
    two = rs.OrganizedCloud(_jittered_grid(2, 2))
    assert 1.0e-3 < min(measured_spacing(two)) <= max(measured_spacing(two)) < 1.9e-3
    lonely = np.full((5, 5, 3), np.nan)
    lonely[2, 2] = (1.0, 0.0, 0.0)  # valid, but no valid neighbour
    with pytest.raises(ValueError, match="angular spacing"):
        measured_spacing(rs.OrganizedCloud(lonely))


def test_derive_scales_refuses_what_it_cannot_use():
    with pytest.raises(ValueError, match="angular spacing"):
        derive_scales(Sensor(), typical_range=3.0)
    with pytest.raises(ValueError, match="typical_range"):
        derive_scales(LMS200, typical_range=float("nan"))
    with pytest.raises(ValueError, match="spacing_rad"):
        derive_scales(LMS200, typical_range=3.0, spacing_rad=(0.0, 0.01))
    empty = rs.OrganizedCloud(np.full((4, 4, 3), np.nan))
    with pytest.raises(ValueError, match="no valid range"):
        scales_for_cloud(LMS200, empty)


def test_shipped_presets_leave_the_scales_to_the_sensor():
    for name in ("lms200", "spinning_lidar", "rgbd_vga", "abw"):
        config = load_config(name)
        params = config.segmenter.params
        assert (params["jump_ratio"], params["jump_min"], params["min_region_size"]) == (None, None, None), name
        assert config.refine.merge_tolerance is None, name
    assert load_config("rgbd_vga").tile == 6  # the one scale still set (see the preset)
    assert load_config("abw").tile is None
