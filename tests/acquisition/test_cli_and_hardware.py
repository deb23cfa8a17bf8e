"""`rangeseg capture` through its module entry points; opt-in hardware tests (--hardware)."""

import argparse
import sys

import numpy as np
import pytest

from rangeseg_o3d import OrganizedCloud
from rangeseg_o3d.cli import capture as cli


def parse(argv):
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    return parser.parse_args(argv)


def test_simulated_capture_writes_a_loadable_file(tmp_path, capsys):
    out = tmp_path / "scan.npz"
    assert cli.run(parse(["--simulate", "--rows", "3", "--seed", "4", "--out", str(out)])) == 0
    cloud = OrganizedCloud.load(out)
    assert cloud.shape == (3, 181) and cloud.timestamps.shape == (3,)
    assert "3 x 181" in capsys.readouterr().out
    assert not list(tmp_path.glob("*.partial.npz"))


def test_hardware_mode_needs_ports(tmp_path, capsys):
    assert cli.run(parse(["--port", "/dev/null", "--out", str(tmp_path / "x.npz")])) == 2
    assert "--tilt-port" in capsys.readouterr().err


def test_bad_setting_is_reported(tmp_path, capsys):
    assert cli.run(parse(["--simulate", "--rows", "0", "--out", str(tmp_path / "x.npz")])) == 2
    assert "rows" in capsys.readouterr().err


def test_import_does_not_load_serial():
    import subprocess

    code = "import sys, rangeseg_o3d.acquisition; print('serial' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.strip() == "False"


@pytest.fixture
def hardware_ports(request):
    if not request.config.getoption("--hardware"):
        pytest.skip("hardware tests need --hardware (and --lms-port / --tilt-port)")
    lms, tilt = request.config.getoption("--lms-port"), request.config.getoption("--tilt-port")
    if not lms:
        pytest.skip("--lms-port not given")
    return lms, tilt


def test_hardware_lms_scan(hardware_ports):
    from rangeseg_o3d.acquisition import Lms2xx

    lms = Lms2xx(hardware_ports[0])
    try:
        lms.initialise(baudrate=38400)
        scan = lms.request_scan()
        assert scan.ranges.shape == (181,) and np.isfinite(scan.ranges).any()
    finally:
        lms.set_mode(0x25)
        lms.close()


def test_hardware_three_row_capture(hardware_ports, tmp_path):
    from rangeseg_o3d.acquisition import CaptureConfig, capture

    lms_port, tilt_port = hardware_ports
    if not tilt_port:
        pytest.skip("--tilt-port not given")
    cfg = CaptureConfig.model_validate({"lms": {"port": lms_port}, "tilt": {"port": tilt_port},
                                        "schedule": {"rows": 3, "start": -0.1, "stop": 0.1}})
    cloud = capture(cfg, out=tmp_path / "hw.npz")
    assert cloud.shape == (3, 181)
