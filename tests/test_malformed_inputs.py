"""A campaign of malformed inputs: each ends in a clear error or a correct result.

Every scan case goes through the library loader (a ValueError, or FileNotFoundError for a
missing file) and through ``rangeseg segment`` (a non-zero exit code, the file named on
stderr, no exception escaping ``main`` -- which is what a traceback would be). Every
configuration case goes through :func:`load_config` and ``rangeseg segment --config``.
Cases that belong to another part of issue 11 (special files in the batch flow, PCD field
types) are written against the behaviour the issue specifies.
"""

from __future__ import annotations

import io
import os
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from rangeseg_o3d import OrganizedCloud
from rangeseg_o3d.cli import main
from rangeseg_o3d.config import load_config
from rangeseg_o3d.io.datasets import load_3dtk
from rangeseg_o3d.io.pcd import write_pcd

ROOT = Path(__file__).resolve().parent.parent


def _wall(rows=12, cols=16):
    """A tilted wall 3 m away: a small scan the pipeline segments into one plane."""
    v, u = np.mgrid[0:rows, 0:cols]
    xyz = np.stack([np.full(u.shape, 3.0) + 0.01 * u, 0.05 * (u - cols / 2), 0.05 * (v - rows / 2)], axis=-1)
    return OrganizedCloud(xyz)


def _npz_bytes(**arrays) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _good_npz() -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, format_version=np.asarray(1), xyz=_wall().xyz)
    return buffer.getvalue()


def _compressed_with_damaged_member() -> bytes:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, xyz=np.random.default_rng(0).normal(size=(20, 20, 3)))
    data = bytearray(buffer.getvalue())
    middle = len(data) // 2
    data[middle:middle + 40] = bytes(40)  # inside the deflated xyz member
    return bytes(data)


def _npz_declaring(shape) -> bytes:
    header = np.lib.format.header_data_from_array_1_0(np.zeros((1, 1, 3)))
    header["shape"] = shape
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive, archive.open("xyz.npy", "w") as member:
        np.lib.format.write_array_header_1_0(member, header)
    return buffer.getvalue()


def _npy_bytes() -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, _wall().xyz)
    return buffer.getvalue()


def _pcd(header_lines, data: bytes = b"") -> bytes:
    return ("\n".join(header_lines) + "\n").encode() + data


def _pcd_header(width=4, height=3, points=None, data="ascii", fields="x y z", size="4 4 4", type_="F F F",
                count="1 1 1"):
    return ["# .PCD v0.7", "VERSION 0.7", f"FIELDS {fields}", f"SIZE {size}", f"TYPE {type_}",
            f"COUNT {count}", f"WIDTH {width}", f"HEIGHT {height}", "VIEWPOINT 0 0 0 1 0 0 0",
            f"POINTS {width * height if points is None else points}", f"DATA {data}"]


def _ascii_points(n, values=None) -> bytes:
    rows = values if values is not None else [f"{3 + 0.01 * i} {0.05 * i} 0.1" for i in range(n)]
    return ("\n".join(rows) + "\n").encode()


def _binary_pcd_bytes(compressed: bool) -> bytes:
    path = Path(os.environ.get("TMPDIR", "/tmp")) / f"rangeseg-campaign-{os.getpid()}-{compressed}.pcd"
    try:
        write_pcd(_wall(), path, data="binary_compressed" if compressed else "binary")
        return path.read_bytes()
    finally:
        path.unlink(missing_ok=True)


def _truncate(data: bytes, keep: float) -> bytes:
    return data[: int(len(data) * keep)]


def _flip_payload(data: bytes) -> bytes:
    data = bytearray(data)
    start = data.index(b"DATA binary_compressed\n") + len("DATA binary_compressed\n") + 8
    for i in range(start, len(data), 7):
        data[i] ^= 0xA5
    return bytes(data)


def _3d_lines(n, line="100 20 300") -> bytes:
    return ("\n".join([line] * n) + "\n").encode()


