"""The wheel as a user gets it: built with the sdist, installed into a fresh virtual environment,
run from another directory -- as this user and, when the tests run as root, as ``nobody``
without a writable home (scripts/wheel_install.py does the work and prints its figures).

Slow (the wheel's build compiles the kernels into it): about one to a few minutes; it still
runs in the default ``pytest`` command.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

pytestmark = pytest.mark.slow


def test_wheel_installs_and_runs_from_another_directory_for_every_user():
    pytest.importorskip("build", reason="the test extra installs 'build'")
    command = [sys.executable, str(ROOT / "scripts" / "wheel_install.py")]
    unprivileged = os.geteuid() == 0 and shutil.which("setpriv") is not None
    if unprivileged:
        command.append("--unprivileged")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(command, capture_output=True, text=True, timeout=3000, env=env)
    print(done.stdout)
    assert done.returncode == 0, done.stdout + done.stderr
    out = done.stdout
    assert "both carry the" in out and "presets" in out
    assert out.count("first result in") >= 2
    # the wheel carries the kernels compiled at its build (setup.py), for this machine:
    # the first process after the install loads them and compiles nothing
    carried = int(out.split("the wheel carries ", 1)[1].split()[0])
    assert carried > 0
    first = next(line for line in out.splitlines() if line.startswith("first process after install"))
    assert "numba compiled 0 functions" in first, first
    assert "as this user: rangeseg demo in" in out and "planes," in out
    assert "as this user: rangeseg segment demo/scan.npz --out result.json: ok" in out
    if unprivileged:
        if "nobody: skipped" in out:  # the dependencies of this environment are private to root
            pytest.skip(next(line for line in out.splitlines() if line.startswith("nobody: skipped")))
        assert "nobody, HOME=/nonexistent: rangeseg demo in" in out
