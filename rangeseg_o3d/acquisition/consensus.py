"""One telegram from several damaged copies of it: byte-wise majority after alignment.

On a noisy line (a few % of the bytes corrupted or dropped) a 372-byte scan telegram
almost never arrives whole: at 3 % byte faults, one send in 80 000. When the device
repeats the same scan (a standstill at one tilt, where the scan is a function of the
tilt), the damaged copies differ where they were hit: each copy is aligned to the current
estimate (edit distance: substituted, missing and extra bytes), every aligned byte votes
for its position, and the majority is the new estimate. The result is used only when
every position has a clear majority of at least two copies and it passes the telegram's
CRC, so a guess never becomes data.
"""

from __future__ import annotations

import numpy as np

__all__ = ["align", "consensus"]

_UNKNOWN = -1


def _cost_matrix(reference: np.ndarray, copy: np.ndarray) -> np.ndarray:
    """Edit distances between every prefix of ``reference`` and of ``copy`` (unit costs).

    Rows go along the reference; each row is computed at once: the insertion term is a
    running minimum (``cost[j] = min_k (a[k] + j - k)``).
    """
    n, m = reference.size, copy.size
    columns = np.arange(m + 1)
    cost = np.empty((n + 1, m + 1), dtype=np.int32)
    cost[0] = columns
    for i in range(1, n + 1):
        previous = cost[i - 1]
        substitute = previous[:-1] + (copy != reference[i - 1])
        best = np.empty(m + 1, dtype=np.int32)
        best[0] = i
        best[1:] = np.minimum(substitute, previous[1:] + 1)  # byte i of the reference missing
        cost[i] = np.minimum.accumulate(best - columns) + columns  # extra bytes in the copy
    return cost


def _as_ints(data) -> np.ndarray:
    if isinstance(data, (bytes, bytearray)):
        return np.frombuffer(bytes(data), dtype=np.uint8).astype(np.int32)
    return np.asarray(data, dtype=np.int32)


def _trace(reference: np.ndarray, copy: np.ndarray):
    """Walk the cheapest alignment: yields ('match', i, byte), ('missing', i, -) or ('extra', i, byte).

    ``('extra', i, byte)``: a byte of the copy that stands before reference position ``i``.
    """
    cost = _cost_matrix(reference, copy)
    steps = []
    i, j = reference.size, copy.size
    while i > 0 or j > 0:
        here = cost[i, j]
        if i > 0 and j > 0 and here == cost[i - 1, j - 1] + (copy[j - 1] != reference[i - 1]):
            steps.append(("match", i - 1, int(copy[j - 1])))
            i, j = i - 1, j - 1
        elif i > 0 and here == cost[i - 1, j] + 1:
            steps.append(("missing", i - 1, -1))
            i -= 1
        else:
            steps.append(("extra", i, int(copy[j - 1])))
            j -= 1
    return steps[::-1]


def align(reference, copy) -> list[tuple[int, int]]:
    """``(reference position, copy byte)`` for every byte of ``copy`` aligned to a reference byte.

    ``reference`` may hold -1 for unknown bytes (they match nothing).

    >>> align([1, 2, 3, 4], [1, 3, 9])   # byte 2 dropped, 4 corrupted to 9
    [(0, 1), (2, 3), (3, 9)]
    """
    steps = _trace(_as_ints(reference), _as_ints(copy))
    return [(i, value) for kind, i, value in steps if kind == "match"]


def _vote(estimate: np.ndarray, copies: list[np.ndarray]):
    """Votes per position (256 values + 'missing') and per gap before each position (+ the end)."""
    n = estimate.size
    votes = np.zeros((n, 257), dtype=np.int32)  # column 256: the copy lacks this byte
    extra = np.zeros((n + 1, 256), dtype=np.int32)
    for copy in copies:
        seen_gap = set()
        for kind, i, value in _trace(estimate, copy):
            if kind == "match":
                votes[i, value] += 1
            elif kind == "missing":
                votes[i, 256] += 1
            elif i not in seen_gap:  # one vote per copy and gap
                extra[i, value] += 1
                seen_gap.add(i)
    return votes, extra


def _revise(votes: np.ndarray, extra: np.ndarray, n_copies: int) -> np.ndarray:
    """The estimate the votes elect: majority bytes, bytes most copies lack removed,
    bytes most copies have in a gap inserted."""
    out = []
    for i in range(votes.shape[0] + 1):
        if extra[i].max() * 2 > n_copies:
            out.append(int(extra[i].argmax()))
        if i == votes.shape[0]:
            break
        winner = int(votes[i].argmax())
        if winner != 256:
            out.append(winner if votes[i, winner] > 0 else _UNKNOWN)
    return np.asarray(out, dtype=np.int32)


def consensus(copies, length: int, *, rounds: int = 4) -> bytes | None:
    """The ``length``-byte frame most copies agree on, or None if some byte has no clear majority.

    A clear majority: at least two copies and more votes than any other value (or than
    the copies that lack the byte).

    >>> frame = bytes(range(10, 30))
    >>> damaged = [frame[:3] + frame[4:], frame[:10] + b"\\x00" + frame[11:], frame[:15] + frame[16:]]
    >>> consensus(damaged, len(frame)) == frame
    True
    """
    copies = [_as_ints(bytes(c)) for c in copies if len(c)]
    if len(copies) < 2:
        return None
    estimate = min(copies, key=lambda c: abs(c.size - length))
    for _ in range(rounds):
        votes, extra = _vote(estimate, copies)
        revised = _revise(votes, extra, len(copies))
        if np.array_equal(revised, estimate):
            break
        estimate = revised
    if estimate.size != length:
        return None
    votes, extra = _vote(estimate, copies)
    ranked = np.sort(votes, axis=1)
    clear = (ranked[:, -1] >= 2) & (ranked[:, -1] > ranked[:, -2]) & (votes.argmax(axis=1) != 256)
    if not clear.all() or extra.max() * 2 > len(copies):
        return None
    return estimate.astype(np.uint8).tobytes()
