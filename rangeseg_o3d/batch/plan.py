"""Planning a batch before any work: inputs, their output files, and checks on both.

Every problem that would otherwise surface after minutes of segmenting (a missing or
read-only output folder, ``--out x.json`` for two inputs, two inputs writing one file)
is found here and raised as one ValueError.

Each output kind (``json``, ``labels``, ``ply``, ``panel``: :data:`.task.OUTPUT_WRITERS`)
goes to a place: a file (one input, the place's suffix is the kind's) or a folder, where
input ``k`` writes ``<folder>/<name_k><suffix>`` (names from :func:`.inputs.output_names`).
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from .inputs import expand_inputs, output_names
from .task import OUTPUT_SUFFIXES, OUTPUT_WRITERS, InputTask

__all__ = ["BatchPlan", "plan_tasks", "prepare_outputs"]


@dataclass(frozen=True)
class BatchPlan:
    """The tasks of a batch and where they write.

    folder : the ``out`` folder (the summary table goes there), or None.
    folders : every output folder (created by :func:`prepare_outputs`).
    """

    tasks: list
    folder: Path | None = None
    folders: list = field(default_factory=list)


def _check_writable(folder: Path) -> None:
    # os.access says yes to root on a read-only mount: try a real file instead.
    try:
        with tempfile.TemporaryFile(dir=folder, prefix=".rangeseg-probe-"):
            pass
    except OSError as exc:
        raise ValueError(f"output folder {folder} is not writable ({exc.strerror})") from None


def _existing_folder(folder: Path, what: str) -> None:
    if not folder.exists():
        raise ValueError(f"the folder of {what} does not exist: {folder}")
    if not folder.is_dir():
        raise ValueError(f"the folder of {what} is not a folder: {folder}")


def _places(out, outputs, targets) -> list[tuple[tuple[str, ...], Path, bool]]:
    """``(kinds, place, is_file)`` for ``out`` and each target."""
    for kind in (*outputs, *(targets or {})):
        if kind not in OUTPUT_WRITERS:
            raise ValueError(f"unknown output kind {kind!r}; known: {', '.join(OUTPUT_WRITERS)}")
    places = []
    if out is not None:
        out = Path(out)
        by_suffix = {OUTPUT_SUFFIXES[k]: k for k in outputs}
        kind = by_suffix.get(out.suffix.lower())
        if kind is not None and not out.is_dir():
            places.append(((kind,), out, True))
        else:
            places.append((tuple(outputs), out, False))
    for kind, place in (targets or {}).items():
        if place is None:
            continue
        place = Path(place)
        is_file = place.suffix.lower() == OUTPUT_SUFFIXES[kind] and not place.is_dir()
        places.append(((kind,), place, is_file))
    return places


def plan_tasks(specs, *, out=None, outputs=("json",), targets: dict | None = None) -> BatchPlan:
    """The batch's tasks: one per input file, with its output files.

    Parameters
    ----------
    specs : files, folders and glob patterns (see :func:`.inputs.expand_inputs`).
    out : None, an output folder for the ``outputs`` kinds, or - for one input - a file
        whose suffix is one of theirs (``x.json``).
    outputs : the kinds written into ``out``.
    targets : ``{kind: file or folder}`` for further kinds (``labels``, ``ply``, ``panel``).

    Raises
    ------
    ValueError
        No input, an unknown output kind, a file place for several inputs, or two
        outputs in one file.
    """
    places = _places(out, outputs, targets)
    paths = expand_inputs(specs, skip=[place for _, place, is_file in places if not is_file])
    if not paths:
        raise ValueError("no input given")
    for kinds, place, is_file in places:
        if is_file and len(paths) > 1:
            option = "--out" if out is not None and place == Path(out) else f"the {kinds[0]} output"
            raise ValueError(f"{option} {place} names one file but {len(paths)} inputs were given; "
                             "give a folder for several inputs")
    names = output_names(paths)
    tasks, seen = [], {}
    for index, (path, name) in enumerate(zip(paths, names)):
        files = []
        for kinds, place, is_file in places:
            files.extend((kind, str(place if is_file else place / f"{name}{OUTPUT_SUFFIXES[kind]}"))
                         for kind in kinds)
        for _, target in files:
            key = os.path.normcase(os.path.abspath(target))
            if key in seen:  # output names are distinct: only places given twice get here
                raise ValueError(f"{path} and {seen[key]} would both write {target}")
            seen[key] = path
        tasks.append(InputTask(index=index, path=str(path), name=name, outputs=tuple(files)))
    folders = [place for _, place, is_file in places if not is_file]
    out_folder = Path(out) if out is not None and not places[0][2] else None
    return BatchPlan(tasks, out_folder, folders)


def prepare_outputs(plan: BatchPlan) -> None:
    """Check the output places and create the output folders, before any work.

    A single output file's folder must exist; an output folder is created if its parent
    exists (a mistyped parent is an error, not a new tree). Every folder written to is
    checked by creating a file in it. Sub-folders for names such as ``a/scan`` are made
    when their file is written.

    Raises
    ------
    ValueError
        A folder is missing, cannot be created or written, or an output path is a folder.
    """
    roots = list(dict.fromkeys(plan.folders))
    files = {Path(target) for task in plan.tasks for _, target in task.outputs
             if not any(root in Path(target).parents for root in roots)}
    for root in roots:
        if root.exists() and not root.is_dir():
            raise ValueError(f"output folder {root} exists and is not a folder")
        _existing_folder(root.parent, f"output folder {root}")
    for target in sorted(files):
        if target.is_dir():
            raise ValueError(f"output {target} is a folder")
        _existing_folder(target.parent, f"output file {target}")
    for root in roots:
        try:
            root.mkdir(exist_ok=True)
        except OSError as exc:
            raise ValueError(f"cannot create output folder {root} ({exc.strerror})") from None
    for folder in dict.fromkeys([*roots, *(t.parent for t in sorted(files))]):
        _check_writable(folder)
