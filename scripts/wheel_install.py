"""Build the sdist and wheel, install the wheel into a fresh virtual environment, use it as a new user would.

Steps, each printed with its figures:

1. ``python -m build`` without kernels (the sdist, then a wheel from the sdist), then
   ``python -m build --wheel`` from the tree, the wheel installed next: all must carry the
   presets, and both wheels the same files. Building the tree's wheel compiles the numba
   kernels into it (setup.py; it takes those the checkout compiled after its last edit, as
   ``scripts/bootstrap.sh`` leaves a fresh clone, and compiles the rest): the step says how
   long and how many compiled kernels the wheel carries.
2. A fresh venv from an interpreter every user may run; the wheel installed with
   ``pip --no-deps``; the dependencies are those of the interpreter running this script
   (a ``.pth`` file), so nothing is downloaded but the build's own requirements (setuptools,
   and for the wheel what compiling the kernels imports: build_support/rangeseg_build.py).
3. From another directory, as the installing user: the time to a first result (a saved
   LMS200 scan loaded and segmented) in the first process after the install (numba loads the
   kernels compiled into the wheel, or compiles those it needs when they do not fit this
   machine) and in the next process, then ``rangeseg demo`` and ``rangeseg segment`` on the demo's scan.
4. With ``--unprivileged`` (needs root): the same as ``nobody`` with ``HOME=/nonexistent``:
   the time to a first result (kernels taken from the installation) and ``rangeseg demo``.

Exit status 0 when every step worked. Times are wall seconds with CPU seconds beside them
(on a shared machine the wall time depends on the load, the CPU time much less).

    python scripts/wheel_install.py [--unprivileged] [--no-precompile] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import shutil
import site
import stat
import subprocess
import sys
import tarfile
import tempfile
import time
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
NOBODY = "65534"

# A user's first result: a saved scan loaded and segmented (simulating the scene is not part of
# it: the simulator alone takes about 0.5 s of ray casting).
FIRST_RESULT = """
import sys, time
start, cpu = time.perf_counter(), time.process_time()
from numba.core import event
import rangeseg_o3d as rs
with event.install_recorder("numba:compile") as compiled:
    result = rs.Pipeline("lms200").run(rs.OrganizedCloud.load(sys.argv[1]))
functions = sum(1 for _, e in compiled.buffer if e.is_start)
print(f"{time.perf_counter() - start:.2f} {time.process_time() - cpu:.2f} {len(result.features)} {functions} {rs.__file__}")
"""


class StepFailed(SystemExit):
    pass


def run(command, *, cwd=None, env=None, timeout=1800, prefix=()) -> subprocess.CompletedProcess:
    done = subprocess.run([*prefix, *map(str, command)], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)
    if done.returncode != 0 or "Traceback" in done.stderr:
        raise StepFailed(f"FAILED ({done.returncode}): {' '.join(map(str, command))}\n{done.stdout[-2000:]}\n"
                         f"{done.stderr[-4000:]}")
    return done


def world_reachable(path: Path, *, execute: bool = False) -> bool:
    path = Path(os.path.realpath(path))
    if any(not os.stat(parent).st_mode & stat.S_IXOTH for parent in path.parents):
        return False
    return bool(os.stat(path).st_mode & (stat.S_IXOTH if execute else stat.S_IROTH))


def base_interpreter() -> str:
    """This interpreter's base, or the system's of the same version if only that one is runnable by all."""
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    candidates = [getattr(sys, "_base_executable", sys.executable), f"/usr/bin/python{version}"]
    for candidate in candidates:
        if Path(candidate).exists() and world_reachable(Path(candidate), execute=True):
            return candidate
    return candidates[0]


def clean_env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CACHE_DIR", "RANGESEG_CACHE_DIR",
                                                              "RANGESEG_NO_PRECOMPILE")}
    env.update(extra)
    return env


def _names(wheel: Path) -> set[str]:
    with zipfile.ZipFile(wheel) as archive:
        return {n for n in archive.namelist() if "/__pycache__/" not in n and ".dist-info/RECORD" not in n}


def build(dist: Path, precompile: bool = True) -> tuple[Path, Path]:
    """The sdist and a wheel built from it (without kernels), then the wheel to install, from the tree."""
    start = time.perf_counter()
    run([sys.executable, "-m", "build", "--outdir", dist / "from-sdist", ROOT],
        env=clean_env(RANGESEG_NO_PRECOMPILE="1"), timeout=1800)
    (sdist,) = (dist / "from-sdist").glob("*.tar.gz")
    (from_sdist,) = (dist / "from-sdist").glob("*.whl")
    sdist_time = time.perf_counter() - start
    start = time.perf_counter()
    env = clean_env() if precompile else clean_env(RANGESEG_NO_PRECOMPILE="1")
    done = run([sys.executable, "-m", "build", "--wheel", "--outdir", dist, ROOT], env=env, timeout=1800)
    (wheel,) = dist.glob("*.whl")
    if _names(from_sdist) != _names(wheel):
        raise StepFailed(f"FAILED: the wheel built from the sdist differs from the tree's in "
                         f"{sorted(_names(from_sdist) ^ _names(wheel))[:20]}")
    presets = sorted(p.name for p in (ROOT / "configs").glob("*.yaml"))
    with tarfile.open(sdist) as archive:
        in_sdist = sorted(Path(n).name for n in archive.getnames() if "/configs/" in n and n.endswith(".yaml"))
    with zipfile.ZipFile(wheel) as archive:
        in_wheel = sorted(Path(n).name for n in archive.namelist() if n.startswith("rangeseg_o3d/configs/"))
        kernels = sum(1 for n in archive.namelist() if n.endswith(".nbi"))
    if not precompile and kernels:
        raise StepFailed(f"FAILED: a wheel built with RANGESEG_NO_PRECOMPILE=1 carries {kernels} compiled kernels")
    if in_sdist != presets or in_wheel != presets:
        raise StepFailed(f"FAILED: presets {presets}; sdist has {in_sdist}, wheel has {in_wheel}")
    seeded = [line for line in done.stdout.splitlines() if "compiled kernel files in the wheel" in line]
    print(f"build: sdist and a wheel from it (no kernels) in {sdist_time:.1f} s; both carry the {len(presets)} "
          f"presets and the same files as the tree's wheel")
    print(f"build: the wheel from the tree in {time.perf_counter() - start:.1f} s; the wheel carries {kernels} "
          f"compiled kernels{' (' + seeded[-1].split(' (', 1)[1] if seeded else ''}")
    return sdist, wheel


def install(wheel: Path, venv: Path) -> Path:
    run([base_interpreter(), "-m", "venv", "--without-pip", venv])
    python = venv / "bin" / "python"
    purelib = run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip()
    dependencies = [p for p in site.getsitepackages() if Path(p).is_dir()]
    Path(purelib, "_rangeseg_dependencies.pth").write_text("\n".join(dependencies) + "\n")
    run([sys.executable, "-m", "pip", "--python", python, "install", "--quiet", "--no-deps", "--no-index", wheel])
    print(f"install: {wheel.name} into {venv} (base {base_interpreter()}; dependencies from {dependencies})")
    return python


def save_scan(path: Path) -> Path:
    """The demo's simulated LMS200 scan, written by this interpreter for the timed processes."""
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    simulate_lms200(default_scene(), seed=0).cloud.save(path)
    os.chmod(path, 0o644)
    return path


