"""Time the I/O paths: loading every shared real scan, LZF backends, npz/PCD round trips.

Prints the median of repeated runs (seconds). Usage::

    python scripts/bench_io.py [--repeats 5] [--data-root PATH]
"""

from __future__ import annotations

import argparse
import struct
import tempfile
from pathlib import Path

import numpy as np

from rangeseg_o3d import OrganizedCloud
from rangeseg_o3d.io import load_cloud, save_npz, write_pcd
from rangeseg_o3d.io.datasets import default_data_root, real_clouds
from rangeseg_o3d.io.lzf import lzf_decompress
from rangeseg_o3d.io.pcd import read_pcd
from rangeseg_o3d.io.pcd import parse_pcd_header
from _timing import median_seconds  # scripts/_timing.py (scripts/ is on sys.path)


def _compressed_stream(path: Path) -> tuple[bytes, int]:
    raw = path.read_bytes()
    header = parse_pcd_header(raw, path)
    offset = header.data_offset
    compressed_size, raw_size = struct.unpack("<II", raw[offset:offset + 8])
    return raw[offset + 8:offset + 8 + compressed_size], raw_size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--data-root", type=Path, default=None)
    args = parser.parse_args()
    root = args.data_root or default_data_root()

    print(f"repeats: {args.repeats} (medians; timings on a shared machine are noisy)")
    print(f"{'real scan':<22} {'preset':<16} {'grid':>9} {'load s':>8}")
    for item in real_clouds(root):
        cloud = item.load()
        seconds = median_seconds(item.load, args.repeats)
        print(f"{item.name:<22} {item.preset:<16} {cloud.shape[0]:>4}x{cloud.shape[1]:<4} {seconds:8.3f}")

    compressed = root / "pcl" / "office1.pcd"
    if compressed.is_file():
        stream, size = _compressed_stream(compressed)
        seconds = median_seconds(lambda: lzf_decompress(stream, size), args.repeats)
        print(f"LZF decompress office1.pcd ({size / 1e6:.1f} MB out): {seconds * 1e3:.1f} ms")
        seconds = median_seconds(lambda: read_pcd(compressed), args.repeats)
        print(f"read_pcd office1.pcd (640x480 binary_compressed, target <= 30 ms): "
              f"{seconds * 1e3:.1f} ms")

    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(480, 640, 3))
    xyz[rng.random((480, 640)) < 0.2] = np.nan
    cloud = OrganizedCloud(xyz, ranges=np.linalg.norm(xyz, axis=2))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cases = [
            ("npz compressed", lambda: save_npz(cloud, tmp / "a.npz", compress=True), tmp / "a.npz"),
            ("npz plain", lambda: save_npz(cloud, tmp / "b.npz"), tmp / "b.npz"),
            ("pcd binary", lambda: write_pcd(cloud, tmp / "c.pcd"), tmp / "c.pcd"),
        ]
        cases.append(("pcd binary_compressed",
                      lambda: write_pcd(cloud, tmp / "d.pcd", data="binary_compressed"),
                      tmp / "d.pcd"))
        print(f"{'640x480 cloud':<24} {'write s':>8} {'read s':>8} {'MB':>6}")
        for name, write, path in cases:
            write_s = median_seconds(write, args.repeats)
            read_s = median_seconds(lambda: load_cloud(path), args.repeats)
            print(f"{name:<24} {write_s:8.3f} {read_s:8.3f} {path.stat().st_size / 1e6:6.1f}")


if __name__ == "__main__":
    main()
