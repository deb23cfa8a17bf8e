"""Per-region fitting through the configured fitter plugin, on bounded subsamples."""

from __future__ import annotations


import numpy as np

from .._numeric import rows_at
from .. import kernels  # the package: its names load on first use (no compiler at import)
from .batch_planes import region_moments
from .primitives import Cylinder, FitFailure, Plane, Sphere, with_statistics
from ..kernels.kinds import CYLINDER, NONE, PARAM_SLOTS, PLANE, SPHERE

__all__ = ["RegionFitter", "region_indices", "label_sizes", "model_table", "model_row", "extended_table", "pixel_rms",
           "fresh_label", "other_curved_decision"]


def model_table(fits: dict, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(kinds, params, rms)`` indexed by label, as :mod:`rangeseg_o3d.kernels` takes models.

    Kinds and parameter rows as :mod:`rangeseg_o3d.kernels.kinds` lays them out. Labels
    without a fitted model (absent, FitFailure, or another plugin's model type) get kind
    NONE and are ignored by the kernels.
    """
    kinds = np.full(n, NONE, np.int8)
    params = np.zeros((n, PARAM_SLOTS))
    rms = np.zeros(n)
    for k, model in fits.items():
        if not 0 < k < n or not model:
            continue
        kinds[k] = _fill_row(model, params[k])
        if kinds[k] != NONE:
            rms[k] = model.rms
    return kinds, params, rms


def other_curved_decision(fitter, points: np.ndarray, kind: str):
    """The fitter's decision on ``points`` when it is the curved kind other than ``kind`` (a
    sphere where ``kind`` is a cylinder, a cylinder where it is a sphere), else None: the
    answer the steps that may turn a curved region's kind weigh against its own kind."""
    decided = fitter.fit(points)
    if not decided or isinstance(decided, Plane) or decided.kind == kind:
        return None
    return decided


def fresh_label(labels: np.ndarray, fits: dict) -> int:
    """The first label number above every label in ``labels`` and every key of ``fits``.

    A region can lose all its pixels while its model stays in ``fits`` (a tile region the
    full-resolution pass gave away whole): numbering new regions from the labels alone would
    hand such a number, with its stale model, to a new region.
    """
    return max(int(labels.max(initial=0)), max(fits, default=0)) + 1


def model_row(model) -> tuple[int, np.ndarray]:
    """``(kind, params)`` of one model as a row of :func:`model_table` (NONE and zeros for a
    failure or another plugin's model type)."""
    row = np.zeros(PARAM_SLOTS)
    return (_fill_row(model, row) if model else NONE), row


def extended_table(table: tuple, models: list) -> tuple:
    """The model table ``table`` (:func:`model_table`) with a row for each of ``models``
    appended: their labels follow the table's last, in their order."""
    if not models:
        return table
    kinds, params, rms = table
    rows = [model_row(m) for m in models]
    return (np.concatenate([kinds, np.array([k for k, _ in rows], kinds.dtype)]),
            np.vstack([params, np.array([p for _, p in rows])]),
            np.concatenate([rms, np.array([m.rms for m in models], float)]))


def _fill_row(model, row: np.ndarray) -> int:
    # write the model's parameters into ``row``; returns its kind (NONE: not a known type)
    if isinstance(model, Plane):
        row[:3], row[3] = model.normal, model.d
        return PLANE
    if isinstance(model, Sphere):
        row[:3], row[3] = model.center, model.radius
        return SPHERE
    if isinstance(model, Cylinder):
        row[:3], row[3:6], row[6] = model.axis, model.point, model.radius
        return CYLINDER
    return NONE


def _label_mask(flat: np.ndarray, only) -> np.ndarray:
    # the mask of the positive labels of ``only``, as long as the largest of them that the
    # flat labels may hold (the grid's largest label is read only when one of ``only`` is
    # beyond the pixel count, which no compact numbering reaches)
    wanted = [int(k) for k in only if k > 0]
    top = max(wanted, default=0)
    if top >= flat.size:
        top = min(top, int(flat.max()))
    members = np.zeros(top + 1, bool)
    members[[k for k in wanted if k <= top]] = True
    return members


def region_indices(labels: np.ndarray, only=None) -> dict[int, np.ndarray]:
    """Flat pixel indices (increasing) of every positive label: one counting sort of the grid.

    With ``only`` (labels), just those labels' (a label without pixels is left out, as
    always): the other pixels are read, not sorted.
    """
    flat = np.ascontiguousarray(labels.ravel())
    if flat.size == 0:
        return {}
    if flat.dtype != np.int32:
        flat = flat.astype(np.int32)
    if only is not None:
        # the mask reaches the largest wanted label only: the kernel passes over larger labels,
        # so no pass over the grid for its largest label (0.1-0.3 ms on a 1280 x 720 scan)
        members = _label_mask(flat, only)
        order, starts = kernels.group_members(flat, members)
        n = members.size
    else:
        n = int(flat.max()) + 1
        order, starts = kernels.group_by_label(flat, n)
    present = (np.flatnonzero(np.diff(starts[1:]) > 0) + 1).tolist()
    bounds = starts.tolist()  # Python ints: slicing by numpy scalars costs more than the slice
    return {k: order[bounds[k]:bounds[k + 1]] for k in present}


def region_samples(labels: np.ndarray, only, target: int) -> dict[int, tuple[np.ndarray, int]]:
    """``{k: (sample, count)}`` for each label of ``only`` with pixels: its pixel ``count`` and
    the even subsample ``region_indices(labels, only)[k][:: max(1, count // target)]``, from
    one count pass and one sampling pass (:func:`rangeseg_o3d.kernels.even_samples`), without
    listing every pixel (a 1280 x 720 scan's plane regions hold ~800k)."""
    flat = np.ascontiguousarray(labels.ravel())
    if flat.size == 0:
        return {}
    if flat.dtype != np.int32:
        flat = flat.astype(np.int32)
    members = _label_mask(flat, only)  # (no pass for the largest label)
    n = members.size
    order, starts, counts = kernels.even_samples(flat, members, int(target))
    bounds, sizes = starts.tolist(), counts.tolist()
    return {k: (order[bounds[k]:bounds[k + 1]], sizes[k]) for k in range(n) if sizes[k] > 0}


def label_sizes(labels: np.ndarray, minlength: int = 0) -> np.ndarray:
    """``np.bincount(labels.ravel(), minlength=minlength)`` of a non-negative label image, in
    one compiled pass (:func:`rangeseg_o3d.kernels.label_counts`: a third of numpy's time on a
    scan, which first copies the labels to 64 bits)."""
    if labels.size == 0:
        return np.zeros(minlength, np.int64)
    counts = kernels.label_counts(np.ascontiguousarray(labels))
    if counts.size < minlength:
        counts = np.concatenate([counts, np.zeros(minlength - counts.size, counts.dtype)])
    return counts


def pixel_rms(xyz_flat: np.ndarray, labels: np.ndarray, fits: dict, sigma: np.ndarray) -> dict:
    """``fits`` with each model's rms replaced by the rms distance of its region's pixels."""
    if not fits:
        return {}
    n = max(int(labels.max(initial=0)), max(fits)) + 1
    kinds, params, rms = model_table(fits, n)
    _, squares, counts = kernels.distance_stats(np.ascontiguousarray(xyz_flat, dtype=np.float64),
                                                np.ascontiguousarray(labels.ravel(), dtype=np.int32),
                                                kinds, params, rms, np.ascontiguousarray(sigma.ravel()), 3.0)
    return {k: with_statistics(m, rms=float(np.sqrt(squares[k] / counts[k]))) if counts[k] else m
            for k, m in fits.items()}


class RegionFitter:
    """Calls a fitter plugin on region points; never raises for a bad region.

    Regions larger than ``max_points`` are fitted on an even subsample: a few thousand
    points pin a surface down far below the noise, and a 100k-pixel wall costs only time.
    A plugin with ``bind_sensor`` gets its keywords for ``sensor`` (resolved here, once).
    """

    def __init__(self, plugin, params: dict, max_points: int, sensor=None):
        self.plugin = plugin
        if plugin.bind_sensor is not None:
            if sensor is None:
                raise ValueError(f"fitter {plugin.name!r} needs the sensor (its thresholds follow its noise)")
            params = plugin.bind_sensor(dict(params), sensor)
        self.params = dict(params)
        self.max_points = int(max_points)

    def _subsample(self, points: np.ndarray) -> np.ndarray:
        step = -(-len(points) // self.max_points)
        return points[::step] if step > 1 else points

    def kept(self, n: int, first: int) -> int:
        """Of ``n`` pixels whose points :meth:`points` gathers, how many of the first ``first`` it keeps."""
        step = -(-n // self.max_points)
        return -(-first // step) if step > 1 else first

    def points(self, xyz_flat: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """The points of pixels ``idx``, subsampled before gathering (large regions)."""
        return rows_at(xyz_flat, self._subsample(idx))

    def points_of(self, xyz_flat: np.ndarray, parts) -> np.ndarray:
        """:meth:`points` of the concatenation of the pixel arrays ``parts``, without building
        it (a union of a large region and a piece: only the subsample is gathered)."""
        step = -(-sum(part.size for part in parts) // self.max_points)
        if step <= 1:
            return rows_at(xyz_flat, np.concatenate(parts))
        picked, skip = [], 0  # ``skip``: where the concatenation's every step-th pixel falls in the next part
        for part in parts:
            picked.append(part[skip::step])
            skip = (skip - part.size) % step
        return rows_at(xyz_flat, np.concatenate(picked))

    def fit(self, points: np.ndarray, **overrides):
        """The fitter's model of ``points``, or FitFailure (also when the fitter raises ValueError).
        ``overrides``: keywords the plugin takes beyond its parameters, or parameters set
        otherwise, for this call."""
        try:
            return self.plugin.run(self._subsample(points), **{**self.params, **overrides})
        except ValueError as exc:
            return FitFailure(kind="any", reason=str(exc))

    def trimmed(self, xyz_flat: np.ndarray, pool: np.ndarray, *, sigma: float, min_points: int,
                max_rms: float = np.inf, starts: bool = False, proposals: dict | None = None):
        """:func:`rangeseg_o3d.fitting.robust.trimmed_fit` of ``xyz_flat[pool]`` judged by
        :meth:`fit` (models over ``max_rms`` refused; with ``starts``, from local starts) in
        the plugin's one call, or None when the plugin has none (or the points are not a
        C-ordered float64 array): the caller then runs ``trimmed_fit`` itself. ``proposals``
        (given only when not None): the plugin's memo of the searches' proposals
        (:func:`rangeseg_o3d.fitting.classify.trimmed_primitive`)."""
        if (self.plugin.trimmed is None or xyz_flat.dtype != np.float64 or xyz_flat.ndim != 2
                or not xyz_flat.flags.c_contiguous):
            return None
        if xyz_flat.flags.writeable:
            xyz_flat = xyz_flat.view()
            xyz_flat.flags.writeable = False  # as a cloud's points are: one compiled signature
        if pool.dtype != np.int64 or not pool.flags.c_contiguous:
            pool = np.ascontiguousarray(pool, dtype=np.int64)
        extra = {} if proposals is None else {"proposals": proposals}
        if starts:
            extra["starts"] = True
        try:
            return self.plugin.trimmed(xyz_flat, pool, sigma=sigma, min_inliers=min_points, max_rms=max_rms,
                                       fit_max_points=self.max_points, **extra, **self.params)
        except ValueError:  # as fit: a bad region is no answer
            return None, None

    def fit_batch(self, xyz_flat: np.ndarray, labels: np.ndarray, **overrides) -> dict:
        """The regions the plugin's batch fit settles at once ({} without one); ``overrides``
        as for :meth:`fit`."""
        if self.plugin.fit_batch is None:
            return {}
        return self.plugin.fit_batch(xyz_flat, labels.ravel(), **self.params, **overrides)

    def fit_regions(self, xyz_flat: np.ndarray, labels: np.ndarray) -> dict:
        """A model or FitFailure for every positive label: the plugin's batch first, then one by one."""
        settled = self.fit_batch(xyz_flat, labels)
        return {k: settled[k] if k in settled else self.fit(self.points(xyz_flat, idx))
                for k, idx in region_indices(labels).items()}

    def moments(self, xyz_flat: np.ndarray, labels: np.ndarray, only=None) -> np.ndarray | None:
        """Label-wise moments when the plugin refits from them, else None; with ``only``
        (labels) those labels' rows alone, the others zero (:func:`region_moments`)."""
        if self.plugin.refit_moments is None:
            return None
        return region_moments(xyz_flat, labels.ravel(), only=only)

    def refit_from_moments(self, moments: np.ndarray | None, models: list) -> list:
        """Per model the plugin's refit from its moments row, or None (refit from points)."""
        if moments is None or not models:
            return [None] * len(models)
        try:
            return self.plugin.refit_moments(moments, models, **self.params)
        except ValueError as exc:
            return [FitFailure(kind=m.kind, reason=str(exc)) for m in models]

    def refit_regions(self, xyz_flat: np.ndarray, labels: np.ndarray, fits: dict, which, *,
                      from_points: bool = True, from_moments: bool = True, regions: dict | None = None) -> dict:
        """Refit the regions ``which`` of ``labels``; returns {label: model or FitFailure}.

        Models the plugin refits from moments come from one pass over the pixels (skipped
        when ``from_moments`` is False: the caller knows none of them can); the others
        are refitted on their points unless ``from_points`` is False (then they are left
        out of the answer). ``regions``: ``region_indices(labels)`` when the caller has it.
        """
        which = [k for k in which if fits.get(k)]
        if not which:
            return {}
        # (the rows of ``which`` alone: a refit of a few grown or settled regions sums their pixels only)
        moments = self.moments(xyz_flat, labels, only=which) if from_moments else None
        out = {}
        if moments is not None:
            rows = np.zeros((len(which), moments.shape[1]))
            inside = np.array([k < len(moments) for k in which])
            rows[inside] = moments[[k for k in which if k < len(moments)]]
            out = {k: m for k, m in zip(which, self.refit_from_moments(rows, [fits[k] for k in which]))
                   if m is not None}
        rest = [k for k in which if k not in out] if from_points else []
        if rest:
            regions = region_indices(labels) if regions is None else regions
            empty = np.empty(0, np.int64)
            for k in rest:
                out[k] = self.refit(self.points(xyz_flat, regions.get(k, empty)), fits[k])
        return out

    def refit(self, points: np.ndarray, model, **overrides):
        """A model of ``model``'s kind for ``points`` (the plugin's ``refit``, else ``fit``);
        ``overrides``: parameters of the plugin set otherwise for this call."""
        if self.plugin.refit is None:
            return self.fit(points)
        try:
            return self.plugin.refit(self._subsample(points), model, **{**self.params, **overrides})
        except ValueError as exc:
            return FitFailure(kind=model.kind, reason=str(exc))