def first_result(python: Path, scan: Path, cwd: Path, label: str, prefix=(), env=None) -> None:
    done = run([python, "-c", FIRST_RESULT, str(scan)], cwd=cwd, prefix=prefix, env=env)
    wall, cpu, features, functions, where = done.stdout.split()
    if not where.startswith(str(python.parent.parent)):
        raise StepFailed(f"FAILED: imported {where}, not the installed package")
    warnings = [line for line in done.stderr.splitlines() if "Warning:" in line]
    warned = f" (warned: {warnings[0].split('Warning: ', 1)[1][:200]})" if warnings else ""
    print(f"{label}: first result in {wall} s wall, {cpu} s CPU ({features} features; numba compiled "
          f"{functions} functions){warned}")


def demo_and_segment(venv: Path, cwd: Path, label: str, prefix=(), env=None, segment=True) -> None:
    rangeseg = venv / "bin" / "rangeseg"
    start = time.perf_counter()
    done = run([rangeseg, "demo", "--out", "demo"], cwd=cwd, prefix=prefix, env=env)
    planes = [line for line in done.stdout.splitlines() if "planes," in line]
    print(f"{label}: rangeseg demo in {time.perf_counter() - start:.1f} s: {planes[-1] if planes else '?'}")
    if segment:
        done = run([rangeseg, "segment", "demo/scan.npz", "--config", "lms200", "--out", "result.json"],
                   cwd=cwd, prefix=prefix, env=env)
        if not (cwd / "result.json").is_file():
            raise StepFailed("FAILED: rangeseg segment wrote no result.json")
        print(f"{label}: rangeseg segment demo/scan.npz --out result.json: ok")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--unprivileged", action="store_true", help="also run as nobody without a home (root only)")
    parser.add_argument("--no-precompile", action="store_true",
                        help="build the wheel without compiled kernels (as one built on another CPU): "
                             "the first process compiles")
    parser.add_argument("--keep", help="work in this folder and keep it (default: a temporary folder)")
    args = parser.parse_args()
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="rangeseg-wheel-"))
    work.mkdir(parents=True, exist_ok=True)
    os.chmod(work, 0o755)  # the unprivileged user must reach the venv
    try:
        _, wheel = build(work / "dist", precompile=not args.no_precompile)
        python = install(wheel, work / "venv")
        elsewhere = work / "run"
        elsewhere.mkdir(exist_ok=True)
        env = clean_env()
        scan = save_scan(work / "scan.npz")
        first_result(python, scan, elsewhere, "first process after install")
        first_result(python, scan, elsewhere, "next process")
        demo_and_segment(work / "venv", elsewhere, "as this user", env=env)
        dependencies = [p for p in site.getsitepackages() if Path(p).is_dir()]
        hidden = [p for p in dependencies if not world_reachable(Path(p))]
        if args.unprivileged and hidden:
            # e.g. a checkout under /root: nobody cannot import numpy from there; not the package's fault
            print(f"nobody: skipped (the dependencies in {hidden} are not readable by other users)")
        elif args.unprivileged:
            if os.geteuid() != 0 or shutil.which("setpriv") is None:
                raise StepFailed("FAILED: --unprivileged needs root and setpriv")
            shared = work / "nobody"
            shared.mkdir(exist_ok=True)
            os.chmod(shared, 0o777)
            prefix = ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups",
                      "env", "-i", "HOME=/nonexistent", "PATH=/usr/bin:/bin"]
            first_result(python, scan, shared, "nobody, HOME=/nonexistent", prefix=prefix)
            demo_and_segment(work / "venv", shared, "nobody, HOME=/nonexistent", prefix=prefix, segment=False)
    except StepFailed as failed:
        print(failed.code, file=sys.stderr)
        sys.exit(1)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
