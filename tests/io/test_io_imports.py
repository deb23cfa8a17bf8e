import subprocess
import sys


def test_importing_io_adds_no_heavy_modules():
    """rangeseg_o3d.io, .datasets and .open3d_conv import open3d, OpenCV and SciPy lazily."""
    code = (
        "import sys, rangeseg_o3d\n"
        "heavy = ('open3d', 'cv2', 'scipy', 'rerun', 'serial')\n"
        "before = {m for m in heavy if m in sys.modules}\n"
        "import rangeseg_o3d.io, rangeseg_o3d.io.datasets, rangeseg_o3d.io.open3d_conv\n"
        "print(sorted({m for m in heavy if m in sys.modules} - before))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
