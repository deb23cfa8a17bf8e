"""360-degree scanners: with sensor.wrap_columns the first and last columns are neighbours."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.evaluation import hoover
from rangeseg_o3d.segmentation.regions import join_wrapped, label_regions, wrap_columns
from rangeseg_o3d.synthetic.scene import Scene, room
from rangeseg_o3d.synthetic.spinning import simulate_spinning_lidar


def _seam_scan():
    # a room around the sensor; the wall the seam (azimuth 0 / 360) crosses is one surface
    scene = Scene(room(x=(-4.0, 5.0), y=(-3.0, 3.5), z=(-1.2, 1.8), first_id=1))
    return simulate_spinning_lidar(scene, rows=32, cols=512, noise_sigma=0.01, seed=3)


def _run(scan, wrap: bool):
    config = rs.load_config("spinning_lidar", overrides={"sensor.wrap_columns": wrap,
                                                          "sensor.sigma0": 0.01})
    return rs.Pipeline(config).run(scan.cloud)


def _seam_surface(scan):
    ids = scan.truth_ids
    both = set(np.unique(ids[:, 0])) & set(np.unique(ids[:, -1])) - {0}
    # the surface seen in most pixels of both edge columns
    return max(both, key=lambda k: (ids[:, [0, -1]] == k).sum())


def test_a_wall_across_the_seam_is_one_region():
    scan = _seam_scan()
    wall = _seam_surface(scan)
    wrapped = _run(scan, wrap=True)
    at_wall = wrapped.labels[scan.truth_ids == wall]
    ids, counts = np.unique(at_wall[at_wall > 0], return_counts=True)
    assert counts.max() >= 0.9 * at_wall.size  # one region holds the wall on both sides
    label = ids[np.argmax(counts)]
    cols = np.nonzero((wrapped.labels == label).any(axis=0))[0]
    assert cols.min() == 0 and cols.max() == scan.cloud.shape[1] - 1
    assert wall in hoover(scan.truth_ids, wrapped.labels).correct


def _segment(scan, wrap: bool):
    from rangeseg_o3d.segmenters.residual_edges import segment_residual_edges

    pipe = rs.Pipeline(rs.load_config("spinning_lidar", overrides={"sensor.wrap_columns": wrap,
                                                                    "sensor.sigma0": 0.01}))
    return segment_residual_edges(scan.cloud, sensor=pipe.sensor, **pipe.config.segmenter.params)


@pytest.mark.parametrize("wrap", [True, False])
def test_the_segmenter_joins_the_seam_only_when_told(wrap):
    scan = _seam_scan()
    wall = _seam_surface(scan)
    seg = _segment(scan, wrap)
    first = seg.labels[:, 0][scan.truth_ids[:, 0] == wall]
    last = seg.labels[:, -1][scan.truth_ids[:, -1] == wall]
    first, last = set(first[first > 0].tolist()), set(last[last > 0].tolist())
    assert first and last
    # one flood-fill region on both sides of the seam, or two
    assert bool(first & last) == wrap
    assert seg.labels.shape == scan.cloud.shape
    assert all(image.shape[:2] == scan.cloud.shape for image in seg.stages.values())


def test_join_wrapped_unites_labels_across_the_seam():
    edges = np.zeros((6, 20), bool)
    edges[:, 5] = edges[:, 14] = True  # two cuts: a band in the middle, one across the seam
    padded = label_regions(wrap_columns(edges, 3), min_size=1)
    labels = join_wrapped(padded, 3)
    assert labels.shape == (6, 20)
    assert labels[0, 0] == labels[0, 19] == labels[0, 17]  # across the seam: one region
    assert labels[0, 10] != labels[0, 0]
    assert set(np.unique(labels)) == {0, 1, 2}


def test_wrap_columns_validates():
    with pytest.raises(ValueError, match="pad"):
        wrap_columns(np.zeros((2, 4)), 5)


def test_region_adjacency_across_the_seam():
    from rangeseg_o3d.refinement.merge import region_adjacency

    labels = np.zeros((4, 20), np.int32)
    labels[:, :3] = 1
    labels[:, 8:12] = 3
    labels[:, -3:] = 2
    assert (1, 2) not in region_adjacency(labels)
    assert (1, 2) in region_adjacency(labels, wrap_columns=True)
    assert (1, 3) not in region_adjacency(labels, wrap_columns=True)
