"""scripts/benchmark.py --export-frames: real frames as raw float32 + a manifest, for timing
other programs (CAPE, PEAC) on the very points rangeseg_o3d's loaders give; and the matrix's
--surfaces listing and --connected-truth relabelling."""

import importlib.util
import os
from pathlib import Path
from types import SimpleNamespace
from unittest import mock

import numpy as np
import pytest

from rangeseg_o3d import OrganizedCloud
from rangeseg_o3d.io.datasets import real_clouds

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "benchmark.py"


@pytest.fixture(scope="module")
def benchmark():
    # the script pins thread counts in os.environ when imported: keep that out of this process
    spec = importlib.util.spec_from_file_location("benchmark_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    with mock.patch.dict(os.environ):
        spec.loader.exec_module(module)
    return module


def _manifest(path: Path) -> dict:
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[0].startswith("#")
    rows = {}
    for line in lines[1:]:
        name, rows_, cols, *intrinsics = line.split()
        rows[name] = (int(rows_), int(cols), [float(v) for v in intrinsics])
    return rows


def _read_raw(path: Path, rows: int, cols: int) -> np.ndarray:
    return np.fromfile(path, dtype="<f4").reshape(rows, cols, 3)


def test_export_writes_points_and_intrinsics(benchmark, tmp_path):
    depth = np.full((12, 16), 1500, dtype=np.uint16)
    depth[3:5, 7:10] = 0  # no return
    depth[8:, :] = 2750
    camera = OrganizedCloud.from_depth(depth, 520.0, 521.5, 7.5, 5.25, depth_scale=0.001)
    xyz = np.random.default_rng(4).normal(size=(5, 7, 3))
    xyz[2, 3] = np.nan
    bare = OrganizedCloud(xyz)  # no pinhole geometry
    items = [SimpleNamespace(name="camera", load=lambda: camera), SimpleNamespace(name="bare", load=lambda: bare)]

    manifest = benchmark.export_frames(tmp_path / "out", items)

    table = _manifest(manifest)
    assert list(table) == ["camera", "bare"]
    rows, cols, intrinsics = table["camera"]
    assert (rows, cols) == (12, 16)
    np.testing.assert_allclose(intrinsics, [520.0, 521.5, 7.5, 5.25], rtol=1e-12)
    assert np.isnan(table["bare"][2]).all()
    for name, cloud in (("camera", camera), ("bare", bare)):
        raw = _read_raw(tmp_path / "out" / f"{name}.xyz", *table[name][:2])
        np.testing.assert_array_equal(np.isnan(raw).all(axis=-1), ~cloud.valid)
        valid = cloud.valid
        # float32 of the metres the loader gave: within float32's relative precision
        np.testing.assert_allclose(raw[valid], cloud.xyz[valid], rtol=1e-7, atol=0)
    assert np.isnan(_read_raw(tmp_path / "out" / "camera.xyz", 12, 16)[3, 8]).all()


def test_export_refuses_a_file_and_bad_names(benchmark, tmp_path):
    cloud = OrganizedCloud(np.ones((2, 2, 3)))
    target = tmp_path / "taken"
    target.write_text("x")
    with pytest.raises(ValueError, match="expects a directory"):
        benchmark.export_frames(target, [SimpleNamespace(name="a", load=lambda: cloud)])
    with pytest.raises(ValueError, match="without spaces"):
        benchmark.export_frames(tmp_path / "d", [SimpleNamespace(name="a b", load=lambda: cloud)])
    with pytest.raises(SystemExit) as exc:
        benchmark.main(["--export-frames", str(target)])
    assert exc.value.code == 2


def test_export_of_the_six_real_frames(benchmark, tmp_path):
    present = {item.name for item in real_clouds()} & set(benchmark.VGA_FRAMES)
    if not present:
        pytest.skip("no real 640x480 frame in ../shared/data")

    assert benchmark.main(["--export-frames", str(tmp_path)]) == 0

    table = _manifest(tmp_path / "frames.txt")
    assert set(table) == present
    for name, (rows, cols, intrinsics) in table.items():
        assert (rows, cols) == (480, 640)
        assert (tmp_path / f"{name}.xyz").stat().st_size == 480 * 640 * 3 * 4
        assert all(np.isfinite(intrinsics)), name  # every frame's points fit a pinhole
    if "cape_tunnel" in table:  # CAPE's IR intrinsics (SOURCES.md)
        np.testing.assert_allclose(table["cape_tunnel"][2], [575.93, 576.41, 315.15, 230.59], atol=0.01)
        raw = _read_raw(tmp_path / "cape_tunnel.xyz", 480, 640)
        valid_z = raw[..., 2][np.isfinite(raw[..., 2])]
        # depth_0.png: 832 to 6990 mm where valid, 14.7 % of pixels without a return
        assert 0.83 <= valid_z.min() and valid_z.max() <= 6.991
        assert np.isnan(raw[..., 2]).mean() == pytest.approx(45256 / (480 * 640), abs=1e-4)


def test_print_surfaces_lists_each_scan_and_surface(benchmark, capsys):
    rows = [{"sensor": "abw", "residual_edges": {"surfaces": [
        {"scan": "abw.test.4", "surfaces": [
            {"truth_id": 16, "pixels": 79, "status": "under", "parts": [(17, "plane", 72, 0.0931), (0, "", 7, 0.0)]}]},
        {"scan": "abw.test.5", "surfaces": []}]}}]
    benchmark.print_surfaces(rows)
    lines = capsys.readouterr().out.splitlines()
    assert lines[-3:] == ["abw RE scan abw.test.4: 1 not correct",
                          "  gt16       79 px under  -> 17p:72(0.09), 0:7(0.00)",
                          "abw RE scan abw.test.5: 0 not correct"]


def test_as_connected_patches_keeps_each_patch_s_model(benchmark):
    from rangeseg_o3d.fitting.primitives import Plane
    from rangeseg_o3d.synthetic.scene import SyntheticScan

    t = np.zeros((4, 9), dtype=np.int32)
    t[:, :3] = t[:, 6:] = 5
    t[:, 3:6] = 9
    floor, box = Plane(np.array([0.0, 0.0, 1.0]), 1.0, 0.0, 10), Plane(np.array([1.0, 0.0, 0.0]), 0.2, 0.0, 10)
    scan = SyntheticScan(cloud=None, truth_ids=t, truth={5: floor, 9: box})
    patched = benchmark.as_connected_patches(scan)
    assert patched.truth_ids.tolist()[0] == [1, 1, 1, 3, 3, 3, 2, 2, 2]
    assert patched.truth == {1: floor, 2: floor, 3: box}
    assert scan.truth_ids[0, 6] == 5  # the scan itself is left alone
