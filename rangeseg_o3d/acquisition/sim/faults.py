"""Seeded byte-level line faults: corrupted and dropped bytes."""

from __future__ import annotations

import numpy as np

__all__ = ["LineFaults"]


class LineFaults:
    """Corrupt or drop each byte with probability ``rate`` (half each), reproducibly.

    Parameters
    ----------
    rate : float
        Probability that a byte is hit, 0 <= rate < 1.
    seed : int
        Seed of the generator.
    """

    def __init__(self, rate: float = 0.0, seed: int = 0):
        if not 0.0 <= rate < 1.0:
            raise ValueError(f"fault rate must be in [0, 1); got {rate}")
        self.rate = float(rate)
        self.rng = np.random.default_rng(seed)
        self.corrupted = 0
        self.dropped = 0

    def apply(self, data: bytes) -> bytes:
        if self.rate == 0.0 or not data:
            return data
        arr = np.frombuffer(data, dtype=np.uint8).copy()
        hit = self.rng.random(arr.size) < self.rate
        if not hit.any():
            return data
        drop = hit & (self.rng.random(arr.size) < 0.5)
        corrupt = hit & ~drop
        arr[corrupt] ^= self.rng.integers(1, 256, int(corrupt.sum()), dtype=np.uint8)
        self.corrupted += int(corrupt.sum())
        self.dropped += int(drop.sum())
        return arr[~drop].tobytes()

    def garbage(self, n: int) -> bytes:
        """What a receiver at the wrong baud rate makes of ``n`` bytes."""
        return self.rng.integers(0, 256, max(1, n // 3), dtype=np.uint8).tobytes()
