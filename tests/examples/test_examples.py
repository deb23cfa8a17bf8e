"""Every script in examples/ runs headless and does what its docstring says."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # (files holding a slow test run first: tests/conftest.py)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
REPO = EXAMPLES.parent


def _run(script: str, *args, cwd: Path) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    done = subprocess.run([sys.executable, str(EXAMPLES / script), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def test_every_example_is_tested():
    scripts = {p.name for p in EXAMPLES.glob("*.py")}
    assert scripts == {"segment_lms200_scan.py", "segment_depth_frame_open3d.py", "log_to_rerun.py",
                       "custom_segmenter_plugin.py"}
    for path in EXAMPLES.glob("*.py"):
        assert 'if __name__ == "__main__":' in path.read_text(), path.name


def test_segment_lms200_scan(tmp_path):
    out = _run("segment_lms200_scan.py", cwd=tmp_path).splitlines()
    assert out[0].startswith("70 x 131 scan: ")
    kinds = {line.split()[1] for line in out[1:]}
    assert {"plane", "cylinder", "sphere"} <= kinds  # the default scene has all three


def test_segment_depth_frame_writes_ply_and_png_without_a_display(tmp_path):
    pytest.importorskip("open3d")
    out = _run("segment_depth_frame_open3d.py", "--out", "frame", cwd=tmp_path)
    assert "640 x 480 depth frame" in out and "no window" in out
    header = (tmp_path / "frame" / "regions.ply").read_bytes()[:400].decode("ascii", "replace")
    vertices = int(header.split("element vertex ")[1].split()[0])
    assert vertices > 100_000  # most of the 307200 pixels are valid
    assert (tmp_path / "frame" / "panel.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_log_to_rerun_writes_a_recording(tmp_path):
    pytest.importorskip("rerun")
    out = _run("log_to_rerun.py", "--out", "rec/scan.rrd", "--scans", "2", cwd=tmp_path)
    assert "scan 1:" in out
    recording = tmp_path / "rec" / "scan.rrd"
    assert recording.stat().st_size > 10_000


def test_custom_segmenter_plugin(tmp_path):
    out = _run("custom_segmenter_plugin.py", cwd=tmp_path)
    assert "range_bands" in out.splitlines()[0]
    assert "fitted" in out and "a bad parameter is refused" in out and "band" in out.splitlines()[-1]
