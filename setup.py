"""Build hook: a wheel carries the numba kernels compiled for the machine that built it.

Everything else about the package is declared in pyproject.toml. After ``build_py`` has
copied the package into the build folder, :class:`BuildPyWithKernels` runs
``rangeseg_o3d.pipeline.warm_up()`` there in a fresh interpreter of the build environment
(pyproject.toml's ``[build-system] requires`` lists what it imports), so numba writes the
compiled kernels into the package's ``__pycache__`` folders and the wheel carries them. A
user installing that wheel (``pip install .`` builds one on the installing machine) loads
them instead of compiling for about a minute in the first scan. numba checks every entry
against the source's content hash, its own version and this CPU (name and features) and
compiles again whatever does not match, so a wheel built elsewhere is only slower on its
first scan, never wrong. Set ``RANGESEG_NO_PRECOMPILE=1`` to build without (an editable
install never compiles here: ``scripts/bootstrap.sh`` warms the checkout up instead).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

WARM_UP = "from rangeseg_o3d.pipeline import warm_up; warm_up()"


def _compiled_kernels(package: Path) -> list[Path]:
    return [p for p in package.rglob("__pycache__/*") if p.suffix in (".nbi", ".nbc")]


def _seed_from_checkout(source: Path, package: Path) -> int:
    """Copy the kernels the checkout ``source`` has compiled into the build folder ``package``.

    Only when every one of them is newer than every source file of the package (a checkout
    warmed up after its last edit, as ``scripts/bootstrap.sh`` leaves it): a kernel compiled
    before an edit to a callee in another file would pass numba's check of its own file.
    numba still checks each copied kernel against its module's content, numba version and
    CPU, and compiles again what does not match. Returns the number of files copied.
    """
    kernels = _compiled_kernels(source)
    if not kernels or source.resolve() == package.resolve():
        return 0
    newest_source = max(p.stat().st_mtime for p in source.rglob("*.py"))
    if min(p.stat().st_mtime for p in kernels) <= newest_source:
        return 0
    for kernel in kernels:
        target = package / kernel.relative_to(source)
        if target.parent.parent.is_dir():  # the module's folder is part of the wheel
            target.parent.mkdir(exist_ok=True)
            shutil.copy2(kernel, target)
    return len(kernels)


class BuildPyWithKernels(build_py):
    """``build_py``, then the kernels compiled into the build folder (see the module docstring)."""

    def run(self) -> None:
        super().run()
        if self.editable_mode:
            return
        package = Path(self.build_lib) / "rangeseg_o3d"
        # An older build's cache (the build folder of a checkout persists) could hold a kernel
        # compiled against a callee in another file that has changed since (numba checks each
        # kernel against its own file only); a wheel asked for without kernels carries none.
        for stale in _compiled_kernels(package):
            stale.unlink()
        if os.environ.get("RANGESEG_NO_PRECOMPILE"):
            return
        seeded = _seed_from_checkout(Path(__file__).resolve().parent / "rangeseg_o3d", package)
        env = {k: v for k, v in os.environ.items()
               if k not in ("NUMBA_CACHE_DIR", "RANGESEG_CACHE_DIR", "NUMBA_DISABLE_JIT", "PYTHONPATH")}
        env.update(PYTHONPATH=str(Path(self.build_lib).resolve()), PYTHONDONTWRITEBYTECODE="1")
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-c", WARM_UP], cwd=self.build_lib, env=env,
                              capture_output=True, text=True)
        if done.returncode != 0:
            # Not fatal: the wheel is complete without a cache, its first scan compiles.
            print(f"rangeseg_o3d: the numba kernels were not compiled into the wheel "
                  f"(the first scan will compile them):\n{done.stderr[-3000:]}", file=sys.stderr)
            for partial in _compiled_kernels(package):
                partial.unlink()
            return
        print(f"rangeseg_o3d: {len(_compiled_kernels(package))} compiled kernel files in the wheel "
              f"({seeded} taken from the checkout; {time.perf_counter() - start:.0f} s)")


setup(cmdclass={"build_py": BuildPyWithKernels})