# (case id, file name, content factory, fragment the error message must hold)
BAD_SCANS = [
    # .npz
    ("npz-empty", "scan.npz", lambda: b"", "not a readable .npz"),
    ("npz-truncated-half", "scan.npz", lambda: _truncate(_good_npz(), 0.5), "scan.npz"),
    ("npz-truncated-10-bytes", "scan.npz", lambda: _good_npz()[:10], "scan.npz"),
    ("npz-truncated-end-record", "scan.npz", lambda: _good_npz()[:-10], "scan.npz"),
    ("npz-damaged-deflate-member", "scan.npz", _compressed_with_damaged_member, "damaged"),
    ("npz-plain-text", "scan.npz", lambda: b"x y z\n1 2 3\n", "not a readable .npz"),
    ("npz-random-bytes", "scan.npz", lambda: np.random.default_rng(1).bytes(4096), "scan.npz"),
    ("npz-single-npy", "scan.npz", _npy_bytes, "single array"),
    ("npz-no-xyz", "scan.npz", lambda: _npz_bytes(points=np.zeros((2, 2, 3))), "no 'xyz'"),
    ("npz-xyz-2d", "scan.npz", lambda: _npz_bytes(xyz=np.zeros((4, 3))), "(H, W, 3)"),
    ("npz-xyz-4-channels", "scan.npz", lambda: _npz_bytes(xyz=np.zeros((2, 2, 4))), "(H, W, 3)"),
    ("npz-xyz-strings", "scan.npz", lambda: _npz_bytes(xyz=np.full((2, 2, 3), "a")), "float"),
    ("npz-xyz-complex", "scan.npz", lambda: _npz_bytes(xyz=np.zeros((2, 2, 3), complex)), "float"),
    ("npz-xyz-object-pickle", "scan.npz", lambda: _npz_bytes(xyz=np.array([[{"a": 1}]], dtype=object)),
     "scan.npz"),
    ("npz-xyz-infinite", "scan.npz", lambda: _npz_bytes(xyz=np.full((2, 2, 3), np.inf)), "infinite"),
    ("npz-zero-rows", "scan.npz", lambda: _npz_bytes(xyz=np.zeros((0, 5, 3))), "at least one row"),
    ("npz-future-version", "scan.npz", lambda: _npz_bytes(format_version=np.asarray(99), xyz=np.zeros((2, 2, 3))),
     "format_version 99"),
    ("npz-version-text", "scan.npz", lambda: _npz_bytes(format_version=np.asarray("one"), xyz=np.zeros((2, 2, 3))),
     "format_version"),
    ("npz-bogus-geometry", "scan.npz",
     lambda: _npz_bytes(xyz=np.zeros((2, 2, 3)), geometry_kind=np.asarray("bogus")), "geometry_kind"),
    ("npz-nodding-without-tilts", "scan.npz",
     lambda: _npz_bytes(xyz=np.zeros((2, 2, 3)), geometry_kind=np.asarray("nodding"),
                        beam_angles=np.zeros(2), mount_offset=np.zeros(3)), "tilt_angles"),
    ("npz-pinhole-nan-focal", "scan.npz",
     lambda: _npz_bytes(xyz=np.zeros((2, 2, 3)), geometry_kind=np.asarray("pinhole"), fx=np.asarray(np.nan),
                        fy=np.asarray(1.0), cx=np.asarray(0.0), cy=np.asarray(0.0)), "fx"),
    ("npz-ranges-wrong-shape", "scan.npz", lambda: _npz_bytes(xyz=np.zeros((2, 2, 3)), ranges=np.zeros((3, 3))),
     "ranges"),
    ("npz-timestamps-wrong-length", "scan.npz",
     lambda: _npz_bytes(xyz=np.zeros((2, 2, 3)), timestamps=np.zeros(5)), "timestamps"),
    ("npz-lying-huge-header", "scan.npz", lambda: _npz_declaring((10_000, 10_000, 3)), "exceeds the limit"),
    ("npz-lying-header-no-data", "scan.npz", lambda: _npz_declaring((20, 30, 3)), "scan.npz"),
    # .pcd
    ("pcd-empty", "scan.pcd", lambda: b"", "scan.pcd"),
    ("pcd-header-only", "scan.pcd", lambda: _pcd(_pcd_header()[:-1]), "scan.pcd"),
    ("pcd-ascii-fewer-points", "scan.pcd", lambda: _pcd(_pcd_header(), _ascii_points(5)), "scan.pcd"),
    ("pcd-ascii-text-value", "scan.pcd",
     lambda: _pcd(_pcd_header(2, 1), _ascii_points(2, ["1 2 3", "1 two 3"])), "scan.pcd"),
    ("pcd-binary-truncated", "scan.pcd", lambda: _truncate(_binary_pcd_bytes(False), 0.6), "shorter than declared"),
    ("pcd-compressed-truncated", "scan.pcd", lambda: _truncate(_binary_pcd_bytes(True), 0.7), "scan.pcd"),
    ("pcd-compressed-corrupt", "scan.pcd", lambda: _flip_payload(_binary_pcd_bytes(True)), "scan.pcd"),
    ("pcd-points-lie", "scan.pcd", lambda: _pcd(_pcd_header(points=7), _ascii_points(12)), "POINTS"),
    ("pcd-width-zero", "scan.pcd", lambda: _pcd(_pcd_header(0, 3, points=0)), "WIDTH"),
    ("pcd-width-negative", "scan.pcd", lambda: _pcd(_pcd_header(-5, 3, points=-15)), "scan.pcd"),
    ("pcd-width-text", "scan.pcd",
     lambda: _pcd([line if not line.startswith("WIDTH") else "WIDTH four" for line in _pcd_header()]), "WIDTH"),
    ("pcd-no-z", "scan.pcd",
     lambda: _pcd(_pcd_header(fields="x y", size="4 4", type_="F F", count="1 1"), _ascii_points(12)), "scan.pcd"),
    ("pcd-size-3", "scan.pcd", lambda: _pcd(_pcd_header(size="3 3 3"), _ascii_points(12)), "scan.pcd"),
    ("pcd-unknown-data", "scan.pcd", lambda: _pcd(_pcd_header(data="binary_foo"), b""), "scan.pcd"),
    ("pcd-lying-huge-dims", "scan.pcd", lambda: _pcd(_pcd_header(100_000, 100_000, data="binary")),
     "exceeds the limit"),
    ("pcd-count-mismatch", "scan.pcd", lambda: _pcd(_pcd_header(count="1 1"), _ascii_points(12)), "scan.pcd"),
    ("pcd-binary-junk-header", "scan.pcd", lambda: np.random.default_rng(2).bytes(2048), "scan.pcd"),
    ("pcd-integer-coordinates", "scan.pcd", lambda: _pcd(_pcd_header(type_="I I I"), _ascii_points(12)),
     "scan.pcd"),
    # 3DTK .3d
    ("3d-empty", "scan000.3d", lambda: b"", "scan000.3d"),
    ("3d-four-values", "scan000.3d", lambda: _3d_lines(360, "1 2 3 4"), "3 values"),
    ("3d-text-value", "scan000.3d", lambda: _3d_lines(359) + b"1 two 3\n", "not a number"),
    ("3d-partial-row", "scan000.3d", lambda: _3d_lines(500), "do not fill rows"),
    ("3d-binary-junk", "scan000.3d", lambda: np.random.default_rng(3).bytes(3000), "scan000.3d"),
    # names and kinds of files
    ("unknown-suffix", "scan.txt", lambda: b"1 2 3\n", "scan.txt"),
    ("no-suffix", "scan", lambda: _good_npz(), "scan"),
]

