import json
import subprocess
import sys

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.cli import main
from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.suite import default_scene


@pytest.fixture(scope="module")
def scan_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scans")
    cloud = simulate_lms200(default_scene(), seed=0).cloud
    npz = cloud.save(folder / "room.npz")
    pcd = cloud.save(folder / "room.pcd")
    return cloud, npz, pcd


def test_segment_npz_writes_json(scan_files, tmp_path, capsys):
    cloud, npz, _ = scan_files
    out = tmp_path / "result.json"
    assert main(["segment", str(npz), "--config", "lms200", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    expected = rs.Pipeline("lms200").run(cloud)
    assert data["shape"] == [70, 131]
    assert len(data["features"]) == len(expected.features)
    assert {f["kind"] for f in data["features"]} == {"plane", "cylinder", "sphere"}
    assert data["config"]["name"] == "lms200"
    # Timings vary run to run: they go to the summary, the result file stays deterministic.
    assert "timings" not in data
    table = capsys.readouterr().out
    assert "sphere" in table and "planes" in table


def test_segment_batch_keeps_going_after_a_bad_file(scan_files, tmp_path, capsys):
    _, npz, pcd = scan_files
    bad = tmp_path / "broken.pcd"
    bad.write_text("VERSION 0.7\nFIELDS x y z\nDATA ascii\n")
    out_dir = tmp_path / "results"
    code = main(["segment", str(npz), str(bad), str(pcd), "--out", str(out_dir)])
    assert code == 1
    # Output names keep the folders below the inputs' common one; room.npz and room.pcd
    # differ only by suffix, so each keeps it.
    written = sorted(str(p.relative_to(out_dir)) for p in out_dir.rglob("*.json"))
    folder = npz.parent.name
    assert written == [f"{folder}/room.npz.json", f"{folder}/room.pcd.json"]
    err = capsys.readouterr().err
    assert "broken.pcd" in err and "1 of 3 inputs failed" in err
    # The PCD (float32 on disk) gives the same regions as the npz.
    a = json.loads((out_dir / folder / "room.npz.json").read_text())
    b = json.loads((out_dir / folder / "room.pcd.json").read_text())
    assert a["counts"] == b["counts"] and a["counts"]["sphere"] == 1


def test_segment_rejects_unknown_preset_and_suffix(scan_files, tmp_path, capsys):
    _, npz, _ = scan_files
    assert main(["segment", str(npz), "--config", "nope"]) == 2
    assert "unknown preset" in capsys.readouterr().err
    other = tmp_path / "scan.xyz"
    other.write_text("1 2 3\n")
    assert main(["segment", str(other)]) == 1


def test_demo_without_capture_writes_results(tmp_path, capsys):
    assert main(["demo", "--no-capture", "--out", str(tmp_path)]) == 0
    for name in ("scan.npz", "result.json", "labels.npy", "panel.png"):
        assert (tmp_path / name).stat().st_size > 0
    labels = np.load(tmp_path / "labels.npy")
    data = json.loads((tmp_path / "result.json").read_text())
    assert labels.shape == tuple(data["shape"])
    assert labels.max() == data["n_regions"]
    assert rs.OrganizedCloud.load(tmp_path / "scan.npz").shape == (70, 131)


def test_demo_through_the_simulated_serial_rig(tmp_path):
    # The README's main command, in a subprocess so the ptys and threads are its own.
    out = subprocess.run([sys.executable, "-m", "rangeseg_o3d.cli", "demo", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "serial" in out.stdout
    data = json.loads((tmp_path / "result.json").read_text())
    assert data["shape"] == [70, 131]
    assert data["counts"]["plane"] >= 5 and data["counts"]["cylinder"] >= 1


def test_segment_writes_labels_png_ply_and_json_that_load_back(scan_files, tmp_path):
    import open3d as o3d

    from rangeseg_o3d.io.export import load_result

    cloud, npz, _ = scan_files
    out, labels, ply = tmp_path / "r.json", tmp_path / "r.png", tmp_path / "r.ply"
    assert main(["segment", str(npz), "--out", str(out), "--labels", str(labels), "--ply", str(ply)]) == 0
    expected = rs.Pipeline("lms200").run(cloud)
    back = load_result(out, labels)
    np.testing.assert_array_equal(back.labels, expected.labels)
    assert [f.kind for f in back.features] == [f.kind for f in expected.features]
    assert all(f.geometry is not None and f.covariance is not None for f in back.features)
    mesh = o3d.io.read_triangle_mesh(str(ply))
    assert len(mesh.vertices) > cloud.n_valid and len(mesh.triangles) > 0


def test_segment_several_inputs_write_one_file_each_into_folders(scan_files, tmp_path):
    _, npz, pcd = scan_files
    other = tmp_path / "other.npz"
    other.write_bytes(npz.read_bytes())
    assert main(["segment", str(npz), str(other), "--labels", str(tmp_path / "labels"),
                 "--ply", str(tmp_path / "ply")]) == 0
    # Names below the inputs' common folder (they sit in two folders): one file each.
    names = [f"{npz.parent.name}/room", f"{tmp_path.name}/other"]
    for kind, suffix in (("labels", ".png"), ("ply", ".ply")):
        written = sorted(p.relative_to(tmp_path / kind).as_posix() for p in (tmp_path / kind).rglob("*.*"))
        assert written == sorted(n + suffix for n in names)
