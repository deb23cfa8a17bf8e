"""`rangeseg segment` over many inputs: failures per input, outputs checked first, names."""

import json
import os
import re
import subprocess
import sys
import zipfile

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.cli import main


def _bad_inputs(folder, good_npz):
    """Malformed inputs of several kinds; each must fail alone with a clear message."""
    folder.mkdir()
    bad = {}
    bad["empty.npz"] = folder / "empty.npz"
    bad["empty.npz"].write_bytes(b"")  # np.load: EOFError
    corrupt = folder / "corrupt.npz"  # a member whose bytes are damaged: BadZipFile / zlib
    data = bytearray(good_npz.read_bytes())
    data[len(data) // 2: len(data) // 2 + 64] = b"\xff" * 64
    corrupt.write_bytes(bytes(data))
    bad["corrupt.npz"] = corrupt
    truncated = folder / "truncated.npz"
    truncated.write_bytes(good_npz.read_bytes()[: good_npz.stat().st_size // 3])
    bad["truncated.npz"] = truncated
    not_zip = folder / "text.npz"
    not_zip.write_text("hello")
    bad["text.npz"] = not_zip
    fifo = folder / "pipe.3d"
    os.mkfifo(fifo)  # opening would block forever
    bad["pipe.3d"] = fifo
    bad["missing.pcd"] = folder / "missing.pcd"
    bad["scan.xyz"] = folder / "scan.xyz"
    bad["scan.xyz"].write_text("1 2 3\n")
    return bad


def test_each_bad_input_is_reported_once_and_the_others_go_on(scan_tree, tmp_path, capsys):
    _, paths = scan_tree
    bad = _bad_inputs(tmp_path / "bad", paths[0])
    inputs = [str(paths[0]), *map(str, bad.values()), str(paths[1]), "/dev/null"]
    out = tmp_path / "out"
    code = main(["segment", *inputs, "--out", str(out), "--jobs", "1"])
    captured = capsys.readouterr()
    assert code == 1
    assert f"{len(bad) + 1} of {len(inputs)} inputs failed" in captured.err
    assert "Traceback" not in captured.err + captured.out
    error_lines = [line for line in captured.err.splitlines() if "error:" in line]
    assert len(error_lines) == len(bad) + 1
    for path in [*map(str, bad.values()), "/dev/null"]:
        [line] = [line for line in error_lines if path + ":" in line or line.endswith(path)
                  or f"{path} " in line]
        assert line.count(path) == 1, line  # the path is named exactly once
    assert "is not a readable .npz archive" in captured.err  # the empty npz (load_npz names it)
    assert re.search(r"pipe\.3d is a FIFO", captured.err)
    assert re.search(r"/dev/null is a character device", captured.err)
    # The good inputs were written, and the summary has one row per input.
    # (named below the common folder of the inputs that exist: /dev/null moves nothing)
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [
        "scans", "scans/a", "scans/a/scan.json", "scans/b", "scans/b/scan.json",
        "summary.jsonl", "summary.parquet"]
    rows = [json.loads(line) for line in (out / "summary.jsonl").read_text().splitlines()]
    assert [r["input"] for r in rows] == inputs
    assert [r["status"] for r in rows].count("failed") == len(bad) + 1
    assert all(r["error"] is None and r["planes"] >= 5 for r in rows if r["status"] == "ok")


def test_same_file_names_in_two_folders_get_two_outputs(scan_tree, tmp_path, room_cloud):
    root, paths = scan_tree
    other = rs.OrganizedCloud(room_cloud.xyz[:, ::-1].copy())  # a different scan, same name
    other.save(paths[1])
    out = tmp_path / "out"
    assert main(["segment", str(root / "a"), str(root / "b"), "--out", str(out), "--jobs", "1"]) == 0
    a = json.loads((out / "a" / "scan.json").read_text())
    b = json.loads((out / "b" / "scan.json").read_text())
    assert a["input"] == str(paths[0]) and b["input"] == str(paths[1])
    assert a["features"] != b["features"]


@pytest.mark.parametrize("case", ["json_for_two", "missing_parent", "file_in_the_way",
                                  "json_in_missing_folder", "unwritable"])
def test_bad_outputs_fail_before_any_work(scan_tree, tmp_path, capsys, monkeypatch, case):
    _, paths = scan_tree
    inputs = [str(p) for p in paths[:2]]
    if case == "json_for_two":
        out, expect = tmp_path / "x.json", "names one file but 2 inputs"
    elif case == "missing_parent":
        out, expect = tmp_path / "no" / "such" / "out", "does not exist"
    elif case == "file_in_the_way":
        out, expect = tmp_path / "taken", "exists and is not a folder"
        out.write_text("")
    elif case == "json_in_missing_folder":
        inputs, out, expect = inputs[:1], tmp_path / "none" / "r.json", "does not exist"
    else:
        if not os.path.isdir("/proc/self"):
            pytest.skip("needs /proc, a folder nobody can write")
        inputs, out, expect = inputs[:1], "/proc/r.json", "not writable"
    started = []
    monkeypatch.setattr("rangeseg_o3d.batch.task.load_scan", lambda *a, **k: started.append(a))
    assert main(["segment", *inputs, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert expect in err and err.count("\n") == 1
    assert started == []  # no input was read
    if case == "json_for_two":
        assert not out.exists()  # no folder named x.json


def test_version_and_non_finite_floats(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.strip() == f"rangeseg {rs.__version__}"
    for argv in (["demo", "--faults", "nan"], ["demo", "--faults", "inf"],
                 ["capture", "--simulate", "--time-scale=-inf"],
                 ["capture", "--simulate", "--tilt-start", "nan"],
                 ["segment", "x.npz", "--jobs", "0"]):
        with pytest.raises(SystemExit) as stop:
            main(argv)
        assert stop.value.code == 2
        err = capsys.readouterr().err
        assert "expected a" in err and "Traceback" not in err


def test_finite_float_type():
    import argparse

    from rangeseg_o3d.cli.args import finite_float, positive_int

    assert finite_float("1e-3") == pytest.approx(1e-3)
    for text in ("nan", "inf", "-Infinity", "1e999", "one"):
        with pytest.raises(argparse.ArgumentTypeError):
            finite_float(text)
    with pytest.raises(argparse.ArgumentTypeError):
        positive_int("-2")


def test_glob_resume_and_summary_table(scan_tree, tmp_path, capsys):
    root, paths = scan_tree
    out = tmp_path / "out"
    pattern = str(root / "*" / "scan.npz")
    assert main(["segment", pattern, "--out", str(out), "--jobs", "1"]) == 0
    first = [json.loads(line) for line in (out / "summary.jsonl").read_text().splitlines()]
    assert [r["status"] for r in first] == ["ok", "ok"]
    assert all(r["segment_s"] > 0 and r["total_s"] >= r["segment_s"] and "total" in r["stage_timings"]
               for r in first)
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*.json")}
    capsys.readouterr()
    # Resume with one more input: only that one runs, the earlier rows are kept.
    assert main(["segment", pattern, str(paths[2]), "--out", str(out), "--resume", "--jobs", "1"]) == 0
    assert {p: p.stat().st_mtime_ns for p in before} == before
    rows = [json.loads(line) for line in (out / "summary.jsonl").read_text().splitlines()]
    assert [r["status"] for r in rows] == ["skipped", "skipped", "ok"]
    assert rows[0]["planes"] == first[0]["planes"] and rows[0]["segment_s"] == first[0]["segment_s"]
    assert "2 skipped" in capsys.readouterr().out
    pq = pytest.importorskip("pyarrow.parquet")
    table = pq.read_table(out / "summary.parquet").to_pylist()
    assert [r["status"] for r in table] == ["skipped", "skipped", "ok"]
    assert table[2]["planes"] == rows[2]["planes"] and json.loads(table[2]["stage_timings"])["total"] > 0


def test_resume_needs_outputs(scan_tree, capsys):
    _, paths = scan_tree
    assert main(["segment", str(paths[0]), "--resume"]) == 2
    assert "--resume needs --out" in capsys.readouterr().err


def test_segment_without_out_prints_every_table(scan_tree, capsys):
    _, paths = scan_tree
    assert main(["segment", str(paths[0]), str(paths[2]), "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    assert out.count("planes,") == 2 and str(paths[2]) in out
