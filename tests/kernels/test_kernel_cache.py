"""The compiled kernels load for every user: a cache folder is always found, and the
kernels compiled into the installation are reused (see rangeseg_o3d/kernels/cache.py)."""

from __future__ import annotations

import ast
import os
import shutil
import tempfile
from pathlib import Path

import pytest
from unprivileged import run_as_nobody, world_reachable

from rangeseg_o3d.kernels import cache as kernel_cache
from rangeseg_o3d.kernels.cache import KernelCacheLocator, _seed

ROOT = Path(__file__).resolve().parents[2]

SNIPPET = """
import warnings, numpy as np
warnings.simplefilter("always")
from rangeseg_o3d.kernels import group_by_label
from rangeseg_o3d.kernels.cache import kernel_cache_dir
order, starts = group_by_label(np.array([2, 1, 2], np.int32), 3)
print("ok", order.tolist(), kernel_cache_dir(str(__import__("pathlib").Path(
    __import__("rangeseg_o3d.kernels.grid").kernels.grid.__file__).parent)))
"""


def test_seed_copies_new_and_newer_files_only(tmp_path):
    source, target = tmp_path / "installed", tmp_path / "user"
    source.mkdir(), target.mkdir()
    (source / "grid.f-1.py311.nbi").write_bytes(b"index")
    (source / "grid.f-1.py311.1.nbc").write_bytes(b"code")
    (source / "grid.py").write_text("not a kernel file")
    assert _seed(source, target) == 2
    assert sorted(p.name for p in target.iterdir()) == ["grid.f-1.py311.1.nbc", "grid.f-1.py311.nbi"]
    assert _seed(source, target) == 0  # up to date
    os.utime(source / "grid.f-1.py311.nbi", (2e9, 2e9))  # recompiled in the installation since
    assert _seed(source, target) == 1
    assert _seed(tmp_path / "missing", target) == 0


def test_locator_is_first_and_only_for_this_package():
    from numba.core import caching

    import rangeseg_o3d.kernels.jit  # noqa: F401  installs the locator

    assert caching.CacheImpl._locator_classes[0] is KernelCacheLocator

    def outside():
        return 1

    assert KernelCacheLocator.from_function(outside, __file__) is None


def _tree_reachable():
    if not world_reachable(ROOT / "rangeseg_o3d" / "kernels" / "grid.py"):
        pytest.skip(f"{ROOT} is not readable by other users")


def test_unprivileged_user_without_home_gets_a_temporary_cache_and_one_warning():
    _tree_reachable()
    done = run_as_nobody(["-c", SNIPPET], pythonpath=[str(ROOT)], cwd="/")
    assert done.returncode == 0, done.stderr
    assert "ok [1, 0, 2]" in done.stdout
    assert f"{tempfile.gettempdir()}/rangeseg_o3d-65534/" in done.stdout
    assert done.stderr.count("no writable cache folder") == 1, done.stderr
    assert "Traceback" not in done.stderr


def test_unprivileged_user_with_a_cache_dir_uses_it_seeded_from_the_installation():
    _tree_reachable()
    import rangeseg_o3d.kernels.grid as grid

    installed = Path(grid.__file__).parent / "__pycache__"
    if not any(installed.glob("grid.*.nbi")):
        pytest.skip("no kernels compiled into this tree yet")
    # taken before the run: with the suite on every core, another worker may compile a
    # new specialisation into the installation while this one seeds its copy
    before = {p.name for p in installed.glob("grid.*.nb[ic]")}
    folder = Path(tempfile.mkdtemp(prefix="rangeseg-cache-"))
    try:
        os.chmod(folder, 0o777)
        done = run_as_nobody(["-c", SNIPPET], pythonpath=[str(ROOT)], cwd="/",
                             extra_env={"RANGESEG_CACHE_DIR": str(folder)})
        assert done.returncode == 0, done.stderr
        assert "no writable cache folder" not in done.stderr
        (used,) = folder.glob("kernels_*")  # one folder per module folder, named after it
        assert str(used) in done.stdout
        assert before <= {p.name for p in used.iterdir()}
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def test_unwritable_numba_cache_dir_is_named_in_the_warning():
    _tree_reachable()
    done = run_as_nobody(["-c", SNIPPET], pythonpath=[str(ROOT)], cwd="/",
                         extra_env={"NUMBA_CACHE_DIR": "/proc/forbidden"})
    assert done.returncode == 0, done.stderr
    assert "NUMBA_CACHE_DIR=/proc/forbidden is not writable" in done.stderr
    assert "Traceback" not in done.stderr


