"""CPU time per scan of the whole pipeline on the synthetic suites: for comparing two trees
on a shared machine.

Wall-time medians swing by 2-3x when other processes share the cores; the process's own
CPU time (``time.process_time``, one thread) moves far less. Each scan of the LMS200 suite
(``lms200``) and of the RGB-D suite (``rgbd_vga``) runs once untimed, then ``--repeats``
timed rounds; printed: the median over scans of each scan's median, and their sum (ms).

Usage: PYTHONPATH=<tree> python scripts/bench_cpu.py [--repeats 10] [--suite lms200] [--per-scan]
(``--per-scan`` also prints each scan's median and names the slowest)
(run it alternately on the two trees being compared, several times each)
"""

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402


def cpu_medians(pipeline, scans, repeats: int) -> list[float]:
    """Per scan, the median CPU seconds of ``repeats`` runs (one untimed run first)."""
    for scan in scans:
        pipeline.run(scan.cloud)
    times = [[] for _ in scans]
    for _ in range(repeats):
        for i, scan in enumerate(scans):
            start = time.process_time()
            pipeline.run(scan.cloud)
            times[i].append(time.process_time() - start)
    return [statistics.median(t) for t in times]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--suite", choices=("lms200", "rgbd_vga"), action="append",
                        help="only this suite (repeatable); default both")
    parser.add_argument("--per-scan", action="store_true", help="print every scan's median too")
    args = parser.parse_args()
    import cv2

    cv2.setNumThreads(1)
    import rangeseg_o3d as rs
    from rangeseg_o3d.synthetic.suite import lms200_suite, rgbd_suite

    suites = {"lms200": lms200_suite, "rgbd_vga": rgbd_suite}
    for preset in args.suite or suites:
        suite = suites[preset](seed=0)
        ms = [1000 * t for t in cpu_medians(rs.Pipeline(preset), [scan for _, scan in suite], args.repeats)]
        slowest = max(range(len(ms)), key=ms.__getitem__)
        print(f"{preset}: {len(ms)} scans, CPU ms per scan median {statistics.median(ms):.2f}, "
              f"sum {sum(ms):.1f}, slowest {suite[slowest][0]} {ms[slowest]:.2f} (medians of {args.repeats} runs)")
        if args.per_scan:
            print("  " + ", ".join(f"{name} {t:.2f}" for (name, _), t in zip(suite, ms)))


if __name__ == "__main__":
    main()
