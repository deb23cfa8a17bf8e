"""Run every segmenter on the same scans and write docs/benchmarks/ (see rangeseg_o3d.evaluation.compare).

Run: python scripts/compare.py [--quick] [--repeats N] [--out-dir DIR] [--segmenters a,b]
"""

from rangeseg_o3d.evaluation.compare import main

if __name__ == "__main__":
    raise SystemExit(main())
