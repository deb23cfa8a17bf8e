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
    kind = ("a directory" if stat.S_ISDIR(mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "not a regular file")
    raise ValueError(f"{path} is {kind}, not a scan file")