def test_module_documents_every_candidate():
    doc = kernel_cache.__doc__
    for name in ("NUMBA_CACHE_DIR", "__pycache__", "RANGESEG_CACHE_DIR", "XDG_CACHE_HOME", "rangeseg_o3d-<uid>"):
        assert name in doc


def test_a_kernel_stamp_follows_the_files_it_names_as_dependencies(tmp_path):
    # numba checks a cached kernel against its own file; one that compiles another file's
    # kernels into itself (fitting._trimmed) names it in CACHE_DEPENDS, and an edit there
    # changes its stamp (by content: a rewrite with the same text does not)
    own, other = tmp_path / "mod.py", tmp_path / "dep.py"
    own.write_text("x = 1\n")
    other.write_text("y = 1\n")
    namespace = {"CACHE_DEPENDS": ("dep.py",)}
    exec(compile("def kernel():\n    return 1\n", str(own), "exec"), namespace)
    locator = KernelCacheLocator(namespace["kernel"], str(own))
    before = locator.get_source_stamp()
    other.write_text("y = 1\n")
    assert KernelCacheLocator(namespace["kernel"], str(own)).get_source_stamp() == before
    other.write_text("y = 2\n")
    after = KernelCacheLocator(namespace["kernel"], str(own)).get_source_stamp()
    assert after != before and after[0] == before[0]
    # a kernel without dependencies keeps numba's own stamp
    plain = {}
    exec(compile("def kernel():\n    return 1\n", str(own), "exec"), plain)
    assert KernelCacheLocator(plain["kernel"], str(own)).get_source_stamp() == before[0]


def _compiled_in(path: Path) -> set[Path]:
    """The package files whose code or constants numba compiles into ``path``'s kernels: the
    modules it imports from (relative imports at module level), and theirs, transitively;
    the cache machinery (jit.py, cache.py) and packages' __init__ files are not compiled in."""
    package = ROOT / "rangeseg_o3d"
    found: set[Path] = set()
    todo = [path]
    while todo:
        module = todo.pop()
        for node in ast.parse(module.read_text()).body:
            if not isinstance(node, ast.ImportFrom) or not node.level:
                continue
            base = module.parent
            for _ in range(node.level - 1):
                base = base.parent
            target = base.joinpath(*node.module.split(".")).with_suffix(".py") if node.module else None
            if target is None or not target.is_file() or target.name in ("jit.py", "cache.py"):
                continue
            if target.resolve().is_relative_to(package) and target.resolve() not in found:
                found.add(target.resolve())
                todo.append(target)
    return found


def _compiling_modules() -> list[Path]:
    package = ROOT / "rangeseg_o3d"
    return sorted(p for p in package.rglob("*.py") if "jit import njit" in p.read_text())


def test_every_compiled_module_names_the_files_it_compiles_in():
    # numba checks a cached kernel against its own file only: a module whose kernels call
    # another file's kernels or read its constants must name that file in CACHE_DEPENDS,
    # or after an edit there (a git pull) it would keep running the old code from its cache
    import importlib

    modules = _compiling_modules()
    assert len(modules) >= 10  # kernels/* and fitting/_compiled, _decide, _trimmed
    missing = {}
    for path in modules:
        name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        declared = {(path.parent / d).resolve() for d in getattr(importlib.import_module(name), "CACHE_DEPENDS", ())}
        assert all(d.is_file() for d in declared), f"{name} names a file that does not exist"
        lacking = _compiled_in(path) - declared
        if lacking:
            missing[name] = sorted(str(d.relative_to(ROOT)) for d in lacking)
    assert not missing, f"CACHE_DEPENDS lacks: {missing}"


def test_the_dependency_finder_follows_imports_transitively():
    from rangeseg_o3d.fitting import _trimmed

    deps = _compiled_in(Path(_trimmed.__file__))
    names = {d.name for d in deps}
    # _trimmed imports _decide, which imports kernels.labelwise, which imports kernels.grid
    assert {"_decide.py", "_compiled.py", "labelwise.py", "grid.py", "inline.py", "kinds.py"} <= names
    assert "jit.py" not in names and "cache.py" not in names
