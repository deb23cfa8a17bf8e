"""Which files a batch reads, and the output name each one gets.

Inputs are given as files, directories (searched recursively for the known scan
suffixes) and glob patterns. Output names are derived from the inputs' paths so that
no two inputs ever share one: the path relative to the inputs' common folder, without
its suffix unless two inputs differ only by it (``room.npz`` and ``room.pcd`` become
``room.npz`` and ``room.pcd``, ``a/scan.npz`` and ``b/scan.npz`` become ``a/scan`` and
``b/scan``). The rule depends on the set of inputs only, so it is deterministic.
"""

from __future__ import annotations

import glob
import logging
import os
from pathlib import Path, PurePosixPath

from ..io.files import require_regular_file

__all__ = ["LOADERS", "input_suffixes", "is_bag_folder", "expand_inputs", "output_names",
           "check_regular_file", "load_scan"]

log = logging.getLogger(__name__)

#: Further readers by suffix, "module:function" (imported when used), tried before
#: :func:`rangeseg_o3d.io.readers.load_input`, which knows the formats the package reads.
LOADERS: dict[str, str] = {}


def input_suffixes() -> tuple[str, ...]:
    """The suffixes a folder is searched for: every format a reader takes."""
    from ..io.readers import INPUT_SUFFIXES

    return tuple(dict.fromkeys([*INPUT_SUFFIXES, *LOADERS]))


def is_bag_folder(path) -> bool:
    """A ROS 2 bag is a folder (``metadata.yaml`` and its storage files): one input."""
    return os.path.isdir(path) and os.path.isfile(os.path.join(path, "metadata.yaml"))


def check_regular_file(path) -> None:
    """Raise unless ``path`` is a regular file (checked with ``stat``, never opened).

    Raises
    ------
    FileNotFoundError
        If nothing is at ``path``.
    ValueError
        If ``path`` is a FIFO, a device, a socket or a directory (other than a ROS 2 bag):
        opening a FIFO or a terminal would wait for a writer forever.
    """
    if is_bag_folder(path):
        return
    require_regular_file(path)


def load_scan(path, **options):
    """Read one scan: :data:`LOADERS` by suffix, else :func:`rangeseg_o3d.io.readers.load_input`.

    The path is checked with :func:`check_regular_file` before anything opens it.
    ``options`` (``units``, ``intrinsics``, ``depth_scale`` ...) go to the reader.
    """
    import importlib

    path = Path(path)
    check_regular_file(path)
    loader = LOADERS.get(path.suffix.lower())
    if loader is None:
        from ..io.readers import load_input

        return load_input(path, **options)
    module, function = loader.split(":")
    return getattr(importlib.import_module(module), function)(path, **options)


def _scan_directory(folder: Path, skip: set) -> list[Path]:
    suffixes = input_suffixes()
    found = []
    for root, dirs, files in os.walk(folder):
        bags = [d for d in dirs if is_bag_folder(os.path.join(root, d))]
        # a deterministic walk that leaves out the output folders and enters no bag
        dirs[:] = sorted(d for d in dirs if d not in bags
                         and os.path.realpath(os.path.join(root, d)) not in skip)
        found.extend(Path(root) / name for name in sorted([*files, *bags])
                     if name in bags or Path(name).suffix.lower() in suffixes)
    return found


def expand_inputs(specs, *, skip=()) -> list[Path]:
    """Turn files, directories and glob patterns into a list of input files.

    A directory gives every file under it with a known suffix (sorted) and every ROS 2
    bag folder, but nothing under the folders in ``skip`` (the outputs); a glob pattern
    (``*``, ``?``, ``[``; ``**`` recursive) gives its matches, sorted; anything else is
    taken as a file name as it is (a missing one fails later, as that input's error).
    The same file named twice is read once.

    Raises
    ------
    ValueError
        If a directory holds no scan or a pattern matches nothing.
    """
    skip = {os.path.realpath(folder) for folder in skip}
    paths: list[Path] = []
    for spec in specs:
        spec = os.fspath(spec)
        if glob.has_magic(spec) and not os.path.exists(spec):
            matches = [Path(m) for m in sorted(glob.glob(spec, recursive=True))]
            files = [m for m in matches if not m.is_dir()]  # folders: their scans
            for folder in (m for m in matches if m.is_dir() and not is_bag_folder(m)):
                files.extend(_scan_directory(folder, skip))
            files.extend(m for m in matches if is_bag_folder(m))
            if not files:
                raise ValueError(f"pattern {spec!r} matches no file")
            paths.extend(files)
        elif os.path.isdir(spec) and not is_bag_folder(spec):
            files = _scan_directory(Path(spec), skip)
            if not files:
                raise ValueError(f"directory {spec} holds no {'/'.join(input_suffixes())} file")
            paths.extend(files)
        else:
            paths.append(Path(spec))
    unique, seen = [], set()
    for path in paths:
        key = os.path.realpath(path)
        if key in seen:
            log.warning("%s is given twice; it is read once", path)
            continue
        seen.add(key)
        unique.append(path)
    return unique


def _inside(path: str, folder: str) -> bool:
    return os.path.commonpath([path, folder]) == folder


def output_names(paths) -> list[str]:
    """A distinct output name (a relative POSIX path, no suffix added) per input.

    Each name is the input's path relative to the deepest folder that holds all inputs
    (that exist), with the suffix dropped unless that would make two names equal.

    Examples
    --------
    >>> output_names(["a/scan.npz", "b/scan.npz"])
    ['a/scan', 'b/scan']
    >>> output_names(["x/room.npz", "x/room.pcd", "x/hall.pcd"])
    ['room.npz', 'room.pcd', 'hall']
    """
    absolute = [os.path.abspath(p) for p in paths]
    if not absolute:
        return []
    # The common folder of the inputs that are there: a missing or special file (which
    # fails anyway) must not move every other input's output.
    present = [p for p in absolute if os.path.isfile(p) or is_bag_folder(p)] or absolute
    root = os.path.commonpath([os.path.dirname(p) for p in present])
    relative = [PurePosixPath(*Path(os.path.relpath(p, root) if _inside(p, root)
                                    else os.path.basename(p)).parts) for p in absolute]
    stems = [str(r.with_suffix("")) if r.suffix else str(r) for r in relative]
    counts: dict[str, int] = {}
    for stem in stems:
        key = stem.casefold()  # distinct on case-insensitive file systems too
        counts[key] = counts.get(key, 0) + 1
    names = [stem if counts[stem.casefold()] == 1 else str(rel) for stem, rel in zip(stems, relative)]
    if len({n.casefold() for n in names}) != len(names):  # e.g. "a.npz" and "a.npz.npz"
        names = [f"{name}.{i}" for i, name in enumerate(names)]
    return names
