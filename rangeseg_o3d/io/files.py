"""Checks on an input path before anything reads it."""

from __future__ import annotations

import stat
from pathlib import Path

__all__ = ["require_regular_file"]


def require_regular_file(path) -> Path:
    """``path`` if it is a regular file (or a link to one).

    Raises
    ------
    FileNotFoundError
        Nothing is there (or a dangling / looping link).
    ValueError
        It is a directory, a FIFO, a device or a socket: reading a FIFO or a terminal
        would block until someone writes to it, and a device such as /dev/zero never ends.
    """
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise FileNotFoundError(f"no such file: {path}") from None
    except OSError as err:  # a link loop, a name too long, no permission on a folder
        raise ValueError(f"{path}: cannot be read ({err.strerror or err})") from None
    if stat.S_ISREG(mode):
        return path
    raise ValueError(f"{path} is {_special_file_kind(mode)}, not a regular file")


def _special_file_kind(mode: int) -> str:
    """What a ``stat`` mode that is not a regular file names: 'a FIFO', 'a directory' ..."""
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"
