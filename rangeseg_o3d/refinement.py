"""The refinement stage: beyond the paper's Sec. 3.2, after the first fits.

Order, each step timed under ``refine.<step>`` in ``Result.timings``:

1. ``split``: a region no model explains is split into all the surfaces it holds, one
   after the other (least trimmed squares, largest connected piece); only what no surface
   takes is freed (the paper's "local checks that remove under-segmentation").
2. ``recover``: compact blobs of unlabelled pixels (small curved objects that the edge
   band swallowed whole) become regions when a model explains most of them.
3. ``grow``: edge-band pixels go back to the neighbouring region whose surface explains
   them (the paper's "re-add points left out by the edge band"). This runs before
   ``recover``, so only what no neighbour explains is left over.
4. ``merge``: regions of one kind whose union one model explains as well as the parts are
   merged; small blobs at junctions are dissolved into the neighbours that explain them
   (the paper's "merging of patches that belong to the same surface").
5. ``polish``: spheres and cylinders are refitted once on their final pixels (planes are
   refitted from moments whenever they change, which costs nothing).
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from .fitstage import RegionFitter, pixel_rms, region_indices
from .fitting.primitives import FitFailure, Plane
from .fitting.batch_planes import planes_from_moments
from .refine import grow_into_edges, leftover_candidates, merge_candidates, region_adjacency
from .robust import trimmed_fit
from .sensor import Sensor

__all__ = ["refine_regions", "recover_pixels"]

# the merge's answer for a union of planes whose least-squares plane is over the merge limit
_NO_UNION = FitFailure("plane", "the union's least-squares plane rms is over the merge limit")
# searches per split region (found surfaces and failed pieces alike): bounds the split's time
_MAX_SPLIT_ATTEMPTS = 24


class _Timer:
    def __init__(self, timings: dict):
        self.timings = timings
        self.last = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.timings[f"refine.{name}"] = now - self.last
        self.last = now


def refine_regions(cloud, labels, fits, *, fitter: RegionFitter, config, sensor: Sensor,
                   ranges: np.ndarray, sigma: np.ndarray, jumps: np.ndarray | None,
                   timings: dict):
    """Run the refinement steps; returns the new ``(labels, fits)``.

    Parameters
    ----------
    cloud : OrganizedCloud
    labels : (H, W) int32 labels after segmentation (modified in place).
    fits : label -> model or FitFailure.
    fitter : the pipeline's region fitter.
    config : RefineConfig (``min_region_size`` and the jump test resolved at load).
    sensor : the run's sensor.
    ranges : (H, W) ranges, NaN where invalid (for the no-jump test of growth).
    sigma : (H, W) range noise per pixel (``sensor.noise`` at ``ranges``).
    jumps : (H, W) jump-edge mask from the segmenter, if it made one.
    timings : dict receiving ``refine.<step>`` durations.
    """
    timer = _Timer(timings)
    # Region sizes and jump ratios are in sensor pixels; a grid step spans cloud.tile.
    tile = cloud.tile
    min_size = max(-(-int(config.min_region_size) // (tile * tile)), 10)
    jump_ratio = config.jump_ratio * tile
    ctx = _Context(cloud, fitter, sigma, min_size)
    failed = [k for k, m in fits.items() if not m]
    if failed:
        labels, fits = ctx.split(labels, fits, failed)
    timer.lap("split")

    def grow(labels, fits, iterations):
        good = {k: m for k, m in fits.items() if m}
        if not (iterations and good):
            return labels, fits
        grown = grow_into_edges(
            cloud.xyz, labels, good, sigma, ranges, iterations=iterations,
            k_sigma=config.k_sigma, jump_ratio=jump_ratio,
            jump_min=config.jump_min,
        )
        return ctx.refit_grown(labels, grown, fits)

    # Growing first leaves as leftovers only what no neighbour explains.
    labels, fits = grow(labels, fits, config.grow_iterations)
    timer.lap("grow")
    if config.recover_leftovers:
        mask = jumps if jumps is not None else np.zeros(cloud.shape, bool)
        first = int(labels.max(initial=0)) + 1
        candidates = leftover_candidates(labels, cloud.valid, mask, min_size=min_size,
                                         first_label=first)
        # A blob at a junction of surfaces can pass for a small curved patch; a real
        # swallowed object makes up most of its blob.
        labels, fits = ctx.explain(labels, fits, candidates, min_share=0.7)
        if labels.max(initial=0) >= first:
            labels, fits = grow(labels, fits, 2)  # recovered blobs take back their rims
    timer.lap("recover")
    if config.merge:
        adjacency = region_adjacency(labels, wrap_columns=sensor.wrap_columns)
        labels, fits, adjacency = ctx.merge(labels, fits, config, adjacency)
        labels, fits = ctx.dissolve(labels, fits, config.k_sigma, adjacency)
    timer.lap("merge")
    labels, fits = ctx.polish(labels, fits)
    timer.lap("polish")
    return labels, fits


def recover_pixels(cloud, labels, fits, *, fitter: RegionFitter, config, sensor: Sensor,
                   ranges: np.ndarray, sigma: np.ndarray, tile: int):
    """After a run on tile means: recover, at full resolution, surfaces thinner than the tiles see.

    A table top seen at a grazing angle may be a band 5-15 pixels thick: under three 6x6
    tiles, so the tile grid's 3x3 window always straddles it, and the tile models leave
    its pixels unlabelled. Those leftovers are cut into compact blobs and fitted as in the
    ``recover`` step (a blob must be mostly one surface). At such angles every pixel step
    is a depth jump by the range test, so neither the blobs nor the 2-pixel rim their
    regions take back are limited by it: the model distance decides.
    """
    # Twice the smallest region: a piece of a surface the tiles already have, left over
    # where its model drifts from the noisy far pixels, is smaller; a surface the tiles
    # could not see at all is not.
    min_size = 2 * max(int(config.min_region_size), 10)
    first = int(labels.max(initial=0)) + 1
    candidates = leftover_candidates(labels, cloud.valid, np.zeros(labels.shape, bool),
                                     min_size=min_size, first_label=first)
    # Only what the tile grid could not see: blobs thinner than its 3x3 window (three
    # tiles). Thicker ones were leftovers of the tile grid too, and its own recovery has
    # had its say on them.
    inside = cv2.distanceTransform((candidates > 0).astype(np.uint8), cv2.DIST_L2, 3)
    half_width = np.zeros(int(candidates.max(initial=0)) + 1, np.float32)
    np.maximum.at(half_width, candidates.ravel(), inside.ravel())
    candidates = np.where(half_width[candidates] < 1.5 * tile, candidates, 0)
    if not candidates.any():
        return labels, fits
    ctx = _Context(cloud, fitter, sigma, min_size)
    labels, fits = ctx.explain(labels, fits, candidates, min_share=0.7)
    new = {k: m for k, m in fits.items() if k >= first and m}
    if new:
        from .fitstage import model_table
        from .kernels import claim_rings, member_pixels

        labels = grow_into_edges(cloud.xyz, labels, new, sigma, ranges, iterations=2,
                                 k_sigma=config.k_sigma, jump_ratio=np.inf, jump_min=np.inf)
        # the tile models took what they could explain before these regions existed
        n = int(labels.max(initial=0)) + 1
        kinds, params, rms = model_table(fits, n)
        challengers = np.zeros(n, bool)
        challengers[list(new)] = True
        rows, cols = np.divmod(member_pixels(labels, challengers), labels.shape[1])
        iterations = 3  # the box grows by the rings the challengers may take
        box = (rows.min() - iterations, rows.max() + iterations + 1,
               cols.min() - iterations, cols.max() + iterations + 1)
        claim_rings(np.ascontiguousarray(cloud.xyz.reshape(-1, 3)), labels, kinds, params, rms,
                    np.ascontiguousarray(sigma).ravel(), challengers, iterations, float(config.k_sigma),
                    np.array(box, np.int64))
        if config.merge:  # a recovered piece of a surface the tile grid already has
            claimed = member_pixels(labels, challengers)
            owner = labels.ravel()[claimed]
            regions = {k: claimed[owner == k] for k in np.unique(owner).tolist()}
            touching = {(min(k, j), max(k, j)) for k, idx in regions.items()
                        for j in _touching(labels, idx, reach=2) if j != k}
            labels, fits, _ = ctx.merge(labels, fits, config, touching, only=set(new))
    return labels, fits


def _blob_patch(idx: np.ndarray, shape: tuple[int, int], margin: int):
    """The flat pixels ``idx`` as a 0/1 uint8 patch of their bounding box grown by ``margin``
    (clipped to ``shape``); returns ``(patch, (top, left), (rows, cols))``."""
    rows, cols = np.divmod(idx, shape[1])
    top, left = max(rows.min() - margin, 0), max(cols.min() - margin, 0)
    bottom, right = min(rows.max() + margin + 1, shape[0]), min(cols.max() + margin + 1, shape[1])
    patch = np.zeros((bottom - top, right - left), np.uint8)
    patch[rows - top, cols - left] = 1
    return patch, (top, left), (rows, cols)


def _touching(labels: np.ndarray, idx: np.ndarray, reach: int) -> set[int]:
    # labels within ``reach`` pixels of the flat pixels ``idx`` (from a bounding-box patch)
    blob, (top, left), _ = _blob_patch(idx, labels.shape, reach)
    patch = labels[top:top + blob.shape[0], left:left + blob.shape[1]]
    near = cv2.dilate(blob, np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)).astype(bool)
    return {int(k) for k in np.unique(patch[near]) if k > 0}


class _Context:
    """What every refinement step needs: points, noise, the fitter, the size floor."""

    def __init__(self, cloud, fitter: RegionFitter, sigma: np.ndarray, min_size: int):
        self.xyz = cloud.xyz.reshape(-1, 3)
        self.sigma = sigma.ravel()
        self.width = cloud.shape[1]
        self.fitter = fitter
        self.min_size = min_size

    def _largest_piece(self, idx: np.ndarray) -> np.ndarray:
        # Inliers can be scattered over the grid; keep the largest 4-connected piece.
        from .kernels import largest_piece

        return largest_piece(np.ascontiguousarray(idx, dtype=np.int64), self.width)

    def split(self, labels, fits, failed: list[int]):
        """Split every region no single model explains into all the surfaces it holds.

        Sequential robust extraction with connectivity kept: the dominant surface of a
        connected pool of the region's pixels (:func:`rangeseg_o3d.robust.trimmed_fit`),
        cut to its largest 4-connected piece, becomes a region; the rest of the pool falls
        apart into its connected pieces, and each is searched in turn, until every piece
        is smaller than the size floor or no model explains enough of it. Regions leaking
        through creases the edge image missed (floor, walls and the objects on them in one)
        come back as one region per surface; what no surface takes (the crease bands) is
        freed for growth. A region of which nothing is explained keeps its failure
        (reported as unfitted).
        """
        flat = labels.ravel()
        regions = region_indices(np.where(np.isin(labels, failed), labels, 0))
        next_label = int(labels.max(initial=0)) + 1
        for k, idx in regions.items():
            label, found = k, False
            pools = self._pieces(idx)
            attempts = 0
            while pools and attempts < _MAX_SPLIT_ATTEMPTS:
                attempts += 1
                pool = pools.pop()  # the largest piece (pools are kept sorted by size)
                piece, model = self._dominant_piece(pool)
                if piece is None:
                    continue
                if not found:
                    flat[idx] = 0  # the failed region dissolves into what is found
                    found = True
                flat[piece] = label
                fits[label] = model
                label, next_label = next_label, next_label + 1
                pools.extend(self._pieces(pool[~np.isin(pool, piece, assume_unique=True)]))
                pools.sort(key=len)
        return labels, fits

    def _pieces(self, idx: np.ndarray) -> list[np.ndarray]:
        """The 4-connected pieces of the flat pixels ``idx`` with at least ``min_size``
        pixels, smallest first."""
        if idx.size < self.min_size:
            return []
        patch, (top, left), (rows, cols) = _blob_patch(idx, (idx.max() // self.width + 1, self.width), 0)
        n, comp = cv2.connectedComponents(patch, connectivity=4, ltype=cv2.CV_32S)
        ids = comp[rows - top, cols - left]
        order = np.argsort(ids, kind="stable")
        bounds = np.searchsorted(ids[order], np.arange(1, n + 1))
        pieces = [idx[order[a:b]] for a, b in zip(bounds[:-1], bounds[1:]) if b - a >= self.min_size]
        return sorted(pieces, key=len)

    def _dominant_piece(self, pool: np.ndarray):
        """The largest connected piece of the dominant surface of the flat pixels ``pool``
        and its model, or ``(None, None)`` when no model explains ``min_size`` of them."""
        if pool.size < self.min_size:
            return None, None
        noise = self.sigma[pool]
        model, inliers = trimmed_fit(self.xyz[pool], self.fitter.fit,
                                     sigma=float(np.partition(noise, noise.size // 2)[noise.size // 2]),
                                     min_points=self.min_size)
        if model is None:
            return None, None
        piece = self._largest_piece(pool[inliers])
        if piece.size < self.min_size:
            return None, None
        if piece.size < 0.9 * inliers.sum():  # a piece was cut off: fit the piece itself
            model = self.fitter.refit(self.fitter.points(self.xyz, piece), model)
        return (piece, model) if model else (None, None)

    def explain(self, labels, fits, candidates, *, min_share: float):
        """Give each candidate blob the model most of it lies on; free the other pixels.

        Blobs nothing explains, or whose explained share is below ``min_share``, are dropped.
        """
        flat = labels.ravel()
        regions = region_indices(candidates)
        # One batched pass settles the candidates that are planes outright.
        settled = self.fitter.fit_batch(self.xyz, candidates) if regions else {}
        for k, idx in regions.items():
            flat[idx] = 0
            fits.pop(k, None)
            # A blob that is one plane needs no trimming (settled in the batch); for the
            # others the trimmed fit's first answer is the plain fit's when it is clean.
            plain = settled.get(k)
            near = None
            if plain:
                near = np.abs(plain.distances(self.xyz[idx])) <= 3.0 * np.maximum(self.sigma[idx], plain.rms)
            if near is not None and near.mean() >= 0.9:
                chosen, model = self._largest_piece(idx[near]), plain
                if chosen.size < 0.9 * near.sum():  # a piece was cut off: fit the piece itself
                    model = self.fitter.refit(self.fitter.points(self.xyz, chosen), plain)
            else:
                chosen, model = self._dominant_piece(idx)
            if chosen is not None and model and chosen.size >= max(self.min_size, min_share * idx.size):
                flat[chosen] = k
                fits[k] = model
        return labels, fits

    def refit_grown(self, labels, grown, fits):
        """Refit regions that grew by more than 5 % where moments suffice (planes); a refit
        must keep the kind. Other models keep their parameters until :meth:`polish` and
        take the rms of their grown pixels, which later steps compare."""
        before = np.bincount(labels.ravel(), minlength=grown.max(initial=0) + 1)
        after = np.bincount(grown.ravel(), minlength=before.size)
        changed = [int(k) for k in np.flatnonzero(after > 1.05 * np.maximum(before, 1)) if k > 0]
        refits = self.fitter.refit_regions(self.xyz, grown, fits, changed, from_points=False)
        for k, refit in refits.items():
            if refit and refit.kind == fits[k].kind:
                fits[k] = refit
        stale = {k: fits[k] for k in changed if k not in refits and fits.get(k)}
        fits.update(pixel_rms(self.xyz, grown, stale, self.sigma))
        return grown, fits

    def polish(self, labels, fits):
        """Refit the models that moments cannot refit (spheres, cylinders) on their final pixels.

        Only where the region outgrew the points the model was fitted to by more than 20 %
        (a model's ``inliers`` counts those): a few more pixels move nothing.
        """
        sizes = np.bincount(labels.ravel(), minlength=max(fits, default=0) + 1)
        curved = [k for k, m in fits.items()
                  if m and not isinstance(m, Plane) and sizes[k] > 1.2 * max(m.inliers, 1)]
        for k, refit in self.fitter.refit_regions(self.xyz, labels, fits, curved, from_moments=False).items():
            if refit and refit.kind == fits[k].kind:
                fits[k] = refit
        return labels, fits

    def merge(self, labels, fits, config, adjacency: set, only: set | None = None):
        """Merge same-kind regions whose union one model explains (union-find over candidates).

        Planes are tried from summed label-wise moments (no point is touched); other kinds
        refit the union's points. With ``only``, just pairs involving those labels.
        """
        good = {k: m for k, m in fits.items() if m}
        pairs = merge_candidates(good, max_angle_deg=config.merge_angle_deg,
                                 tolerance=config.merge_tolerance,
                                 adjacency=adjacency, disjoint=config.merge_disjoint)
        if only is not None:
            pairs = [(a, b) for a, b in pairs if a in only or b in only]
        if not pairs:
            return labels, fits, adjacency
        moments = self.fitter.moments(self.xyz, labels)
        root = {k: k for k in fits}

        def find(k):
            while root[k] != k:
                k = root[k]
            return k

        cache: dict = {}

        def add_unions(rest):
            # The unions of the remaining pairs of current roots not yet known, from summed
            # moments in one call; None where the kind needs its points (or no moments).
            keys = []
            for a, b in rest:
                key = (find(a), find(b))
                if key[0] != key[1] and key not in cache and fits.get(key[0]) and fits.get(key[1]):
                    keys.append(key)
            if moments is None or not keys:
                cache.update(dict.fromkeys(keys))
                return
            a_idx, b_idx = np.array(keys).T
            rows = moments[a_idx] + moments[b_idx]
            # No plane fits a union better than its least-squares plane: where that is over
            # the merge limit, the refit (and its model) is not needed. Most adjacent planes
            # meet at creases and end here.
            planar = np.array([isinstance(fits[a], Plane) and isinstance(fits[b], Plane) for a, b in keys])
            if planar.any():
                limits = config.merge_rms_factor * np.maximum([fits[a].rms for a, _ in keys],
                                                              [fits[b].rms for _, b in keys])
                hopeless = planar & (planes_from_moments(rows).rms > limits)
                cache.update((key, _NO_UNION) for key, no in zip(keys, hopeless.tolist()) if no)
                keys = [key for key, no in zip(keys, hopeless.tolist()) if not no]
                rows = rows[~hopeless]
            if keys:
                cache.update(zip(keys, self.fitter.refit_from_moments(rows, [fits[a] for a, _ in keys])))

        add_unions(pairs)
        regions = None
        for i, (a, b) in enumerate(pairs):
            ra, rb = find(a), find(b)
            if ra == rb or not fits[ra] or not fits[rb]:
                continue
            if (ra, rb) not in cache:  # a part merged since: its pairs' unions are new
                add_unions(pairs[i:])
            union = cache.get((ra, rb))
            if union is None:
                if regions is None:
                    regions = region_indices(labels)
                union_idx = np.concatenate([regions[ra], regions[rb]])
                union = self.fitter.refit(self.fitter.points(self.xyz, union_idx), fits[ra])
            limit = config.merge_rms_factor * max(fits[ra].rms, fits[rb].rms)
            if union and union.kind == fits[ra].kind and union.rms <= limit:
                root[rb] = ra
                fits[ra] = union
                fits.pop(rb)
                for key in [key for key in cache if ra in key or rb in key]:
                    del cache[key]
                if moments is not None:
                    moments[ra] += moments[rb]
                if regions is not None:
                    regions[ra] = np.concatenate([regions[ra], regions.pop(rb)])
        lut = np.arange(int(labels.max(initial=0)) + 1, dtype=np.int32)
        for k in root:
            lut[k] = find(k)
        # merged regions touch whatever their parts touched
        mapped = ((int(lut[a]), int(lut[b])) for a, b in adjacency)
        adjacency = {(min(a, b), max(a, b)) for a, b in mapped if a != b}
        return lut[labels], fits, adjacency

    def dissolve(self, labels, fits, k_sigma: float, adjacency: set):
        """Hand small regions to larger neighbours whose surfaces already explain them.

        A blob where surfaces meet can pass for a small curved patch; its kind differs from
        its neighbours', so :meth:`merge` never pairs it. When at least 80 % of a region
        smaller than ``3 * min_size`` lies within ``k_sigma max(sigma, rms)`` of larger
        neighbours' models, each such point joins the neighbour that explains it best and
        the rest become unlabelled; the neighbours are refitted.
        """
        sizes = np.bincount(labels.ravel())
        if not np.any((sizes[1:] > 0) & (sizes[1:] < 3 * self.min_size)):
            return labels, fits
        regions = region_indices(labels)
        small_ones = [k for k in regions if regions[k].size < 3 * self.min_size]
        neighbours: dict[int, set[int]] = {}
        for a, b in adjacency:
            neighbours.setdefault(a, set()).add(b)
            neighbours.setdefault(b, set()).add(a)
        changed = set()
        flat = labels.ravel()
        for small in sorted(small_ones, key=lambda k: regions[k].size):
            idx = regions.get(small)
            hosts = [k for k in neighbours.get(small, ()) if k in regions and fits.get(k)
                     and regions[k].size > idx.size]
            if not hosts:
                continue
            pts = self.xyz[idx]
            score = np.stack([
                np.abs(fits[k].distances(pts)) / np.maximum(self.sigma[idx], fits[k].rms)
                for k in hosts
            ])
            best = np.argmin(score, axis=0)
            explained = score[best, np.arange(idx.size)] <= k_sigma
            if explained.mean() < 0.8:
                continue
            new_labels = np.where(explained, np.asarray(hosts)[best], 0)
            flat[idx] = new_labels
            for k in set(new_labels[explained].tolist()):
                regions[k] = np.concatenate([regions[k], idx[new_labels == k]])
                changed.add(k)
            del regions[small]
            fits.pop(small, None)
        # planes now; spheres and cylinders in polish
        for k, refit in self.fitter.refit_regions(
                self.xyz, labels, fits, [k for k in changed if k in regions], from_points=False).items():
            if refit:
                fits[k] = refit
        return labels, fits
