import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.evaluation import hoover
from rangeseg_o3d.segmenters.residual_edges import segment_residual_edges
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


def test_stride_expands_labels_to_the_full_grid():
    _, scan = rgbd_suite(seed=0)[0]
    seg = segment_residual_edges(scan.cloud, sigma0=0.001, sigma_quadratic=0.001425,
                                 threshold=3.0, stride=6, min_region_size=300,
                                 jump_ratio=0.02, jump_min=0.02)
    assert seg.labels.shape == (480, 640)
    for image in seg.stages.values():
        assert image.shape == (480, 640)
    assert seg.labels.max() >= 3
    assert not seg.labels[~scan.cloud.valid].any()


def test_segmenter_validates_stride_and_config():
    cloud = rs.OrganizedCloud(np.zeros((4, 4, 3)))
    with pytest.raises(ValueError, match="stride"):
        segment_residual_edges(cloud, stride=0)
    with pytest.raises(ValueError, match="sigma0 and sigma_quadratic"):
        rs.load_config({"segmenter": {"name": "residual_edges",
                                      "params": {"sigma0": 0, "sigma_quadratic": 0}}})
