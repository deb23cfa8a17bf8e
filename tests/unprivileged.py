"""Run a Python snippet or command as the unprivileged user ``nobody`` with no writable home.

Needs root (to drop privileges with ``setpriv``), an interpreter every user may execute and
this tree's dependencies readable by every user; :func:`nobody_python` skips the calling
test, saying which of these is missing, when one is.
"""

from __future__ import annotations

import os
import shutil
import site
import stat
import subprocess
import sys
from pathlib import Path

import pytest

NOBODY = "65534"  # nobody / nogroup on Debian


def world_reachable(path: Path, *, execute: bool = False) -> bool:
    """Every directory above ``path`` is searchable by others and ``path`` readable (executable)."""
    path = Path(os.path.realpath(path))
    for parent in path.parents:
        if not os.stat(parent).st_mode & stat.S_IXOTH:
            return False
    mode = os.stat(path).st_mode
    return bool(mode & (stat.S_IXOTH if execute else stat.S_IROTH))


def runnable_interpreter() -> str | None:
    """This interpreter's base, or the system's of the same version, if every user may run it."""
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    for candidate in (getattr(sys, "_base_executable", sys.executable), f"/usr/bin/python{version}"):
        if candidate and Path(candidate).exists() and world_reachable(Path(candidate), execute=True):
            return candidate
    return None


def nobody_python() -> tuple[list[str], list[str]]:
    """(command prefix dropping to nobody, PYTHONPATH entries for this tree's dependencies)."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("running as another user needs root and setpriv")
    python = runnable_interpreter()
    if python is None:
        pytest.skip("no Python interpreter of this version that every user may execute")
    packages = [p for p in site.getsitepackages() if Path(p).is_dir()]
    if not all(world_reachable(Path(p)) for p in packages):
        pytest.skip(f"the dependencies in {packages} are not readable by other users")
    prefix = ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups",
              "env", "-i", "HOME=/nonexistent", "PATH=/usr/bin:/bin"]
    return prefix + [python], packages


def run_as_nobody(args: list[str], *, extra_env: dict[str, str] | None = None, cwd=None,
                  pythonpath: list[str] = (), timeout: float = 900) -> subprocess.CompletedProcess:
    """``python args...`` as nobody, with ``pythonpath`` then the dependencies on the path."""
    prefix, packages = nobody_python()
    env = [f"{k}={v}" for k, v in (extra_env or {}).items()]
    env.append("PYTHONPATH=" + os.pathsep.join([*pythonpath, *packages]))
    *setpriv, python = prefix
    return subprocess.run([*setpriv, *env, python, *args], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout)
