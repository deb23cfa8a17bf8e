import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.evaluation import hoover
from rangeseg_o3d.segmenters.residual_edges import segment_residual_edges
from rangeseg_o3d.sensor import NoiseModel, Sensor
from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.suite import default_scene, rgbd_suite


def test_lms_scan_segments_into_the_big_surfaces():
    scan = simulate_lms200(default_scene(), seed=0)
    seg = segment_residual_edges(scan.cloud, threshold=4.0, min_region_size=20)
    assert seg.labels.shape == (70, 131) and seg.labels.dtype == np.int32
    assert {"residual", "closed", "edges", "jumps"} <= set(seg.stages)
    # Edges and regions partition the valid grid.
    assert not (seg.stages["edges"] & (seg.labels > 0)).any()
    score = hoover(scan.truth_ids, seg.labels, tolerance=0.6, min_region=500)
    assert score.n_correct >= score.n_truth - 1  # the big walls and floor, before refinement


def test_tile_means_cloud_is_segmented_with_its_reduced_noise():
    _, scan = rgbd_suite(seed=0)[0]
    tiles = scan.cloud.tile_means(6)
    assert tiles.shape == (80, 107) and tiles.tile == 6
    assert tiles.samples.max() == 36
    params = dict(sensor=Sensor(NoiseModel(sigma0=0.001, sigma_quadratic=0.001425)), threshold=3.0,
                  min_region_size=300, jump_ratio=0.02, jump_min=0.02)
    seg = segment_residual_edges(tiles, **params)
    assert seg.labels.shape == (80, 107)
    for image in seg.stages.values():
        assert image.shape == (80, 107)
    assert seg.labels.max() >= 3
    assert not seg.labels[~tiles.valid].any()
    # min_region_size counts sensor pixels: 300 px are 9 tiles of 36
    sizes = np.bincount(seg.labels.ravel())[1:]
    assert sizes.min() >= 9
    # The residual is in units of each point's own noise variance: for a mean of 36
    # returns the range-dependent term is 6x smaller (sigma0, quantisation, is not).
    raw = segment_residual_edges(rs.OrganizedCloud(tiles.xyz), **params).stages["residual"]
    full = (tiles.samples == 36) & np.isfinite(raw) & (raw > 0)
    assert full.sum() > 5000
    r2 = np.square(tiles.range_image()[full])
    expected = ((0.001 + 0.001425 * r2) / (0.001 + 0.001425 * r2 / 6)) ** 2
    np.testing.assert_allclose(seg.stages["residual"][full] / raw[full], expected, rtol=1e-6)


def test_segmenter_validates_config():
    with pytest.raises(ValueError, match="sigma0 and sigma_quadratic"):
        rs.load_config({"sensor": {"sigma0": 0, "sigma_quadratic": 0}})
    with pytest.raises(ValueError, match=r"segmenter\.params\.sigma0 has moved to sensor\.sigma0"):
        rs.load_config({"segmenter": {"name": "residual_edges", "params": {"sigma0": 0.01}}})
