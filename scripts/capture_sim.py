"""Time simulated captures over ptys (default scene) and print medians of repeated runs.

    python scripts/capture_sim.py [--rows 70] [--repeats 3] [--faults 0 0.01]
"""

import argparse
import statistics
import time

from rangeseg_o3d.acquisition import CaptureConfig, simulated_capture


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--rows", type=int, default=70)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--faults", type=float, nargs="+", default=[0.0, 0.01])
    parser.add_argument("--time-scale", type=float, default=0.01)
    args = parser.parse_args()
    config = CaptureConfig.model_validate({"schedule": {"rows": args.rows}})
    for rate in args.faults:
        times = []
        for seed in range(args.repeats):
            start = time.perf_counter()
            cloud = simulated_capture(config, faults=rate, seed=seed, time_scale=args.time_scale)
            times.append(time.perf_counter() - start)
        print(f"faults={rate:.3f} rows={cloud.shape[0]} cols={cloud.shape[1]} time_scale={args.time_scale}: "
              f"median {statistics.median(times):.2f} s per capture ({args.repeats} runs)")


if __name__ == "__main__":
    main()
