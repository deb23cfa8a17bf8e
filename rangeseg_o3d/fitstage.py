"""Per-region fitting through the configured fitter plugin, on bounded subsamples."""

from __future__ import annotations

import numpy as np

from .fitting.models import FitFailure

__all__ = ["RegionFitter", "region_indices"]


def region_indices(labels: np.ndarray) -> dict[int, np.ndarray]:
    """Flat pixel indices of every positive label (one sort of the grid, not a mask per region)."""
    flat = labels.ravel()
    if flat.size and 0 <= flat.min() and flat.max() < 65536:
        flat = flat.astype(np.uint16)  # numpy's stable sort is a radix sort for 16-bit keys
    order = np.argsort(flat, kind="stable")
    sorted_labels = flat[order]
    present, starts = np.unique(sorted_labels, return_index=True)
    stops = np.r_[starts[1:], flat.size]
    return {int(k): order[a:b] for k, a, b in zip(present, starts, stops) if k > 0}


class RegionFitter:
    """Calls a fitter plugin on region points; never raises for a bad region.

    Regions larger than ``max_points`` are fitted on an even subsample: a few thousand
    points pin a surface down far below the noise, and a 100k-pixel wall costs only time.
    """

    def __init__(self, plugin, params: dict, max_points: int):
        self.plugin = plugin
        self.params = dict(params)
        self.max_points = int(max_points)

    def _subsample(self, points: np.ndarray) -> np.ndarray:
        step = -(-len(points) // self.max_points)
        return points[::step] if step > 1 else points

    def points(self, xyz_flat: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """The points of pixels ``idx``, subsampled before gathering (large regions)."""
        return xyz_flat[self._subsample(idx)]

    def fit(self, points: np.ndarray):
        """The fitter's model of ``points``, or FitFailure (also when the fitter raises ValueError)."""
        try:
            return self.plugin.run(self._subsample(points), **self.params)
        except ValueError as exc:
            return FitFailure(kind="any", reason=str(exc))

    def refit(self, points: np.ndarray, model):
        """A model of ``model``'s kind for ``points`` (the plugin's ``refit``, else ``fit``)."""
        if self.plugin.refit is None:
            return self.fit(points)
        try:
            return self.plugin.refit(self._subsample(points), model, **self.params)
        except ValueError as exc:
            return FitFailure(kind=model.kind, reason=str(exc))
