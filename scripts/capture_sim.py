"""Time simulated captures over ptys (default scene, 70 rows) and check them against a fault-free one.

Prints, per fault rate: the wall time of ``rangeseg capture --simulate --faults RATE
--time-scale T --out x.npz`` run as a command (median of ``--repeats``, each a fresh
process, so interpreter start and imports are included), and whether every row of the
captured ranges equals the fault-free capture's (same seed: same scene, same noise).

    python scripts/capture_sim.py [--faults 0.01 0.03] [--time-scale 0.05] [--repeats 3] [--rows 70]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rangeseg_o3d import OrganizedCloud


def capture_once(out: Path, faults: float, time_scale: float, rows: int, seed: int) -> float:
    """Run the command line once; returns its wall time in seconds."""
    command = [sys.executable, "-m", "rangeseg_o3d.cli", "capture", "--simulate", "--faults", str(faults),
               "--time-scale", str(time_scale), "--rows", str(rows), "--seed", str(seed), "--out", str(out)]
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=dict(os.environ))
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"capture failed ({done.returncode}): {done.stderr.strip()}")
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=70)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--faults", type=float, nargs="+", default=[0.01, 0.03])
    parser.add_argument("--time-scale", type=float, default=0.05)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        clean_path = folder / "clean.npz"
        clean_time = capture_once(clean_path, 0.0, args.time_scale, args.rows, args.seed)
        clean = OrganizedCloud.load(clean_path)
        print(f"faults=0.000: {clean_time:.1f} s, {clean.shape[0]} x {clean.shape[1]} (reference)")
        for rate in args.faults:
            times, equal_rows = [], []
            for k in range(args.repeats):
                path = folder / f"faults_{rate}_{k}.npz"
                times.append(capture_once(path, rate, args.time_scale, args.rows, args.seed))
                cloud = OrganizedCloud.load(path)
                same = [np.array_equal(a, b, equal_nan=True) for a, b in zip(cloud.ranges, clean.ranges)]
                equal_rows.append(sum(same) if cloud.shape == clean.shape else 0)
                for row in np.flatnonzero(~np.asarray(same)):  # say how a differing row differs
                    tilt, reference = cloud.geometry.tilt_angles[row], clean.geometry.tilt_angles[row]
                    values = int((~np.isclose(cloud.ranges[row], clean.ranges[row], equal_nan=True)).sum())
                    print(f"  run {k}: row {row} differs in {values} values; tilt {tilt:.7f} "
                          f"(fault-free {reference:.7f})")
            print(f"faults={rate:.3f} time_scale={args.time_scale}: median {statistics.median(times):.1f} s "
                  f"(runs: {', '.join(f'{t:.1f}' for t in times)} s); rows equal to the fault-free "
                  f"capture: {', '.join(f'{n}/{clean.shape[0]}' for n in equal_rows)}")


if __name__ == "__main__":
    main()
