"""Simulated time that runs ``1 / time_scale`` times faster than the wall clock."""

from __future__ import annotations

import time

__all__ = ["SimClock"]


class SimClock:
    """Device time in seconds; ``time_scale=0.01`` makes a 1 s move take 10 ms of wall time."""

    def __init__(self, time_scale: float = 1.0):
        if not time_scale > 0:
            raise ValueError(f"time_scale must be positive; got {time_scale}")
        self.time_scale = float(time_scale)
        self._t0 = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self._t0) / self.time_scale

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds * self.time_scale)
