import subprocess
import sys


def test_importing_io_stays_cheap():
    """rangeseg_o3d.io and its datasets module load no open3d, OpenCV or SciPy."""
    code = (
        "import sys, rangeseg_o3d.io, rangeseg_o3d.io.datasets, rangeseg_o3d.io.open3d_conv; "
        "print(sorted(m for m in ('open3d', 'cv2', 'scipy', 'rerun', 'serial') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
