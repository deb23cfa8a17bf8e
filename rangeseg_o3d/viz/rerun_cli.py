"""Command-line flags for rerun output, without importing rerun until it is needed.

The flags are those of ``rerun.script_add_args`` in rerun-sdk 0.41 (``--headless``,
``--connect``, ``--serve``, ``--url``, ``--save``, ``--stdout``; same names, same
destinations) plus ``--spawn`` (0.41's script helpers spawn a viewer whenever no other
flag is given; we spawn only when asked) and ``--png``. They are declared here rather
than by calling ``rr.script_add_args`` so that building the parser, and every run
without a rerun flag, stays free of the rerun import.

The ``.rrd`` of ``--save`` is written to a temporary file next to it and moved into place
by :func:`finish_recording`, so a crashed run never leaves a truncated recording.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import time
import weakref
from pathlib import Path

__all__ = [
    "RERUN_FLAGS",
    "add_rerun_arguments",
    "wants_recording",
    "recording_from_args",
    "finish_recording",
]

log = logging.getLogger(__name__)

#: Destinations whose presence asks for a recording (``--headless`` and ``--png`` do not).
RERUN_FLAGS = ("save", "connect", "serve", "spawn", "stdout", "url")

# rec -> (temporary path, final path) of a pending --save.
_PENDING_SAVES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def add_rerun_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the rerun output flags and ``--png`` to ``parser``.

    Parameters
    ----------
    parser : argparse.ArgumentParser

    Returns
    -------
    argparse.ArgumentParser
        ``parser``, for chaining.
    """
    if not isinstance(parser, argparse.ArgumentParser):
        raise TypeError(f"parser must be an argparse.ArgumentParser; got {type(parser).__name__}")
    group = parser.add_argument_group("rerun output (nothing is logged without one of these)")
    group.add_argument("--save", type=str, default=None, metavar="FILE.rrd",
                       help="save the recording to this .rrd file")
    group.add_argument("--connect", action="store_true",
                       help="stream to a running rerun viewer (see --url)")
    group.add_argument("--url", type=str, default=None,
                       help="rerun gRPC URL for --connect (default: the local viewer)")
    group.add_argument("--serve", action="store_true",
                       help="host a gRPC and web server and open a web viewer; runs until Ctrl-C")
    group.add_argument("--spawn", action="store_true", help="start a rerun viewer and stream to it")
    group.add_argument("--stdout", action="store_true",
                       help="write the recording to standard output, to pipe into `rerun -`")
    group.add_argument("--headless", action="store_true",
                       help="accepted for compatibility with rerun scripts; no viewer is "
                            "started unless --spawn is given")
    group.add_argument("--light", action="store_true",
                       help="log no intermediate images (residual, closed, edges): a smaller recording")
    group.add_argument("--png", type=str, default=None, metavar="FILE.png",
                       help="write range, residual, edges and labels side by side to this PNG")
    return parser


def wants_recording(args: argparse.Namespace) -> bool:
    """True when ``args`` asks for rerun output."""
    return any(getattr(args, flag, None) for flag in RERUN_FLAGS)


def _temporary_rrd(final: Path) -> Path:
    directory = final.parent if str(final.parent) else Path(".")
    if not directory.is_dir():
        raise ValueError(f"--save needs an existing directory; {directory} does not exist")
    fd, name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".tmp", dir=directory)
    os.close(fd)
    return Path(name)


def recording_from_args(args: argparse.Namespace, application_id: str = "rangeseg"):
    """A rerun recording set up as ``args`` ask, or None when no rerun flag was given.

    Sinks combine: ``--save run.rrd --spawn`` both writes the file and streams to a new
    viewer. ``--stdout`` cannot be combined with the others.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed with :func:`add_rerun_arguments`.
    application_id : str

    Returns
    -------
    rerun.RecordingStream or None
        None (and rerun not imported) when no rerun flag was given.

    Raises
    ------
    ValueError
        For ``--stdout`` with another sink, ``--serve`` with ``--spawn``, or a ``--save``
        path whose directory is missing.
    """
    if not wants_recording(args):
        return None
    others = [flag for flag in RERUN_FLAGS if flag != "stdout" and getattr(args, flag, None)]
    if getattr(args, "stdout", False) and others:
        raise ValueError(f"--stdout cannot be combined with --{', --'.join(others)}")
    if getattr(args, "serve", False) and getattr(args, "spawn", False):
        # Both would bind rerun's default gRPC port; --serve already opens a viewer.
        raise ValueError("--serve cannot be combined with --spawn (both use port 9876)")
    import rerun as rr

    rec = rr.RecordingStream(application_id)
    if args.stdout:
        rec.stdout()
        return rec
    sinks = []
    if args.save:
        final = Path(args.save)
        temporary = _temporary_rrd(final)
        sinks.append(rr.FileSink(str(temporary)))
        _PENDING_SAVES[rec] = (temporary, final)
    if args.connect or args.url:
        sinks.append(rr.GrpcSink(args.url))
    if args.spawn:
        rr.spawn(connect=False)
        if not (args.connect or args.url):
            sinks.append(rr.GrpcSink())
    server = None
    if args.serve:
        server = rr.GrpcServerSink()
        sinks.append(server)
    rec.set_sinks(*sinks)
    if server is not None:
        rr.serve_web_viewer(open_browser=True, connect_to=server.uri)
    return rec


def finish_recording(args: argparse.Namespace, rec) -> Path | None:
    """Flush ``rec``, close its sinks and move a ``--save`` file into place.

    With ``--serve`` this blocks until Ctrl-C so that the web viewer can keep reading.

    Parameters
    ----------
    args : argparse.Namespace
    rec : rerun.RecordingStream or None
        What :func:`recording_from_args` returned; None does nothing.

    Returns
    -------
    pathlib.Path or None
        The saved ``.rrd``, if ``--save`` was given.
    """
    if rec is None:
        return None
    rec.flush()
    if getattr(args, "serve", False):
        print("serving the recording to the web viewer; Ctrl-C to stop", file=sys.stderr)
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
    rec.disconnect()
    pending = _PENDING_SAVES.pop(rec, None)
    if pending is None:
        return None
    temporary, final = pending
    # mkstemp made the file 0600; give it the permissions a plain open() would.
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(temporary, 0o666 & ~umask)
    os.replace(temporary, final)
    log.info("saved rerun recording %s", final)
    return final
