"""Keep the memory a frame frees in the process, so the next frame does not page-fault it back.

A pipeline run allocates whole-frame temporaries (a 640 x 480 frame: 1-7 MB each) and frees
them when it returns. glibc's malloc adapts its thresholds to the blocks it sees freed and,
after a few frames, hands those blocks back to the system at the end of each run: every
later run then takes a page fault for each 4 KiB page it writes (pcl/office1 after three
other frames: ~2400 faults, 4-5 ms of a 40 ms run on the 2-core test machine;
docs/benchmarks.md, "Why office1 depends on what ran before it"). Fixing the two thresholds
once (glibc's ``mallopt``) stops the adaptation: blocks up to :data:`MMAP_THRESHOLD_BYTES`
come from the heap, and the heap keeps up to :data:`TRIM_THRESHOLD_BYTES` free at its top.

:class:`rangeseg_o3d.pipeline.Pipeline` calls :func:`keep_freed_memory` when it first runs
on a frame of at least :data:`LARGE_FRAME_PIXELS` pixels (``Pipeline(..., keep_memory=False)``
never does): a smaller scan's whole-frame float64 arrays stay under glibc's smallest mmap
threshold (128 KiB), always come from the heap and are not page-faulted again, so a process
that only segments small scans keeps glibc's settings as they were. It does nothing on a C library other than
glibc, nor when the process was started with glibc's own malloc settings in its
environment (``MALLOC_TRIM_THRESHOLD_``, ``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TOP_PAD_`` or
a ``glibc.malloc`` tunable): the user's choice wins, e.g. a Dask worker's deliberate
``MALLOC_TRIM_THRESHOLD_=65536``.
"""

from __future__ import annotations

import ctypes
import os

__all__ = ["LARGE_FRAME_PIXELS", "MMAP_THRESHOLD_BYTES", "TRIM_THRESHOLD_BYTES", "keep_freed_memory",
           "large_frame"]

#: A frame of this many pixels has float64 whole-frame arrays of glibc's default (and
#: smallest) mmap threshold, 128 KiB: from there on its temporaries can leave the process.
LARGE_FRAME_PIXELS = (128 << 10) // 8

#: Blocks below this come from the heap, not from a mapping of their own that free()
#: unmaps. 32 MiB is the largest value glibc accepts on 64-bit systems; a 1280 x 720
#: frame's float64 points take 22 MB.
MMAP_THRESHOLD_BYTES = 32 << 20
#: Free memory the heap keeps at its top before handing it back to the system: the
#: process keeps its peak heap up to this much (a VGA run's temporaries take ~10-40 MB).
TRIM_THRESHOLD_BYTES = 256 << 20

# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

# environment variables through which glibc reads malloc settings at start-up
_GLIBC_MALLOC_ENV = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TOP_PAD_")

_applied = False


def _glibc_mallopt():
    """glibc's ``mallopt`` function, or None on another C library."""
    try:
        if not os.confstr("CS_GNU_LIBC_VERSION"):
            return None
    except (AttributeError, ValueError, OSError):  # no confstr or no such name: not glibc
        return None
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return mallopt


def _user_settings() -> bool:
    # glibc settings the process was started with (they are read before Python runs)
    if any(name in os.environ for name in _GLIBC_MALLOC_ENV):
        return True
    return "glibc.malloc" in os.environ.get("GLIBC_TUNABLES", "")


def large_frame(shape: tuple[int, int]) -> bool:
    """Whether a ``shape`` frame's whole-frame float64 arrays reach glibc's default mmap
    threshold (:data:`LARGE_FRAME_PIXELS`): the frames :func:`keep_freed_memory` is for."""
    return int(shape[0]) * int(shape[1]) >= LARGE_FRAME_PIXELS


def keep_freed_memory() -> bool:
    """Fix glibc's malloc thresholds so that freed frame-sized blocks stay in the process.

    Process-wide and idempotent (the second call does nothing). Returns True when the
    thresholds are set (now or by an earlier call), False when nothing was done: not glibc,
    the environment already sets glibc's malloc, or glibc refused a value.
    """
    global _applied
    if _applied:
        return True
    if _user_settings():
        return False
    mallopt = _glibc_mallopt()
    if mallopt is None:
        return False
    # mallopt returns 1 on success; either setting also stops glibc's adaptation
    _applied = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                    & mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    return _applied
