"""Where numba keeps this package's compiled kernels, for every user of an installation.

numba's own choice (``cache=True``) is the ``__pycache__`` beside each module, else a
per-user folder under ``~/.cache/numba``, else it refuses to import the module ("cannot
cache function ...: no locator available"). For an installation shared between users that
means: an unprivileged user without a writable home crashes before segmenting, and every
other user recompiles for about a minute although the compiled code already sits beside
the package. :class:`KernelCacheLocator`, put first in numba's list of locators for the
files of this package only, picks the first folder it can write:

1. ``$NUMBA_CACHE_DIR/<module folder>_<hash>`` when that variable is set (numba's meaning);
2. the ``__pycache__`` beside the module (a source checkout, or an installation the user owns);
3. ``$RANGESEG_CACHE_DIR``, else ``$XDG_CACHE_HOME/rangeseg_o3d``, else
   ``~/.cache/rangeseg_o3d`` (each under ``<module folder>_<hash>``);
4. ``<temp dir>/rangeseg_o3d-<uid>`` (kept until the system clears it), with one warning.

Folders 1, 3 and 4 are first seeded with the kernels already compiled into the package's
``__pycache__`` (at install time or by the user who owns it): numba cannot load from a
folder it cannot write, so they are copied, a few MB once, instead of recompiled. numba
checks each entry against the module's source (a content hash) and this CPU, so a copy
from another machine or version is simply recompiled. If no folder at all is writable,
numba's own locators decide (and the import fails as numba's does).
"""

from __future__ import annotations

import functools
import logging
import os
import shutil
import tempfile
import warnings
from pathlib import Path

from numba.core import caching
from numba.core import config as numba_config

__all__ = ["KernelCacheLocator", "install_kernel_cache", "kernel_cache_dir"]

log = logging.getLogger(__name__)

PACKAGE = Path(__file__).resolve().parent.parent  # rangeseg_o3d: its kernels and its fits


def _writable(folder: Path) -> bool:
    """Create ``folder`` if needed and check that a file can be written in it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


def _user_cache_root() -> Path:
    explicit = os.environ.get("RANGESEG_CACHE_DIR")
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "rangeseg_o3d"


def _seed(source: Path, target: Path) -> int:
    """Copy the compiled kernels of ``source`` (a __pycache__) that ``target`` lacks or has older.

    Each file is copied under a temporary name and renamed, so a process reading ``target``
    at the same time sees a whole file or none. Returns the number of files copied.
    """
    copied = 0
    try:
        entries = [p for p in source.iterdir() if p.suffix in (".nbi", ".nbc")]
    except OSError:
        return 0
    for entry in entries:
        destination = target / entry.name
        try:
            if destination.exists() and destination.stat().st_mtime >= entry.stat().st_mtime:
                continue
            partial = destination.with_name(f"{destination.name}.{os.getpid()}.part")
            shutil.copyfile(entry, partial)
            os.replace(partial, destination)
            copied += 1
        except OSError:
            continue
    return copied


@functools.lru_cache(maxsize=None)
def _warn_once(message: str) -> None:
    warnings.warn(message, RuntimeWarning, stacklevel=3)


@functools.lru_cache(maxsize=None)
def kernel_cache_dir(module_dir: str) -> str | None:
    """The folder numba caches the kernels of the modules in ``module_dir`` in (see the module doc).

    Chosen once per folder and process; None when no candidate is writable.
    """
    source = Path(module_dir)
    in_tree = source / "__pycache__"
    subpath = caching._CacheLocator.get_suitable_cache_subpath(str(source / "x.py"))
    if numba_config.CACHE_DIR:
        target = Path(numba_config.CACHE_DIR) / subpath
        if _writable(target):
            _seed(in_tree, target)
            return str(target)
        _warn_once(f"NUMBA_CACHE_DIR={numba_config.CACHE_DIR} is not writable; rangeseg_o3d "
                   "caches its compiled kernels elsewhere (see the README, 'Compiled kernels: where the cache lives')")
    if _writable(in_tree):
        return str(in_tree)
    target = _user_cache_root() / subpath
    if _writable(target):
        copied = _seed(in_tree, target)
        log.info("numba kernels of %s cached in %s (%d compiled files taken from the installation)",
                 source, target, copied)
        return str(target)
    try:
        temp_root = Path(tempfile.gettempdir()) / f"rangeseg_o3d-{os.getuid()}"
    except (OSError, FileNotFoundError):
        return None
    target = temp_root / subpath
    if not _writable(target):
        return None
    _seed(in_tree, target)
    _warn_once(f"no writable cache folder for rangeseg_o3d's compiled kernels (the installation, "
               f"{_user_cache_root()} and NUMBA_CACHE_DIR are not writable); using {temp_root}, "
               "which the system may clear. Set RANGESEG_CACHE_DIR to a writable folder to keep them.")
    return str(target)


class KernelCacheLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
    """numba cache locator for this package's modules: see the module docstring."""

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._cache_path = kernel_cache_dir(os.path.dirname(os.path.abspath(py_file)))
        folder = os.path.dirname(os.path.abspath(py_file))
        self._depends = [os.path.normpath(os.path.join(folder, name))
                         for name in py_func.__globals__.get("CACHE_DEPENDS", ())]

    def get_cache_path(self):
        return self._cache_path

    def get_source_stamp(self):
        """The module's stamp, and those of the files it names in ``CACHE_DEPENDS``.

        numba checks a cached kernel against its own file only; a module whose kernels
        compile others' code into themselves (``fitting._trimmed`` holds the whole
        decision) lists those files, so that editing them recompiles it too.
        """
        own = super().get_source_stamp()
        if not self._depends:
            return own
        stamps = [own]
        for path in self._depends:  # by content, as numba's own (a wheel's installed copies match)
            st = os.stat(path)
            stamps.append(caching._hash_source_file(path, st.st_mtime, st.st_size))
        return tuple(stamps)

    @classmethod
    def from_function(cls, py_func, py_file):
        try:
            inside = Path(py_file).resolve().is_relative_to(PACKAGE)
        except OSError:
            return None
        if not inside or kernel_cache_dir(os.path.dirname(os.path.abspath(py_file))) is None:
            return None  # not ours, or nothing writable: numba's own locators decide
        return super().from_function(py_func, py_file)


def install_kernel_cache() -> None:
    """Put :class:`KernelCacheLocator` first in numba's locator list (once; idempotent).

    Called by :mod:`.jit` on import, before any kernel module's decorators run (a kernel's
    cache is set up when its module is executed).
    """
    locators = caching.CacheImpl._locator_classes
    if KernelCacheLocator not in locators:
        locators.insert(0, KernelCacheLocator)
