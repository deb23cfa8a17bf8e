"""``rangeseg capture``: capture a nodding scan from hardware or from the simulated rig.

On failure the rows already captured are saved next to ``--out`` as ``<stem>.partial.npz``
and the command exits with status 1.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import tempfile
from pathlib import Path

from .args import finite_float

__all__ = ["add_arguments", "run", "check_output"]

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the capture options to ``parser``."""
    parser.add_argument("--port", help="serial port of the LMS2xx (e.g. /dev/ttyUSB0)")
    parser.add_argument("--tilt-port", help="serial port of the PowerCube tilt unit")
    parser.add_argument("--simulate", action="store_true", help="capture from the built-in simulated rig")
    parser.add_argument("--faults", type=finite_float, default=0.0, help="simulated byte fault rate (0.01 = 1%%)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated faults and noise")
    parser.add_argument("--time-scale", type=finite_float, default=0.01, help="simulated: wall seconds per device second")
    parser.add_argument("--config", help="capture settings YAML (a 'capture:' mapping or the bare settings)")
    parser.add_argument("--baud", type=int, choices=(9600, 19200, 38400, 500000), help="LMS line rate to switch to")
    parser.add_argument("--tilt-baud", type=int, choices=(9600, 19200, 38400), help="PowerCube line rate")
    parser.add_argument("--module-id", type=int, help="PowerCube module id (1..31)")
    parser.add_argument("--rows", type=int, help="number of tilt rows")
    parser.add_argument("--tilt-start", type=finite_float, help="first tilt angle, rad")
    parser.add_argument("--tilt-stop", type=finite_float, help="last tilt angle, rad")
    parser.add_argument("--mode", choices=("stop_and_go", "continuous"), help="capture procedure")
    parser.add_argument("--mount-offset", type=finite_float, nargs=3, metavar=("X", "Y", "Z"),
                        help="mirror centre from the tilt axis, tilting frame, metres")
    parser.add_argument("--tilt-sign", type=int, choices=(-1, 1), help="sign of the unit's angle")
    parser.add_argument("--out", required=True, help="output file (.npz or .pcd), written atomically")


def _config(args):
    from ..acquisition.config import CaptureConfig, load_capture_config

    # Only the fields the file or the command line set: a settings model rebuilt from a full
    # dump would count every field as set, and the simulator would keep the hardware's waits.
    data = load_capture_config(args.config).model_dump(exclude_unset=True)
    overrides = {
        ("lms", "port"): args.port, ("lms", "baudrate"): args.baud,
        ("tilt", "port"): args.tilt_port, ("tilt", "baudrate"): args.tilt_baud, ("tilt", "module_id"): args.module_id,
        ("schedule", "rows"): args.rows, ("schedule", "start"): args.tilt_start, ("schedule", "stop"): args.tilt_stop,
        ("mount", "offset"): tuple(args.mount_offset) if args.mount_offset else None,
        ("mount", "tilt_sign"): args.tilt_sign,
    }
    for (section, key), value in overrides.items():
        if value is not None:
            data.setdefault(section, {})[key] = value
    if args.mode:
        data["mode"] = args.mode
    out = Path(args.out)
    data["partial_path"] = out.with_name(out.stem + ".partial.npz")
    return CaptureConfig.model_validate(data)


def check_output(out: Path) -> None:
    """Refuse an ``--out`` the capture could not be written to, before capturing anything."""
    if out.suffix.lower() not in (".npz", ".pcd"):
        raise ValueError(f"--out {out} must end in .npz or .pcd; got {out.suffix or 'no suffix'!r}")
    if out.is_dir():
        raise ValueError(f"--out {out} is a directory; give a file name")
    folder = out.parent
    if not folder.is_dir():
        raise ValueError(f"--out {out}: folder {folder} does not exist")
    try:
        tempfile.TemporaryFile(dir=folder).close()
    except OSError as err:
        raise ValueError(f"--out {out}: cannot write in {folder} ({err.strerror or err})") from None


def _kept(err: BaseException, config) -> str:
    """Where the rows captured before ``err`` went, for the message."""
    partial = getattr(err, "partial", None)
    kept = partial.n_rows if partial is not None else 0
    if kept and config.partial_path is not None and Path(config.partial_path).is_file():
        return (f"{kept} rows saved to {config.partial_path} "
                "(OrganizedCloud.load or rangeseg segment read it)")
    return "no rows captured" if not kept else f"{kept} rows captured, but saving them failed"


def run(args: argparse.Namespace) -> int:
    """Run a capture; 0 on success, 1 on a device or write error, 2 on bad arguments, 130 on Ctrl-C."""
    from pydantic import ValidationError

    from ..acquisition.capture import CaptureProgress, capture
    from ..acquisition.errors import AcquisitionError
    from ..acquisition.simulate import simulated_capture

    try:
        config = _config(args)
        if not args.simulate and not (args.port and args.tilt_port):
            raise ValueError("give --port and --tilt-port for hardware, or --simulate")
        if not (math.isfinite(args.time_scale) and args.time_scale > 0):
            raise ValueError(f"--time-scale must be a positive number; got {args.time_scale}")
        if not (math.isfinite(args.faults) and 0 <= args.faults < 1):
            raise ValueError(f"--faults must be in [0, 1); got {args.faults}")
        check_output(Path(args.out))
    except (ValueError, ValidationError, OSError) as err:
        print(f"rangeseg capture: {err}", file=sys.stderr)
        return 2
    progress = CaptureProgress(config.schedule.rows)
    try:
        if args.simulate:
            cloud = simulated_capture(config, faults=args.faults, seed=args.seed, time_scale=args.time_scale,
                                      out=args.out, progress=progress)
        else:
            cloud = capture(config, out=args.out, progress=progress)
    except KeyboardInterrupt as err:
        progress.close()
        print(f"rangeseg capture: interrupted; {_kept(err, config)}", file=sys.stderr)
        return 130
    except (AcquisitionError, OSError) as err:
        progress.close()
        print(f"rangeseg capture: {err}; {_kept(err, config)}", file=sys.stderr)
        return 1
    progress.close()
    h, w = cloud.shape
    print(f"captured {h} x {w} ({cloud.n_valid} points) -> {args.out}")
    return 0


def main(argv=None) -> int:
    """``rangeseg capture`` on its own (``python -m rangeseg_o3d.cli.capture``): the exit code of :func:`run`."""
    parser = argparse.ArgumentParser(prog="rangeseg capture", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
