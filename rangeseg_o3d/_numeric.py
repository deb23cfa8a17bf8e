"""Small numeric helpers shared by the stages (plain numpy)."""

from __future__ import annotations

import numpy as np

__all__ = ["median", "rows_at", "unique_ints"]


def median(values) -> float:
    """``float(np.median(values))`` of a non-empty 1-D array, bit for bit, at a fraction of
    its cost on small arrays.

    ``np.median`` takes ~10 us of generic-axis bookkeeping before its partition; the
    refinement takes medians of a few dozen to a few thousand values many times per scan.
    The same steps: a partition around the middle (and the last element, which holds a
    NaN if there is one: the answer is then NaN), the middle value or the mean of the two
    middle ones (their sum over 2, as numpy's mean of two values).
    """
    values = np.asarray(values, dtype=np.float64)
    n = values.size
    if values.ndim != 1 or n == 0:
        raise ValueError(f"values must be a non-empty 1-D array; got shape {values.shape}")
    half = n // 2
    kth = [half, n - 1] if n % 2 else [half - 1, half, n - 1]
    part = np.partition(values, kth)
    if part[n - 1] != part[n - 1]:  # NaN
        return float("nan")
    return float(part[half]) if n % 2 else float((part[half - 1] + part[half]) / 2.0)


def rows_at(array: np.ndarray, idx) -> np.ndarray:
    """``array[idx]`` for a 1-D integer array ``idx`` of indices into ``array``'s first axis,
    by ``ndarray.take`` (the same rows, a new C-ordered array, at a third to a quarter of
    fancy indexing's time on (N, 3) points: the refinement gathers a region's points many
    times per scan); any other index as ``array[idx]``."""
    if type(idx) is np.ndarray and idx.ndim == 1 and idx.dtype.kind == "i":
        return array.take(idx, axis=0)
    return array[idx]


def unique_ints(values) -> np.ndarray:
    """``np.unique(values)`` of a 1-D integer (or bool, or empty) array: its distinct values,
    increasing, in its dtype, by one sort.

    NumPy 2.4's ``np.unique`` hashes the values first: on the thousands of flat pixel indices
    or labels the full-resolution steps deduplicate, 4-10 times slower than sorting them.
    """
    values = np.asarray(values)
    if values.ndim != 1 or (values.dtype.kind not in "biu" and values.size):
        raise ValueError(f"values must be a 1-D integer array; got shape {values.shape}, dtype {values.dtype}")
    ordered = np.sort(values)  # (an empty array of any dtype: as np.unique, itself)
    if ordered.size < 2:
        return ordered
    keep = np.empty(ordered.size, bool)
    keep[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=keep[1:])
    return ordered[keep]
