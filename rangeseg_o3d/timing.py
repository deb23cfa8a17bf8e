"""Seconds per step of a run, for ``Result.timings``: the pipeline's stages, the refinement's
``refine.<step>`` and the full-resolution stage's ``full.<step>``."""

import time

__all__ = ["StepTimer"]


class StepTimer:
    """Seconds per step into ``timings`` under ``prefix + name``, each lap from the last (or
    from creation, ``start``); nothing is recorded when ``timings`` is None."""

    def __init__(self, timings: dict | None, prefix: str = ""):
        self.timings, self.prefix = timings, prefix
        self.start = self.last = time.perf_counter()

    def lap(self, name: str) -> None:
        """Record the seconds since the last lap as ``prefix + name``."""
        now = time.perf_counter()
        if self.timings is not None:
            self.timings[self.prefix + name] = now - self.last
        self.last = now
