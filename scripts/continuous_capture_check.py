"""Continuous sweeps on the simulated rig, on a prompt and on a slow host: rows kept of scans sent, tilt errors.

The simulated LMS writes into every range the tilt it measured the scan at (4 m + 4 x tilt, read
back to 0.25 mrad), so each row's tilt error is known. A slow host spends ``--slow`` device seconds
around each tilt query of the sweep (two a loop turn). Per case it prints the rows kept of the scans
the LMS streamed, the rows inside the sweep against what its duration and the stream's beat give,
and the median and largest |tilt error| over the repeats.

    python scripts/continuous_capture_check.py [--time-scale 0.05 0.5] [--slow 0 0.1] [--repeats 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rangeseg_o3d.acquisition import CaptureConfig
from rangeseg_o3d.acquisition.capture import capture_continuous, initialise, open_devices
from rangeseg_o3d.acquisition.sim.powercube import ramp_profile
from rangeseg_o3d.acquisition.sim.rig import SimulatedRig
from rangeseg_o3d.acquisition.simulate import simulation_config

START, STOP, VELOCITY, ACCELERATION, BAUD = -0.3, 0.2, 0.5, 1.0, 38400
MOUNT = (0.0, 0.0, 0.1)
MARGIN = 1e-3  # rad: rows this far inside both ends count as inside the sweep


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


def sweep(time_scale: float, slow: float) -> tuple[int, int, int, np.ndarray]:
    """(rows kept, scans streamed, rows inside the sweep, |tilt error| per row) of one sweep."""
    config = CaptureConfig.model_validate({
        "schedule": {"start": START, "stop": STOP}, "mount": {"offset": MOUNT}, "mode": "continuous",
        "continuous_velocity": VELOCITY, "tilt": {"acceleration": ACCELERATION}, "lms": {"baudrate": BAUD}})
    rig = SimulatedRig(row_ranges=tilt_in_ranges, time_scale=time_scale, noise=0.0, mount_offset=MOUNT)
    sent = []
    tick = rig.lms.tick

    def counted():  # the streamed scans, counted where the simulator sends them
        out = tick()
        sent.extend(out)
        return out

    rig.lms.tick = counted
    with rig:
        sim = simulation_config(config, lms_port=rig.lms_port, tilt_port=rig.tilt_port, time_scale=time_scale)
        lms, tilt = open_devices(sim)
        try:
            initialise(lms, tilt, sim)
            cloud = capture_continuous(lms, SlowHost(tilt, slow * time_scale), sim)
        finally:
            lms.close()
            tilt.close()
    truth = (np.median(cloud.ranges, axis=1) - 4.0) / 4.0
    inside = int(np.count_nonzero((truth > START + MARGIN) & (truth < STOP - MARGIN)))
    return cloud.shape[0], len(sent), inside, np.abs(cloud.geometry.tilt_angles - truth)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--time-scale", type=float, nargs="+", default=[0.05, 0.5])
    parser.add_argument("--slow", type=float, nargs="+", default=[0.0, 0.1], help="device s per tilt query")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"expected inside the sweep: {scans_inside():.1f} rows")
    for time_scale in args.time_scale:
        for slow in args.slow:
            kept, sent, inside, errors = [], [], [], []
            for _ in range(args.repeats):
                k, s, i, e = sweep(time_scale, slow)
                kept.append(k), sent.append(s), inside.append(i), errors.append(e)
            errors = np.concatenate(errors)
            print(f"time scale {time_scale}, slow {slow * 1000:.0f} ms/query: rows kept/sent "
                  f"{'/'.join(map(str, kept))} of {'/'.join(map(str, sent))}, inside {'/'.join(map(str, inside))}, "
                  f"|tilt error| median {np.median(errors) * 1e3:.2f} max {errors.max() * 1e3:.2f} mrad")


if __name__ == "__main__":
    main()
