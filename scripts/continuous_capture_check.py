"""Continuous sweeps on the simulated rig, on a prompt and on a slow host, on clean or noisy lines: rows kept of scans sent, tilt errors.

The simulated LMS writes into every range the tilt it measured the scan at (4 m + 4 x tilt, read
back to 0.25 mrad), so each row's tilt error is known. A slow host spends ``--slow`` device seconds
around each tilt query of the sweep (two a loop turn). Per case it prints the rows kept of the scans
the LMS streamed, the rows inside the sweep against what its duration and the stream's beat give,
and the median and largest |tilt error| over the repeats.

With ``--faults`` (bytes corrupted or dropped on both lines, the simulators' LineFaults) it also
prints, summed over the repeats: the streamed scans that crossed the line whole (their telegram
passes the CRC), the rows kept, the damaged scans the driver counted (``stats["damaged_scans"]``,
"-" where the driver does not count them) and the sweeps that failed (seed = repeat index).

    python scripts/continuous_capture_check.py [--time-scale 0.05 0.5] [--slow 0 0.1] [--repeats 3] [--faults 0 0.01 0.03]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rangeseg_o3d.acquisition import AcquisitionError, CaptureConfig
from rangeseg_o3d.acquisition.capture import capture_continuous, initialise, open_devices
from rangeseg_o3d.acquisition.sim.powercube import ramp_profile
from rangeseg_o3d.acquisition.sim.rig import SimulatedRig
from rangeseg_o3d.acquisition.simulate import simulation_config

START, STOP, VELOCITY, ACCELERATION, BAUD = -0.3, 0.2, 0.5, 1.0, 38400
MOUNT = (0.0, 0.0, 0.1)
MARGIN = 1e-3  # rad: rows this far inside both ends count as inside the sweep
SCAN_COMMAND = 0xB0


def tilt_in_ranges(tilt, beams):
    return np.full(beams.shape, 4.0 + 4.0 * tilt)


class SlowHost:
    """A tilt unit whose every query of the sweep costs the host ``delay`` wall seconds (half before, half after)."""

    def __init__(self, inner, delay: float):
        self.inner, self.delay = inner, delay

    def __getattr__(self, name):
        query = getattr(self.inner, name)
        if name not in ("state", "read_position", "timed_position") or not self.delay:
            return query

        def slowly(*args, **kwargs):
            time.sleep(self.delay / 2)
            value = query(*args, **kwargs)
            time.sleep(self.delay / 2)
            return value

        return slowly


def scans_inside() -> float:
    duration = ramp_profile(abs(STOP - START), VELOCITY, ACCELERATION, 0.0)[1]
    beat = max(1 / 75, (2 * 181 + 10) * 10 / BAUD)
    return (duration - 2 * np.sqrt(2 * MARGIN / ACCELERATION)) / beat


def count_whole_scans(rig: SimulatedRig, counts: dict) -> None:
    """Count the scans the simulated LMS sends and those its line leaves whole (``counts["sent"]``, ``["whole"]``)."""
    tick, faults = rig.lms.tick, rig.lms_link.faults
    apply = faults.apply

    def counted_tick():  # the streamed scans, counted where the simulator sends them
        out = tick()
        counts["sent"] += len(out)
        return out

    def counted_apply(data):
        out = apply(data)
        if len(data) > 4 and data[0] == 0x02 and data[4] == SCAN_COMMAND and out == data:
            counts["whole"] += 1
        return out

    rig.lms.tick, faults.apply = counted_tick, counted_apply


def sweep(time_scale: float, slow: float, faults: float = 0.0, seed: int = 0):
    """(rows kept, counts, rows inside the sweep, |tilt error| per row, error or None) of one sweep.

    ``counts``: scans streamed ("sent"), scans that crossed the line whole ("whole"), damaged scans
    the driver counted ("damaged", None where it does not count them).
    """
    config = CaptureConfig.model_validate({
        "schedule": {"start": START, "stop": STOP}, "mount": {"offset": MOUNT}, "mode": "continuous",
        "continuous_velocity": VELOCITY, "tilt": {"acceleration": ACCELERATION}, "lms": {"baudrate": BAUD}})
    rig = SimulatedRig(row_ranges=tilt_in_ranges, time_scale=time_scale, noise=0.0, mount_offset=MOUNT,
                       faults=faults, seed=seed)
    counts = {"sent": 0, "whole": 0}
    count_whole_scans(rig, counts)
    error = None
    with rig:
        sim = simulation_config(config, lms_port=rig.lms_port, tilt_port=rig.tilt_port, time_scale=time_scale)
        lms, tilt = open_devices(sim)
        try:
            initialise(lms, tilt, sim)
            counts["whole"] = 0  # scans replying to requests during initialise are not the sweep's
            try:
                cloud = capture_continuous(lms, SlowHost(tilt, slow * time_scale), sim)
            except AcquisitionError as err:
                error, cloud = err, (err.partial.to_cloud() if err.partial is not None else None)
            counts["damaged"] = lms.stats.get("damaged_scans")
        finally:
            lms.close()
            tilt.close()
    if cloud is None:
        return 0, counts, 0, np.zeros(0), error
    truth = (np.median(cloud.ranges, axis=1) - 4.0) / 4.0
    inside = int(np.count_nonzero((truth > START + MARGIN) & (truth < STOP - MARGIN)))
    return cloud.shape[0], counts, inside, np.abs(cloud.geometry.tilt_angles - truth), error


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--time-scale", type=float, nargs="+", default=[0.05, 0.5])
    parser.add_argument("--slow", type=float, nargs="+", default=[0.0, 0.1], help="device s per tilt query")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--faults", type=float, nargs="+", default=[0.0], help="byte fault rate on both lines")
    args = parser.parse_args()
    print(f"expected inside the sweep: {scans_inside():.1f} rows")
    for faults in args.faults:
        for time_scale in args.time_scale:
            for slow in args.slow:
                kept, sent, inside, errors, whole, damaged, failed = [], [], [], [], 0, [], []
                for repeat in range(args.repeats):
                    k, counts, i, e, error = sweep(time_scale, slow, faults, seed=repeat)
                    kept.append(k), sent.append(counts["sent"]), inside.append(i), errors.append(e)
                    whole += counts["whole"]
                    damaged.append(counts["damaged"])
                    if error is not None:
                        failed.append(f"{repeat}: {type(error).__name__}: {error}")
                errors = np.concatenate(errors)
                tilt = (f"|tilt error| median {np.median(errors) * 1e3:.2f} max {errors.max() * 1e3:.2f} mrad"
                        if errors.size else "no rows")
                line = (f"faults {faults}, time scale {time_scale}, slow {slow * 1000:.0f} ms/query: rows kept/sent "
                        f"{'/'.join(map(str, kept))} of {'/'.join(map(str, sent))}, inside "
                        f"{'/'.join(map(str, inside))}, {tilt}")
                if faults:
                    counted = "-" if None in damaged else sum(damaged)
                    line += (f"; sent {sum(sent)}, whole {whole}, kept {sum(kept)}, damaged counted {counted}, "
                             f"failed sweeps {len(failed)}")
                print(line, flush=True)
                for failure in failed:
                    print(f"    failed sweep {failure}", flush=True)


if __name__ == "__main__":
    main()