#: Cases another helper's part of issue 11 fixes: xfail(strict) while they still fail.
OWNED_ELSEWHERE: dict[str, str] = {}


def _write(tmp_path, name, factory) -> Path:
    path = tmp_path / name
    path.write_bytes(factory())
    return path


def _load(path: Path):
    if path.suffix.lower() == ".3d":
        return load_3dtk(path)
    return OrganizedCloud.load(path)


def _segment(argv, capsys) -> tuple[int, str]:
    try:
        code = main(["segment", *argv])
    except SystemExit as stop:  # argparse
        code = stop.code
    except BaseException as escaped:  # what the user would see as a traceback
        pytest.fail(f"rangeseg segment {' '.join(argv)} raised {type(escaped).__name__}: {escaped}")
    return code, capsys.readouterr().err


def _maybe_owned(request, case_id):
    reason = OWNED_ELSEWHERE.get(case_id)
    if reason:
        request.applymarker(pytest.mark.xfail(strict=True, reason=reason))


@pytest.mark.parametrize("case_id, name, factory, fragment", BAD_SCANS, ids=[c[0] for c in BAD_SCANS])
def test_malformed_scan_is_a_clear_error_in_the_library(tmp_path, request, case_id, name, factory, fragment):
    _maybe_owned(request, case_id)
    path = _write(tmp_path, name, factory)
    with pytest.raises(ValueError) as info:
        _load(path)
    assert fragment in str(info.value)


