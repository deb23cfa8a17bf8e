"""A grid beyond the size limit is refused before anything is allocated, with a clear message."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.cloud import check_grid_size, max_grid_points, set_max_grid_points
from rangeseg_o3d.cli import main


@pytest.fixture
def small_limit():
    previous = set_max_grid_points(100)
    yield 100
    set_max_grid_points(previous)


def _npz_declaring(path, shape):
    """An .npz whose xyz member declares ``shape`` but holds no data (a lying header)."""
    header = np.lib.format.header_data_from_array_1_0(np.zeros((1, 1, 3)))
    header["shape"] = shape
    with zipfile.ZipFile(path, "w") as zf, zf.open("xyz.npy", "w") as member:
        np.lib.format.write_array_header_1_0(member, header)
    return path


def test_default_limit_refuses_ten_thousand_squared(tmp_path):
    assert max_grid_points() == rs.load_config("lms200").max_grid_points == 20_000_000
    with pytest.raises(ValueError, match=r"10000 x 10000 grid \(100,000,000 points\) exceeds"):
        rs.io.load_cloud(_npz_declaring(tmp_path / "huge.npz", (10_000, 10_000, 3)))


def test_pcd_header_checked_before_reading(tmp_path):
    path = tmp_path / "huge.pcd"
    path.write_bytes(b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                     b"WIDTH 10000\nHEIGHT 10000\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 100000000\nDATA binary\n")
    with pytest.raises(ValueError, match="exceeds the limit"):
        rs.OrganizedCloud.load(path)


def test_constructors_respect_a_lowered_limit(small_limit):
    with pytest.raises(ValueError, match="11 x 10 grid"):
        rs.OrganizedCloud(np.zeros((11, 10, 3)))
    with pytest.raises(ValueError, match="depth: a 20 x 20 grid"):
        rs.OrganizedCloud.from_depth(np.ones((20, 20)), 1, 1, 0, 0)
    assert rs.OrganizedCloud(np.zeros((10, 10, 3))).shape == (10, 10)


def test_3dtk_file_checked_before_parsing(tmp_path, small_limit):
    from rangeseg_o3d.io.datasets import load_3dtk

    path = tmp_path / "scan000.3d"
    path.write_text("1 2 3\n" * 360)
    with pytest.raises(ValueError, match="1 x 360 grid"):
        load_3dtk(path)


def test_limit_is_validated():
    with pytest.raises(ValueError, match="positive integer"):
        set_max_grid_points(0)
    check_grid_size(1, max_grid_points())


def test_config_raises_the_limit_for_the_command_line(tmp_path, capsys):
    cloud = rs.OrganizedCloud(np.random.default_rng(0).normal(size=(20, 30, 3)) + [0, 0, 3])
    scan = cloud.save(tmp_path / "scan.npz")
    low = tmp_path / "low.yaml"
    low.write_text("max_grid_points: 100\n")
    previous = max_grid_points()
    try:
        assert main(["segment", str(scan), "--config", str(low)]) == 1
        err = capsys.readouterr().err
        assert "20 x 30 grid (600 points) exceeds the limit of 100 points" in err
        assert "Traceback" not in err
        high = tmp_path / "high.yaml"
        high.write_text("max_grid_points: 1000\n")
        assert main(["segment", str(scan), "--config", str(high)]) == 0
    finally:
        set_max_grid_points(previous)
