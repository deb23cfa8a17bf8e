"""Pipeline: OrganizedCloud -> segmentation -> per-region fits -> refinement -> Result."""

from __future__ import annotations

import logging
import time

import numpy as np

from . import registry
from .cloud import OrganizedCloud
from .config import PipelineConfig, load_config
from .fitting.models import FitFailure
from .refine import grow_into_edges, leftover_candidates, merge_candidates, region_adjacency
from .regions import relabel_sequential
from .residual import noise_sigma
from .robust import trimmed_fit
from .result import Feature, Result, Unfitted

__all__ = ["Pipeline"]

log = logging.getLogger(__name__)


def _region_indices(labels: np.ndarray) -> dict[int, np.ndarray]:
    # One sort of the whole grid instead of one mask per region.
    flat = labels.ravel()
    order = np.argsort(flat, kind="stable")
    sorted_labels = flat[order]
    present, starts = np.unique(sorted_labels, return_index=True)
    stops = np.r_[starts[1:], flat.size]
    return {int(k): order[a:b] for k, a, b in zip(present, starts, stops) if k > 0}


class Pipeline:
    """Segment organized clouds and fit planes, cylinders and spheres to the regions.

    Parameters
    ----------
    config : PipelineConfig, preset name, YAML path, dict, or None (the lms200 preset).

    Examples
    --------
    >>> import rangeseg_o3d as rs  # doctest: +SKIP
    >>> result = rs.Pipeline("lms200").run(cloud)  # doctest: +SKIP
    """

    def __init__(self, config=None):
        self.config: PipelineConfig = load_config(config)
        self.segmenter = registry.get("segmenter", self.config.segmenter.name)
        self.fitter = registry.get("fitter", self.config.fitter.name)

    def __repr__(self) -> str:
        return (f"Pipeline({self.config.name!r}, segmenter={self.segmenter.name!r}, "
                f"fitter={self.fitter.name!r})")

    def _noise(self, ranges: np.ndarray) -> np.ndarray:
        seg = self.config.segmenter.params
        ref = self.config.refine
        sigma0 = ref.sigma0 if ref.sigma0 is not None else seg.get("sigma0", 0.005)
        quad = ref.sigma_quadratic if ref.sigma_quadratic is not None else seg.get("sigma_quadratic", 0.0)
        return noise_sigma(ranges, sigma0=sigma0, sigma_quadratic=quad)

    def _subsample(self, points: np.ndarray) -> np.ndarray:
        # A few thousand points pin a surface down to well below the noise; fitting a
        # 100k-pixel wall on all of them only costs time.
        step = -(-len(points) // self.config.max_fit_points)
        return points[::step] if step > 1 else points

    def _fit(self, points: np.ndarray):
        points = self._subsample(points)
        try:
            return self.fitter.run(points, **self.config.fitter.params)
        except ValueError as exc:
            # A region the fitter rejects is reported, the rest of the scan goes on.
            return FitFailure(kind="any", reason=str(exc))

    def _refit(self, points: np.ndarray, model):
        if self.fitter.refit is None:
            return self._fit(points)
        points = self._subsample(points)
        try:
            return self.fitter.refit(points, model, **self.config.fitter.params)
        except ValueError as exc:
            return FitFailure(kind=model.kind, reason=str(exc))

    def run(self, cloud: OrganizedCloud, *, recording=None, scan_index: int = 0) -> Result:
        """Segment ``cloud`` and fit every region.

        Parameters
        ----------
        cloud : OrganizedCloud
        recording : optional ``rerun.RecordingStream``; every stage is logged to it.
        scan_index : position of this scan on the recording's ``scan`` timeline.

        Raises
        ------
        TypeError
            ``cloud`` is not an OrganizedCloud.
        ValueError
            The cloud has no valid point, or the segmenter returned malformed labels.
        """
        if not isinstance(cloud, OrganizedCloud):
            raise TypeError(f"cloud must be an OrganizedCloud; got {type(cloud).__name__}")
        if cloud.n_valid == 0:
            raise ValueError(f"cloud has no valid point (all {cloud.shape[0]}x{cloud.shape[1]} are NaN)")
        timings: dict[str, float] = {}
        t_start = time.perf_counter()
        seg = self.segmenter.run(cloud, **self.config.segmenter.params)
        labels = np.asarray(seg.labels)
        if labels.shape != cloud.shape or not np.issubdtype(labels.dtype, np.integer):
            raise ValueError(
                f"segmenter {self.segmenter.name!r} returned labels of shape {labels.shape} and "
                f"dtype {labels.dtype}; expected integer labels of shape {cloud.shape}"
            )
        labels = labels.astype(np.int32, copy=False)
        labels[~cloud.valid] = 0
        timings.update(seg.timings)
        t_seg = time.perf_counter()
        timings["segment"] = t_seg - t_start

        xyz_flat = cloud.xyz.reshape(-1, 3)
        regions = _region_indices(labels)
        fits = {k: self._fit(xyz_flat[idx]) for k, idx in regions.items()}
        t_fit = time.perf_counter()
        timings["fit"] = t_fit - t_seg

        if self.config.refine.enabled:
            labels, fits = self._refine(cloud, labels, fits, seg.stages.get("jumps"))
        t_ref = time.perf_counter()
        timings["refine"] = t_ref - t_fit

        labels, fits = self._renumber(labels, fits)
        sizes = np.bincount(labels.ravel(), minlength=len(fits) + 1)
        features, unfitted = [], []
        for k in sorted(fits):
            model = fits[k]
            if model:
                features.append(Feature(label=k, model=model, n_pixels=int(sizes[k])))
            else:
                unfitted.append(Unfitted(label=k, n_pixels=int(sizes[k]),
                                         reason=f"{model.kind}: {model.reason}"))
        timings["total"] = time.perf_counter() - t_start
        result = Result(labels=labels, features=features, unfitted=unfitted, timings=timings,
                        stages=dict(seg.stages))
        if recording is not None:
            from .viz.rerun_log import log_scan

            log_scan(recording, cloud, result, scan_index=scan_index)
        return result

    def _explain(self, labels, fits, cloud, sigma, candidates, *, keep_failures: bool,
                 min_share: float = 0.0):
        """Give each candidate region the model most of it lies on; split off the rest.

        The inliers of a trimmed fit (:func:`rangeseg_o3d.robust.trimmed_fit`) keep the
        region, restricted to their largest 4-connected piece of the grid; the other pixels
        are freed for growth. Candidates nothing explains, or whose explained share is
        below ``min_share``, are dropped, or kept as unfitted regions when ``keep_failures``.
        """
        import cv2

        min_size = max(int(self.config.segmenter.params.get("min_region_size", 30)), 10)
        xyz_flat = cloud.xyz.reshape(-1, 3)
        sigma_flat = sigma.ravel()
        width = cloud.shape[1]
        for k, idx in _region_indices(candidates).items():
            model = self._fit(xyz_flat[idx])
            if not model:
                trimmed, inliers = trimmed_fit(xyz_flat[idx], self._fit,
                                               sigma=float(np.nanmedian(sigma_flat[idx])),
                                               min_points=min_size)
                if trimmed is not None:
                    rows, cols = np.divmod(idx[inliers], width)
                    top, left = rows.min(), cols.min()
                    patch = np.zeros((rows.max() - top + 1, cols.max() - left + 1), np.uint8)
                    patch[rows - top, cols - left] = 1
                    n, comp = cv2.connectedComponents(patch, connectivity=4)
                    piece = comp[rows - top, cols - left]
                    largest = np.argmax(np.bincount(piece, minlength=n)[1:]) + 1
                    chosen = idx[inliers][piece == largest]
                    if chosen.size >= max(min_size, min_share * idx.size):
                        refined = self._refit(xyz_flat[chosen], trimmed)
                        if refined:
                            labels.ravel()[idx] = 0
                            labels.ravel()[chosen] = k
                            fits[k] = refined
                            continue
            if model:
                labels.ravel()[idx] = k
                fits[k] = model
            elif keep_failures:
                labels.ravel()[idx] = k
                fits[k] = model
            else:
                labels.ravel()[idx] = 0
                fits.pop(k, None)
        return labels, fits

    def _refine(self, cloud, labels, fits, jumps=None):
        ref = self.config.refine
        seg = self.config.segmenter.params
        ranges = np.where(cloud.valid, cloud.range_image(), np.nan)
        sigma = self._noise(ranges)
        failed = np.isin(labels, [k for k, m in fits.items() if not m])
        if failed.any():
            # Under-segmented regions: keep the dominant surface, free the rest.
            labels, fits = self._explain(labels, fits, cloud, sigma, np.where(failed, labels, 0),
                                         keep_failures=True)
        if ref.recover_leftovers:
            if jumps is None:
                jumps = np.zeros(cloud.shape, bool)
            min_size = max(int(seg.get("min_region_size", 30)), 10)
            candidates = leftover_candidates(labels, cloud.valid, jumps, min_size=min_size,
                                             first_label=int(labels.max(initial=0)) + 1)
            # A blob at a junction of surfaces can pass for a small curved patch; a real
            # swallowed object makes up most of its blob.
            labels, fits = self._explain(labels, fits, cloud, sigma, candidates,
                                         keep_failures=False, min_share=0.7)
        xyz_flat = cloud.xyz.reshape(-1, 3)
        good = {k: m for k, m in fits.items() if m}
        if ref.grow_iterations and good:
            grown = grow_into_edges(
                cloud.xyz, labels, good, sigma, ranges, iterations=ref.grow_iterations,
                k_sigma=ref.k_sigma, jump_ratio=seg.get("jump_ratio", 0.08),
                jump_min=seg.get("jump_min", 0.05),
            )
            changed = np.unique(grown[grown != labels])
            labels = grown
            if changed.size:
                regions = _region_indices(labels)
                for k in changed:
                    refit = self._refit(xyz_flat[regions[int(k)]], fits[int(k)])
                    # Keep the refit only if it stays the same kind of surface.
                    if refit and refit.kind == fits[int(k)].kind:
                        fits[int(k)] = refit
        if ref.merge:
            labels, fits = self._merge(labels, fits, xyz_flat)
            labels, fits = self._dissolve(labels, fits, xyz_flat, sigma.ravel())
        return labels, fits

    def _merge(self, labels, fits, xyz_flat):
        ref = self.config.refine
        good = {k: m for k, m in fits.items() if m}
        pairs = merge_candidates(good, max_angle_deg=ref.merge_angle_deg,
                                 tolerance=ref.merge_tolerance, adjacency=region_adjacency(labels),
                                 disjoint=ref.merge_disjoint)
        if not pairs:
            return labels, fits
        regions = _region_indices(labels)
        root = {k: k for k in fits}

        def find(k):
            while root[k] != k:
                k = root[k]
            return k

        for a, b in pairs:
            ra, rb = find(a), find(b)
            if ra == rb or not fits[ra] or not fits[rb]:
                continue
            union_idx = np.concatenate([regions[ra], regions[rb]])
            union = self._refit(xyz_flat[union_idx], fits[ra])
            limit = ref.merge_rms_factor * max(fits[ra].rms, fits[rb].rms)
            if union and union.kind == fits[ra].kind and union.rms <= limit:
                root[rb] = ra
                regions[ra] = union_idx
                fits[ra] = union
                del regions[rb]
                fits.pop(rb)
        lut = np.arange(int(labels.max(initial=0)) + 1, dtype=np.int32)
        for k in root:
            lut[k] = find(k)
        return lut[labels], fits

    def _dissolve(self, labels, fits, xyz_flat, sigma_flat):
        """Hand small regions to the larger neighbours whose surfaces already explain them.

        A blob where two or three surfaces meet can pass for a small curved patch; its kind
        differs from its neighbours', so the union fits of :meth:`_merge` never see it. When
        at least 80 % of a small region's points lie within ``k_sigma max(sigma, rms)`` of a
        larger neighbour's model, each such point joins the neighbour that explains it best
        and the rest become unlabelled; the neighbours are refitted.
        """
        min_size = int(self.config.segmenter.params.get("min_region_size", 30))
        k_sigma = self.config.refine.k_sigma
        regions = _region_indices(labels)
        neighbours: dict[int, set[int]] = {}
        for a, b in region_adjacency(labels):
            neighbours.setdefault(a, set()).add(b)
            neighbours.setdefault(b, set()).add(a)
        changed = set()
        for small in sorted(regions, key=lambda k: regions[k].size):
            idx = regions.get(small)
            if idx is None or idx.size >= 3 * min_size:
                continue
            hosts = [k for k in neighbours.get(small, ()) if k in regions and fits.get(k)
                     and regions[k].size > idx.size]
            if not hosts:
                continue
            pts = xyz_flat[idx]
            score = np.stack([
                np.abs(fits[k].distances(pts)) / np.maximum(sigma_flat[idx], fits[k].rms)
                for k in hosts
            ])
            best = np.argmin(score, axis=0)
            explained = score[best, np.arange(idx.size)] <= k_sigma
            if explained.mean() < 0.8:
                continue
            new_labels = np.where(explained, np.asarray(hosts)[best], 0)
            labels.ravel()[idx] = new_labels
            for k in set(new_labels[explained].tolist()):
                regions[k] = np.concatenate([regions[k], idx[new_labels == k]])
                changed.add(k)
            del regions[small]
            fits.pop(small, None)
        for k in changed:
            if k in regions:
                refit = self._refit(xyz_flat[regions[k]], fits[k])
                if refit:
                    fits[k] = refit
        return labels, fits

    @staticmethod
    def _renumber(labels, fits):
        new = relabel_sequential(labels)
        mapping = {}
        flat_old, flat_new = labels.ravel(), new.ravel()
        nz = np.flatnonzero(flat_old)
        if nz.size:
            old_ids, first = np.unique(flat_old[nz], return_index=True)
            mapping = {int(o): int(flat_new[nz[i]]) for o, i in zip(old_ids, first)}
        return new, {mapping[k]: m for k, m in fits.items() if k in mapping}