@pytest.mark.parametrize("case_id, name, factory, fragment", BAD_SCANS, ids=[c[0] for c in BAD_SCANS])
def test_malformed_scan_is_a_clear_error_on_the_command_line(tmp_path, capsys, request, case_id, name, factory,
                                                             fragment):
    _maybe_owned(request, case_id)
    path = _write(tmp_path, name, factory)
    code, err = _segment([str(path)], capsys)
    assert code != 0
    assert str(path) in err and "Traceback" not in err


def test_a_good_scan_beside_bad_ones_still_gives_its_result(tmp_path, capsys):
    good = _wall().save(tmp_path / "good.npz")
    bad = _write(tmp_path, "bad.npz", lambda: b"")
    code, err = _segment([str(bad), str(good), "--out", str(tmp_path / "results")], capsys)
    assert code == 1 and "bad.npz" in err
    assert (tmp_path / "results" / "good.json").is_file()


def test_all_invalid_points_is_a_clear_error_not_zero_regions(tmp_path, capsys):
    cloud = OrganizedCloud(np.full((6, 8, 3), np.nan))
    assert cloud.n_valid == 0
    path = cloud.save(tmp_path / "empty.npz")
    code, err = _segment([str(path)], capsys)
    assert code != 0 and f"{path}: cloud has no valid point" in err


def test_infinite_3dtk_values_are_points_without_a_return(tmp_path):
    # 3DTK files mark no-return with huge values; inf is outside the range filter too
    path = _write(tmp_path, "scan000.3d", lambda: _3d_lines(360, "inf 1 1"))
    cloud = load_3dtk(path)
    assert cloud.shape == (1, 360) and cloud.n_valid == 0


def test_missing_file(tmp_path, capsys):
    path = tmp_path / "absent.npz"
    with pytest.raises(FileNotFoundError):
        OrganizedCloud.load(path)
    code, err = _segment([str(path)], capsys)
    assert code != 0 and str(path) in err


def test_directory_named_like_a_scan(tmp_path, capsys):
    path = tmp_path / "scan.npz"
    path.mkdir()
    with pytest.raises(ValueError, match="is a directory, not a regular file"):
        OrganizedCloud.load(path)
    code, err = _segment([str(path)], capsys)
    assert code != 0 and str(path) in err


