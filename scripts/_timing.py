"""The timing helper the bench_* scripts share."""

from __future__ import annotations

import statistics
import time


def median_seconds(func, repeats: int, *, warm: bool = False) -> float:
    """Median wall time of ``repeats`` calls of ``func()``; one untimed call first if ``warm``."""
    if warm:
        func()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return statistics.median(times)
