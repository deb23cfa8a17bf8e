"""Batch throughput: --jobs 1 vs --jobs N vs a Dask LocalCluster over the same VGA frames.

    python scripts/bench_batch.py [--frames 60] [--repeats 3] [--jobs 2] [--no-dask]

The frames are the three RGB-D suite scenes (rangeseg_o3d.synthetic, 640 x 480), ray-cast
once and written again and again as ``frame_000.npz`` ... (kept in --data for later runs).
Each measurement runs in a fresh Python process (so each pays its kernel loading, as a
real run does) and segments every frame with the ``rgbd_vga`` preset, writing the JSON
results. Printed per engine (medians over the repeats, runs interleaved):

- wall: from the call of run_batch to the last result (worker start-up and kernel loading
  included; the Dask cluster's own start-up is not, it is printed on its own line);
- steady: inputs per second after the first result, (N - 1) / (t_last - t_first), i.e.
  the throughput once the workers are warm;
- CPU s/file: the median CPU time a worker spent per input (process_time: it does not
  grow when other programs take the cores), and cores busy: all inputs' CPU time / wall.

The machine's load average is printed before and after: on a shared machine the figures
move with it. No test asserts on these numbers.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

_MEASURE = r"""
import json, sys, time
from rangeseg_o3d.batch import run_batch, dask_client
frames, out, engine, jobs = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
def measure(client=None):
    start = time.perf_counter()
    stamps, cpu = [], []
    for row in run_batch([frames], config="rgbd_vga", out=out, jobs=jobs, client=client):
        assert row.status == "ok", row.error
        stamps.append(time.perf_counter() - start)
        cpu.append(row.cpu_s)
    return {"wall": stamps[-1], "first": stamps[0], "n": len(stamps),
            "steady": (len(stamps) - 1) / (stamps[-1] - stamps[0]),
            "cpu_per_file": sorted(cpu)[len(cpu) // 2], "cpu_total": sum(cpu)}
if __name__ == "__main__":
    if engine == "dask":
        t0 = time.perf_counter()
        with dask_client("local", workers=jobs) as client:
            cluster_s = time.perf_counter() - t0
            result = measure(client)
        result["cluster_s"] = cluster_s
    else:
        result = measure()
    print(json.dumps(result))
"""


def make_frames(folder: Path, count: int) -> Path:
    """``count`` VGA frames in ``folder`` (the three RGB-D suite scenes, repeated)."""
    folder.mkdir(parents=True, exist_ok=True)
    existing = sorted(folder.glob("frame_*.npz"))
    if len(existing) == count:
        return folder
    for path in existing:
        path.unlink()
    from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
    from rangeseg_o3d.synthetic.suite import rgbd_scenes

    scenes = [simulate_depth_camera(scene, seed=k).cloud for k, (_, scene) in enumerate(rgbd_scenes())]
    for i in range(count):
        scenes[i % len(scenes)].save(folder / f"frame_{i:03d}.npz")
    return folder


def run_once(frames: Path, engine: str, jobs: int) -> dict:
    out = Path(tempfile.mkdtemp(prefix="bench_batch_out_"))
    try:
        env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
        proc = subprocess.run([sys.executable, "-c", _MEASURE, str(frames), str(out), engine, str(jobs)],
                              capture_output=True, text=True, env=env, check=False)
        if proc.returncode != 0:
            raise SystemExit(f"{engine} jobs={jobs} failed:\n{proc.stderr[-3000:]}")
        return json.loads(proc.stdout.strip().splitlines()[-1])
    finally:
        shutil.rmtree(out, ignore_errors=True)


def pickle_sizes(frames: Path) -> tuple[int, int, int]:
    """Pickled bytes of a VGA frame's Result with and without the intermediate images,
    and of a summary row alone."""
    from rangeseg_o3d.batch import run_batch

    first = sorted(frames.glob("frame_*.npz"))[0]
    [full] = run_batch([first], config="rgbd_vga", jobs=1, keep_results=True, keep_stages=True)
    [lean] = run_batch([first], config="rgbd_vga", jobs=1, keep_results=True)
    [row] = run_batch([first], config="rgbd_vga", jobs=1)
    return len(pickle.dumps(full.result)), len(pickle.dumps(lean.result)), len(pickle.dumps(row))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=2, help="workers of the pool and of the cluster")
    parser.add_argument("--no-dask", action="store_true")
    parser.add_argument("--data", default=os.path.join(tempfile.gettempdir(), "rangeseg_bench_batch"),
                        help="where the frames are kept between runs")
    args = parser.parse_args(argv)
    frames = make_frames(Path(args.data), args.frames)
    print(f"load before: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f} "
          f"(1/5/15 min), {os.cpu_count()} cores; {args.frames} VGA frames in {frames}")
    engines = [("pool", 1), ("pool", args.jobs)] + ([] if args.no_dask else [("dask", args.jobs)])
    runs: dict = {e: [] for e in engines}
    for _ in range(args.repeats):
        for engine in engines:
            runs[engine].append(run_once(frames, *engine))
    print(f"{'engine':<16} {'wall s':>8} {'wall files/s':>13} {'steady files/s':>15} "
          f"{'CPU s/file':>11} {'cores busy':>11}   (medians of {args.repeats})")
    med = {}
    for (engine, jobs), results in runs.items():
        wall = statistics.median(r["wall"] for r in results)
        steady = statistics.median(r["steady"] for r in results)
        med[(engine, jobs)] = (wall, steady)
        cpu_file = statistics.median(r["cpu_per_file"] for r in results)
        busy = statistics.median(r["cpu_total"] / r["wall"] for r in results)
        label = f"{'jobs' if engine == 'pool' else 'dask local'} {jobs}"
        print(f"{label:<16} {wall:>8.2f} {args.frames / wall:>13.2f} {steady:>15.2f} "
              f"{cpu_file:>11.3f} {busy:>11.2f}")
    one, many = med[("pool", 1)], med[("pool", args.jobs)]
    print(f"jobs {args.jobs} / jobs 1: {one[0] / many[0]:.2f}x wall throughput, "
          f"{many[1] / one[1]:.2f}x steady throughput")
    if not args.no_dask:
        dask = med[("dask", args.jobs)]
        cluster = statistics.median(r["cluster_s"] for r in runs[("dask", args.jobs)])
        print(f"dask local {args.jobs} / jobs {args.jobs}: {many[0] / dask[0]:.2f}x wall throughput, "
              f"{dask[1] / many[1]:.2f}x steady throughput; LocalCluster start-up {cluster:.2f} s (not in wall)")
    print(f"per frame, one process warm: {1e3 / one[1]:.1f} ms")
    full, lean, row = pickle_sizes(frames)
    print(f"pickled Result of a VGA frame: {full / 1e6:.2f} MB with intermediate images, "
          f"{lean / 1e6:.2f} MB without (the batch default when results are asked for); "
          f"a summary row alone {row} bytes")
    print(f"load after: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