def test_symlink_loop(tmp_path, capsys):
    path = tmp_path / "loop.npz"
    path.symlink_to(path)
    code, err = _segment([str(path)], capsys)
    assert code != 0 and str(path) in err


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
@pytest.mark.parametrize("name", ["scan000.3d", "scan.npz", "scan.pcd"])
def test_fifo_named_like_a_scan_is_refused_not_read(tmp_path, name):
    fifo = tmp_path / name
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="FIFO"):
        load_3dtk(fifo) if name.endswith(".3d") else OrganizedCloud.load(fifo)
    done = subprocess.run([sys.executable, "-m", "rangeseg_o3d.cli", "segment", str(fifo)],
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode != 0 and str(fifo) in done.stderr and "Traceback" not in done.stderr


def test_character_device_is_refused(tmp_path, capsys):
    device = tmp_path / "zero.3d"
    device.symlink_to("/dev/zero")  # reading it would never end
    with pytest.raises(ValueError, match="a character device"):
        load_3dtk(device)
    code, err = _segment([str(device)], capsys)
    assert code != 0 and str(device) in err


# -- configurations -----------------------------------------------------------------------

BAD_CONFIGS = [
    ("yaml-empty", "", "must hold a mapping"),
    ("yaml-list", "- 1\n- 2\n", "must hold a mapping"),
    ("yaml-syntax", "segmenter: {name: residual_edges\n", "not valid YAML"),
    ("yaml-tab-indent", "segmenter:\n\tname: x\n", "not valid YAML"),
    ("unknown-key", "colour: red\n", "colour"),
    ("unknown-segmenter", "segmenter: {name: no_such}\n", "no_such"),
    ("threshold-inf", "segmenter: {name: residual_edges, params: {threshold: .inf}}\n", "threshold"),
    ("threshold-nan", "segmenter: {name: residual_edges, params: {threshold: .nan}}\n", "threshold"),
    ("threshold-text", "segmenter: {name: residual_edges, params: {threshold: high}}\n", "threshold"),
    ("k-sigma-inf", "refine: {k_sigma: .inf}\n", "k_sigma"),
    ("merge-tolerance-nan", "refine: {merge_tolerance: .nan}\n", "merge_tolerance"),
    ("max-fit-points-negative", "max_fit_points: -1\n", "max_fit_points"),
    ("tile-text", "tile: six\n", "tile"),
    ("max-grid-points-zero", "max_grid_points: 0\n", "max_grid_points"),
    ("sensor-sigma-nan", "sensor: {sigma0: .nan}\n", "sigma0"),
    ("params-not-mapping", "segmenter: {name: residual_edges, params: [1, 2]}\n", "params"),
]


@pytest.mark.parametrize("case_id, text, fragment", BAD_CONFIGS, ids=[c[0] for c in BAD_CONFIGS])
def test_malformed_configuration_is_a_clear_error(tmp_path, capsys, case_id, text, fragment):
    path = tmp_path / f"{case_id}.yaml"
    path.write_text(text)
    with pytest.raises(ValueError) as info:
        load_config(path)
    assert fragment in str(info.value)
    scan = _wall().save(tmp_path / "scan.npz")
    code, err = _segment([str(scan), "--config", str(path)], capsys)
    assert code != 0 and fragment in err and "Traceback" not in err


def test_binary_file_as_configuration(tmp_path, capsys):
    path = tmp_path / "binary.yaml"
    path.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(ValueError, match="binary.yaml"):
        load_config(path)
    code, err = _segment([str(_wall().save(tmp_path / "scan.npz")), "--config", str(path)], capsys)
    assert code != 0 and "binary.yaml" in err


def test_directory_as_configuration(tmp_path, capsys):
    folder = tmp_path / "preset.yaml"
    folder.mkdir()
    with pytest.raises(ValueError, match="preset.yaml' is not a regular file"):
        load_config(folder)


def test_unknown_preset_lists_the_known_ones(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="unknown preset 'nope'; known presets: .*lms200"):
        load_config("nope")


@pytest.mark.parametrize("argv, fragment", [
    (["demo", "--no-capture", "--faults", "nan"], "faults"),
    (["demo", "--no-capture", "--faults", "inf"], "faults"),
    (["capture", "--simulate", "--faults", "nan", "--out", "x.npz"], "--faults"),
    (["capture", "--simulate", "--time-scale", "inf", "--out", "x.npz"], "--time-scale"),
    (["capture", "--simulate", "--time-scale", "0", "--out", "x.npz"], "--time-scale"),
])
def test_non_finite_float_options_are_refused(tmp_path, monkeypatch, capsys, argv, fragment):
    monkeypatch.chdir(tmp_path)
    try:
        code = main(argv + (["--out", str(tmp_path / "demo")] if argv[0] == "demo" else []))
    except SystemExit as stop:  # argparse refusing the value: its message, exit code 2
        code = stop.code
    except BaseException as escaped:
        pytest.fail(f"raised {type(escaped).__name__}: {escaped}")
    err = capsys.readouterr().err
    assert code != 0 and fragment in err and "Traceback" not in err


def test_campaign_size():
    assert len(BAD_SCANS) + len(BAD_CONFIGS) >= 60
    assert struct.calcsize("<I") == 4  # the PCD builders above assume 4-byte sizes
