#!/usr/bin/env bash
# Idempotent set-up for a fresh Debian machine (Python >= 3.10): Debian's libusb-1.0-0
# (Open3D's wheel does not import without it), a virtual environment in .venv, and the
# package with its test extras installed editable. Safe to run again: it skips what is done.
set -euo pipefail
cd "$(dirname "$0")/.."

need_apt=()
if ! { ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; }; then
    need_apt+=(libusb-1.0-0)
fi
if ! python3 -c 'import venv, ensurepip' >/dev/null 2>&1; then
    need_apt+=(python3-venv)
fi
if [ ${#need_apt[@]} -gt 0 ]; then
    if [ "$(id -u)" -ne 0 ]; then
        echo "bootstrap: please install ${need_apt[*]} (apt-get needs root)" >&2
        exit 1
    fi
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi

if [ ! -x .venv/bin/python ]; then
    python3 -m venv .venv
fi
stamp=.venv/.rangeseg-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[test]"
    touch "$stamp"
fi
# numba compiles the kernels on first use and caches them beside the package: do it now,
# once, rather than in the middle of the first scan.
if ! ls rangeseg_o3d/kernels/__pycache__/*.nbi >/dev/null 2>&1; then
    echo "bootstrap: compiling the numba kernels (first time only: 2-3 minutes on an idle 2-core machine, longer under load)" >&2
    # (two processes: the laser scan's kernels and the depth frame's compile side by side)
    .venv/bin/python -c 'from rangeseg_o3d.pipeline import warm_up; print(f"bootstrap: compiled in {warm_up(processes=2):.0f} s")' >&2
fi
