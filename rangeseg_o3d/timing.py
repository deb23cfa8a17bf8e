"""Seconds per step of a run, for ``Result.timings``: the pipeline's stages, the refinement's
``refine.<step>`` and the full-resolution stage's ``full.<step>``.

Steps are timed on wall time (``time.perf_counter``) unless a caller picks another clock
with :func:`set_clock`: ``scripts/benchmark.py --cpu-stages`` takes the process's CPU time,
which on a machine shared with other jobs moves far less than wall time (a 14 ms LMS200
scan read 55-75 ms of wall time per run under a load of 8 on 2 cores, its steps alike).
"""

import time

__all__ = ["StepTimer", "now", "set_clock"]

_clock = time.perf_counter


def now() -> float:
    """The current reading, in seconds, of the clock steps are timed on."""
    return _clock()


def set_clock(clock):
    """Time every step from here on with ``clock`` (a function of no argument returning
    seconds, e.g. ``time.process_time``); returns the clock used so far, to put back."""
    global _clock
    previous, _clock = _clock, clock
    return previous


class StepTimer:
    """Seconds per step into ``timings`` under ``prefix + name``, each lap from the last (or
    from creation, ``start``); nothing is recorded when ``timings`` is None."""

    def __init__(self, timings: dict | None, prefix: str = ""):
        self.timings, self.prefix = timings, prefix
        self.start = self.last = _clock()

    def lap(self, name: str) -> None:
        """Record the seconds since the last lap as ``prefix + name``."""
        now = _clock()
        if self.timings is not None:
            self.timings[self.prefix + name] = now - self.last
        self.last = now

    def elapsed(self) -> float:
        """Seconds since the timer was created."""
        return _clock() - self.start
