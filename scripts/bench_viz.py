"""Median times of the viz stages: log_scan to an in-memory recording, and the PNG panel.

    python scripts/bench_viz.py [--repeats 7]

Scans: the synthetic default LMS200 scene (70 x 131) and the first RGB-D suite frame
(480 x 640), segmented once with their presets; only the viz calls are timed.
"""

from __future__ import annotations

import argparse
from _timing import median_seconds  # scripts/_timing.py (scripts/ is on sys.path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()

    import rerun as rr

    from rangeseg_o3d.pipeline import Pipeline
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene, rgbd_suite
    from rangeseg_o3d.viz import log_scan, render_panel

    scans = [
        ("lms200 70x131", simulate_lms200(default_scene(), seed=0).cloud, "lms200"),
        ("rgbd 480x640", rgbd_suite()[0][1].cloud, "rgbd_vga"),
    ]
    for name, cloud, preset in scans:
        result = Pipeline(preset).run(cloud)
        rec = rr.RecordingStream("bench")
        memory = rec.memory_recording()
        counter = iter(range(10**6))

        sizes = {}

        def log_once(light=False):
            log_scan(rec, cloud, result, scan_index=next(counter), light=light)
            rec.flush()
            sizes[light] = len(memory.drain_as_bytes())  # keep memory flat across repeats

        t_log = median_seconds(log_once, args.repeats)
        t_light = median_seconds(lambda: log_once(True), args.repeats)
        t_panel = median_seconds(lambda: render_panel(cloud, result), args.repeats)
        print(f"{name}: {cloud.n_valid} valid points, {len(result.features)} features | "
              f"log_scan {t_log * 1e3:.1f} ms, {sizes[False] / 1e6:.2f} MB per scan | light "
              f"{t_light * 1e3:.1f} ms, {sizes[True] / 1e6:.2f} MB | render_panel "
              f"{t_panel * 1e3:.1f} ms (median of {args.repeats}; the first scan of a recording "
              "also carries the static context and blueprint)")


if __name__ == "__main__":
    main()
