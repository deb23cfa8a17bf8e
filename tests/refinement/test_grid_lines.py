"""Regions on one row or one column of the grid tell no surface (refinement.grid_lines)."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.evaluation import evaluate
from rangeseg_o3d.refinement.grid_lines import lines_across, on_one_grid_line, release_grid_lines
from rangeseg_o3d.synthetic.lms200 import lms200_beam_angles, lms200_tilt_angles
from rangeseg_o3d.synthetic.matrix import get_sensor, matrix_rng


def _plane_rms(points: np.ndarray) -> float:
    points = points[np.isfinite(points).all(axis=1)].astype(np.float64)
    centred = points - points.mean(axis=0)
    return float(np.sqrt(max(np.linalg.eigvalsh(centred.T @ centred)[0], 0.0) / len(points)))


def test_the_returns_of_one_scan_row_lie_in_one_plane_whatever_their_ranges():
    # a nodding laser's row of rays is a plane through its mirror, so returns anywhere
    # along those rays (here random ranges of 1-6 m) are coplanar; two rows are not. (A
    # column's rays sweep a cone about the tilt axis: its returns are one curve on whatever
    # they hit, which no more tells the surface across it.)
    rng = np.random.default_rng(4)
    beams, tilts = lms200_beam_angles(), lms200_tilt_angles()
    ranges = rng.uniform(1.0, 6.0, size=(tilts.size, beams.size))
    cloud = rs.OrganizedCloud.from_ranges(ranges, beams, tilts, mount_offset=(0, 0, 0.1))
    assert _plane_rms(cloud.xyz[30]) < 1e-6  # m: the cloud's float rounding
    assert _plane_rms(cloud.xyz[30:32].reshape(-1, 3)) > 1e-3


def test_a_camera_row_and_column_lie_in_planes_through_its_centre():
    rng = np.random.default_rng(5)
    depth = rng.uniform(500, 4000, size=(48, 64)).astype(np.uint16)
    cloud = rs.OrganizedCloud.from_depth(depth, 60.0, 60.0, 31.5, 23.5, depth_scale=0.001)
    scale = float(np.nanmax(np.abs(cloud.xyz)))
    assert _plane_rms(cloud.xyz[10]) < 1e-6 * scale
    assert _plane_rms(cloud.xyz[:, 20]) < 1e-6 * scale
    assert _plane_rms(cloud.xyz[10:12].reshape(-1, 3)) > 1e-3 * scale


def test_on_one_grid_line_tells_rows_and_columns_from_areas():
    width = 10
    assert on_one_grid_line(np.array([23, 24, 25, 29]), width)  # row 2
    assert on_one_grid_line(np.array([3, 13, 43, 63]), width)  # column 3
    assert on_one_grid_line(np.array([57]), width)
    assert on_one_grid_line(np.array([], dtype=np.int64), width)
    assert not on_one_grid_line(np.array([3, 4, 13]), width)  # an L over two rows and two columns
    assert not on_one_grid_line(np.array([0, 19]), width)  # a 360-degree seam's two columns are two


def test_lines_across_counts_the_narrower_direction():
    # merge.planes_into_curved lets strips up to two lines across be pieces of a column
    width = 10
    assert lines_across(np.array([3, 4, 13, 14, 23, 24, 33, 34]), width) == 2  # two columns
    assert lines_across(np.array([3, 13, 23]), width) == 1  # one column
    assert lines_across(np.array([20, 21, 22, 23, 30, 31, 32, 33]), width) == 2  # two rows
    assert lines_across(np.array([0, 1, 2, 10, 11, 12, 20, 21, 22]), width) == 3  # 3 x 3
    assert lines_across(np.array([], dtype=np.int64), width) == 0


def test_on_one_grid_line_refuses_a_grid_without_columns():
    with pytest.raises(ValueError, match="width must be a positive number of columns; got 0"):
        on_one_grid_line(np.array([1, 2]), 0)


def test_release_grid_lines_frees_rows_and_columns_and_keeps_areas():
    labels = np.zeros((6, 9), np.int32)
    labels[1, 1:7] = 1  # one row
    labels[:, 8] = 2  # one column
    labels[3:6, 1:4] = 3  # an area
    labels[3, 5:7] = 4  # two pixels of one row
    labels[4:6, 5] = 5  # an L of three pixels over two rows and two columns: an area
    labels[5, 6] = 5
    fits = {1: "row", 2: "column", 3: "area", 4: "pair", 5: "corner", 9: "no pixels"}
    out, kept = release_grid_lines(labels, fits)
    expected = np.where(np.isin(labels, [1, 2, 4]), 0, labels)
    np.testing.assert_array_equal(out, expected)
    assert out.dtype == labels.dtype
    assert kept == {3: "area", 5: "corner", 9: "no pixels"}
    assert labels[1, 1] == 1  # the input is not changed


def test_release_grid_lines_returns_its_inputs_when_no_region_is_a_line():
    labels = np.zeros((4, 4), np.int32)
    labels[1:3, 1:3] = 7
    fits = {7: "area"}
    out, kept = release_grid_lines(labels, fits)
    assert out is labels and kept is fits


def test_release_grid_lines_refuses_a_flat_label_array():
    with pytest.raises(ValueError, match=r"labels must be an \(H, W\) image; got shape \(12,\)"):
        release_grid_lines(np.zeros(12, np.int32), {})


@pytest.fixture(scope="module")
def noise_2mm():
    spec = get_sensor("noise_2mm")
    config = rs.load_config(spec.preset, overrides={f"sensor.{k}": v for k, v in spec.sensor_facts().items()})
    return spec, rs.Pipeline(config)


# (seed, scan, surface): matrix scans (study seeds) where one row (seed 37: returns mixed
# between a wall and the ceiling at a crease seen near grazing, 23 px) or one column (seed
# 23, 20 px) of mostly mixed returns held one or two pixels of a surface (2901 and 226 px),
# which was then scored as split in two
@pytest.mark.parametrize("seed, scan, wall", [(37, 0, 6), (23, 5, 11)])
def test_a_surface_is_not_split_by_a_line_of_mixed_returns(noise_2mm, seed, scan, wall):
    spec, pipeline = noise_2mm
    made = spec.simulate(matrix_rng(seed, spec.name, scan), False)
    result = pipeline.run(made.cloud)
    width = made.cloud.shape[1]
    for k in np.unique(result.labels[result.labels > 0]):
        assert not on_one_grid_line(np.flatnonzero(result.labels.ravel() == k), width)
    score = evaluate(made, result, tolerance=0.8, min_region=60).hoover
    assert wall in score.correct
    region = result.labels == score.correct[wall]
    on_wall = made.truth_ids == wall
    assert (region & on_wall).sum() >= 0.95 * on_wall.sum()


@pytest.mark.parametrize("seed", range(6))
def test_release_grid_lines_frees_the_regions_lines_across_calls_lines(seed):
    # the compiled bounding boxes (kernels.label_boxes) against lines_across of each region's
    # pixel indices, on random images of small regions (runs, rows, columns, single pixels),
    # a label without pixels in the fits and labels beyond them
    rng = np.random.default_rng(seed)
    h, w = 17, 23
    labels = np.zeros((h, w), np.int32)
    for k in range(1, 30):
        r, c = rng.integers(0, h), rng.integers(0, w)
        shape = rng.integers(0, 4)
        if shape == 0:
            labels[r, c:c + rng.integers(1, 6)] = k  # a run along a row
        elif shape == 1:
            labels[r:r + rng.integers(1, 6), c] = k  # a run down a column
        elif shape == 2:
            labels[r:r + rng.integers(2, 4), c:c + rng.integers(2, 4)] = k  # an area
        else:
            labels[r, c] = k
            labels[min(r + 1, h - 1), min(c + 1, w - 1)] = k  # a diagonal pair
    fits = {k: f"model {k}" for k in range(1, 33)}
    present = {k: np.flatnonzero(labels == k) for k in np.unique(labels) if k > 0}
    lines = sorted(k for k, idx in present.items() if lines_across(idx, w) <= 1)
    out, kept = release_grid_lines(labels, fits)
    np.testing.assert_array_equal(out, np.where(np.isin(labels, lines), 0, labels))
    assert kept == {k: m for k, m in fits.items() if k not in lines}
    assert (out is labels) == (not lines)
