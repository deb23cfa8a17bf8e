"""``rangeseg capture``: capture a nodding scan from hardware or from the simulated rig.

On failure the rows already captured are saved next to ``--out`` as ``<stem>.partial.npz``
and the command exits with status 1.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from ..cliargs import finite_float

__all__ = ["add_arguments", "run"]

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
    from .config import CaptureConfig, load_capture_config

    data = load_capture_config(args.config).model_dump()
    overrides = {
        ("lms", "port"): args.port, ("lms", "baudrate"): args.baud,
        ("tilt", "port"): args.tilt_port, ("tilt", "baudrate"): args.tilt_baud, ("tilt", "module_id"): args.module_id,
        ("schedule", "rows"): args.rows, ("schedule", "start"): args.tilt_start, ("schedule", "stop"): args.tilt_stop,
        ("mount", "offset"): tuple(args.mount_offset) if args.mount_offset else None,
        ("mount", "tilt_sign"): args.tilt_sign,
    }
    for (section, key), value in overrides.items():
        if value is not None:
            data[section][key] = value
    if args.mode:
        data["mode"] = args.mode
    out = Path(args.out)
    data["partial_path"] = out.with_name(out.stem + ".partial.npz")
    return CaptureConfig.model_validate(data)


def run(args: argparse.Namespace) -> int:
    """Run a capture; 0 on success, 1 on a device error, 2 on bad arguments."""
    from pydantic import ValidationError

    from .capture import capture
    from .errors import AcquisitionError
    from .simulate import simulated_capture

    try:
        config = _config(args)
        if not args.simulate and not (args.port and args.tilt_port):
            raise ValueError("give --port and --tilt-port for hardware, or --simulate")
    except (ValueError, ValidationError, OSError) as err:
        print(f"rangeseg capture: {err}", file=sys.stderr)
        return 2
    try:
        if args.simulate:
            cloud = simulated_capture(config, faults=args.faults, seed=args.seed, time_scale=args.time_scale,
                                      out=args.out)
        else:
            cloud = capture(config, out=args.out)
    except AcquisitionError as err:
        kept = err.partial.n_rows if err.partial is not None else 0
        where = f"; {kept} rows saved to {config.partial_path}" if kept else "; no rows captured"
        print(f"rangeseg capture: {err}{where}", file=sys.stderr)
        return 1
    h, w = cloud.shape
    print(f"captured {h} x {w} ({cloud.n_valid} points) -> {args.out}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="rangeseg capture", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
