"""Log a segmentation to a rerun recording file (.rrd) and open it later with the rerun viewer.

    python examples/log_to_rerun.py [--out out/scan.rrd]
    rerun out/scan.rrd

Every stage is logged: ``scan/range``, ``scan/residual``, ``scan/closed``, ``scan/edges``,
``scan/labels`` (with region names), ``world/points`` coloured by region,
``world/features/<label>`` and ``timings/<stage>``; three scans of different noise are put
on the ``scan`` timeline.
"""

import argparse
from pathlib import Path

import rerun as rr

import rangeseg_o3d as rs
from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.suite import default_scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/scan.rrd"), help="recording file to write")
    parser.add_argument("--scans", type=int, default=3, help="scans on the timeline")
    args = parser.parse_args()

    args.out.parent.mkdir(parents=True, exist_ok=True)
    recording = rr.RecordingStream("rangeseg_o3d_example")
    recording.save(str(args.out))
    pipeline = rs.Pipeline("lms200")
    for index in range(args.scans):
        scan = simulate_lms200(default_scene(), seed=index)
        result = pipeline.run(scan.cloud, recording=recording, scan_index=index)
        print(f"scan {index}: {len(result.features)} features logged")
    recording.flush()
    print(f"wrote {args.out}; view it with: rerun {args.out}")


if __name__ == "__main__":
    main()
