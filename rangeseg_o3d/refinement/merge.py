"""Step 5, ``merge``: regions of one kind whose union one model explains as well as the parts are merged.

The paper's "merging of patches that belong to the same surface" (Sec. 6). Candidates are
pairs of adjacent regions of one kind, and with ``merge_disjoint`` regions apart whose
parameters agree; cheap tests first (summed moments, the union's least-squares plane),
the fitter decides.
"""

from __future__ import annotations

import numpy as np

from .. import kernels  # the package: its names load on first use (no compiler at import)
from .._numeric import median, rows_at, unique_ints
from ..fitting.batch_planes import plane_rms_from_moments, planes_from_moments
from ..fitting.classify import refit_planes_from_moments
from ..fitting.primitives import Cylinder, FitFailure, Plane, Sphere, squared_distances
from ..fitting.region_fitter import model_row, region_indices
from ..fitting.robust import CHI_SQUARE_SIGMAS, beyond_noise, curvature_resolved, union_out_of_reach
from ..kernels.linalg import NOISE_CHI2_SIGMAS, noise_rms_bound
from ..scales import GRAZING_COSINE
from .context import SCREEN_SLACK, TRIM_SIGMAS, Context
from .grid_lines import lines_across
from .sight import seen_past_plane

__all__ = ["curved_pairs_apart", "merge_regions", "merge_into_curved", "merge_candidates", "pieces_near",
           "region_adjacency", "region_adjacency_matrix", "similar_models", "beyond_median_noise"]

#: The smaller part of a union of planes, turned from it, lies on the union's plane within
#: this many times the merge's rms limit (rms of its points): a piece of a rippled face a
#: millimetre off, yes; a small face a few millimetres off, no.
PART_SIGMAS = 5.0
#: Two planes' pieces apart are two surfaces a step apart, not one, when the smaller piece's
#: mean lies off the larger's plane by more than this many times the scatter of its own
#: samples (its plane's rms, at least their distance noise: range noise times the incidence
#: cosine): then hardly a sample of it lies within the larger's band. Two box tops 2 cm apart
#: seen near grazing at 3.6 m are 7-8 of them apart on a Kinect's tile grid (13-19 distance
#: noises), while the pieces of one surface the study seeds join lie within 3 (a nodding
#: laser's floor seen near grazing scatters several distance noises: the beam's footprint).
#: One sample's scatter, not the noise of a mean: a real wall's pieces lie a fraction of a
#: millimetre apart, systematically, which the noise of a mean of thousands would call a step.
STEP_SIGMAS = 5.0
# the merge's answer for a union of planes whose least-squares plane is over the merge limit
_NO_UNION = FitFailure("plane", "the union's least-squares plane rms is over the merge limit")


def _shifted(array: np.ndarray, dy: int, dx: int, fill) -> np.ndarray:
    # out[i, j] = array[i + dy, j + dx], ``fill`` outside the grid.
    out = np.full_like(array, fill)
    h, w = array.shape[:2]
    ys, yd = (slice(dy, h), slice(0, h - dy)) if dy >= 0 else (slice(0, h + dy), slice(-dy, h))
    xs, xd = (slice(dx, w), slice(0, w - dx)) if dx >= 0 else (slice(0, w + dx), slice(-dx, w))
    out[yd, xd] = array[ys, xs]
    return out


def region_adjacency(labels: np.ndarray, *, reach: int = 2, wrap_columns: bool = False) -> set[tuple[int, int]]:
    """Pairs (a < b) of regions whose pixels come within ``reach`` pixels of each other.

    With ``wrap_columns`` (a 360-degree grid) the first and last columns are neighbours too.
    """
    if wrap_columns and labels.shape[1] > 2 * reach:
        return region_adjacency(labels, reach=reach) | region_adjacency(_seam(labels, reach), reach=reach)
    n = int(labels.max(initial=0)) + 1
    if n <= ADJACENCY_MATRIX_LABELS:  # an n x n matrix stays small; beyond, collect pairs per shift
        # the matrix is symmetric with an empty diagonal: its pairs a < b are np.triu's,
        # without building the triangle's n x n mask
        a, b = np.nonzero(region_adjacency_matrix(labels, n, reach=reach))
        upper = a < b
        return set(zip(a[upper].tolist(), b[upper].tolist()))
    pairs = set()
    for dy in range(-reach, reach + 1):
        for dx in range(0, reach + 1):
            if (dx == 0 and dy <= 0):
                continue
            other = _shifted(labels, dy, dx, 0)
            touch = (labels > 0) & (other > 0) & (labels != other)
            if touch.any():
                a, b = labels[touch], other[touch]
                codes = unique_ints(np.minimum(a, b).astype(np.int64) << 32 | np.maximum(a, b))
                pairs.update((int(c >> 32), int(c & 0xFFFFFFFF)) for c in codes)
    return pairs


#: The most labels (the largest label + 1) whose adjacency is an (n, n) matrix.
ADJACENCY_MATRIX_LABELS = 4096


def region_adjacency_matrix(labels: np.ndarray, n: int, *, reach: int = 2, wrap_columns: bool = False) -> np.ndarray:
    """(n, n) bool, symmetric: regions ``a != b`` (both > 0, below ``n``) whose pixels come
    within ``reach`` pixels of each other, as :func:`region_adjacency`'s pairs (with
    ``wrap_columns`` the first and last columns are neighbours too)."""
    adjacency = kernels.adjacency_matrix(np.ascontiguousarray(labels, dtype=np.int32), n, reach)
    if wrap_columns and labels.shape[1] > 2 * reach:
        adjacency |= kernels.adjacency_matrix(np.ascontiguousarray(_seam(labels, reach), dtype=np.int32), n, reach)
    return adjacency


def _seam(labels: np.ndarray, reach: int) -> np.ndarray:
    # a 360-degree grid's seam as a strip: the last ``reach`` columns, then the first ``reach``
    return np.concatenate([labels[:, -reach:], labels[:, :reach]], axis=1)


def _angle_deg(u: np.ndarray, v: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(abs(float(u @ v)), 0.0, 1.0))))


def similar_models(a, b, *, max_angle_deg: float, tolerance: float) -> bool:
    """Cheap pre-test: could ``a`` and ``b`` be the same surface (before fitting the union)?"""
    if a.kind != b.kind:
        return False
    if isinstance(a, Plane):
        sign = 1.0 if float(a.normal @ b.normal) >= 0 else -1.0
        return (_angle_deg(a.normal, b.normal) <= max_angle_deg
                and abs(a.d - sign * b.d) <= tolerance)
    # A piece of a pipe or ball is seen from one side: its pixels fix the surface they lie
    # on, and a fit that errs in the radius by dR moves the axis (centre) by about dR along
    # the line of sight, the visible surface staying put. The axes (centres) are therefore
    # compared within the tolerance plus the radii's difference; the radii themselves
    # within the smaller one (the same size class: a pipe's radius from a short piece errs
    # by tens of percent, not by a factor of two). The union fit decides.
    if abs(a.radius - b.radius) > max(tolerance, min(a.radius, b.radius)):
        return False
    reach = tolerance + abs(a.radius - b.radius)
    if isinstance(a, Cylinder):
        # the axis of the piece fitted to more points passes within reach of the other's
        # point (the axis point nearest its region): two pieces of one pipe seen apart agree
        # where their pixels are, though the axis of a short or noisy piece is known only to
        # several degrees, which carried along the pipe to the other piece misses it (kinect
        # seed 1043 scan 4: a column at 4.4 m cut by a box before it, 7247 and 1505 px, axes
        # 2.9 degrees apart: 6 cm off one metre away); pieces of one size: both axes
        rel = b.point - a.point
        axes = (a.axis,) if a.inliers > b.inliers else (b.axis,) if b.inliers > a.inliers else (a.axis, b.axis)
        return all(bool(np.linalg.norm(rel - (rel @ axis) * axis) <= reach) for axis in axes)
    if isinstance(a, Sphere):
        return bool(np.linalg.norm(a.center - b.center) <= reach)
    return False


def pieces_on_planes(normals: np.ndarray, offsets: np.ndarray, rms: np.ndarray,
                     moments: np.ndarray, rms_factor: float, noise: np.ndarray | None = None) -> np.ndarray:
    """(K, K) bool: the points of the smaller region of a pair of planes lie on the larger's
    plane within ``rms_factor`` times the larger of their rms (from label-wise moments:
    no point is touched).

    A thin strip of a wall seen between two columns has a normal its few pixels across
    hardly determine, so comparing normals rejects it; the mean square distance of its
    points to the wall's plane, ``(sum (n.x)^2 - 2 d sum n.x + N d^2) / N``, does not
    depend on its own fit. Those are exactly the pairs whose union passes the merge's rms
    test whatever the parts' normals. With ``noise`` (each row's mean range noise) the
    smaller piece may also lie within what that noise alone leaves a plane fitted to as
    many points (:func:`rangeseg_o3d.kernels.linalg.noise_rms_bound`, up its chi-square,
    as the fitter's plane tolerance): the fits of a few tens of pixels fall under the noise,
    and a strip of a wall with a mixed pixel or two at a jump lies off the wall's plane by
    a fraction of a millimetre more than 1.3 times them. That bound is not widened by
    ``rms_factor`` (on a 3 cm lidar 1.3 times it took a 34-pixel piece of another face).
    """
    count = np.maximum(moments[:, 0], 1.0)
    sums = moments[:, 1:4]
    second = moments[:, [4, 5, 6, 5, 7, 8, 6, 8, 9]].reshape(-1, 3, 3)
    # msd[i, j]: mean square distance of region i's points to plane j
    projected = np.einsum("ja,iab,jb->ij", normals, second, normals)
    along = sums @ normals.T
    msd = (projected - 2.0 * offsets[None, :] * along + count[:, None] * offsets[None, :] ** 2) / count[:, None]
    limit = (rms_factor * np.maximum(rms[:, None], rms[None, :])) ** 2
    if noise is not None:
        # row i (the smaller piece of the pair) also within its own noise's bound
        floor = noise_rms_bound.py_func(noise, count - 3.0, NOISE_CHI2_SIGMAS)
        limit = np.maximum(limit, (floor ** 2)[:, None])
    smaller = count[:, None] <= count[None, :]
    on = smaller & (msd <= limit)
    return on | on.T


def _mean_square_distances(moments: np.ndarray, normal: np.ndarray, d: float) -> np.ndarray:
    """Mean square distance of each row's points (label-wise moments: count, sums, second
    moments xx xy xz yy yz zz) to the plane ``normal . p = d``, no point touched."""
    count = np.maximum(moments[:, 0], 1.0)
    second = moments[:, [4, 5, 6, 5, 7, 8, 6, 8, 9]].reshape(-1, 3, 3)
    projected = np.einsum("a,iab,b->i", normal, second, normal)
    along = moments[:, 1:4] @ normal
    return (projected - 2.0 * d * along + count * d * d) / count


def merge_candidates(models: dict, *, max_angle_deg: float, tolerance: float,
                     adjacency: set[tuple[int, int]], disjoint: bool = True,
                     moments: np.ndarray | None = None, rms_factor: float = 1.3,
                     noise: np.ndarray | None = None) -> list[tuple[int, int]]:
    """Pairs of labels worth a union fit, cheapest first (by the parts' rms sum).

    Adjacent regions of one kind are always candidates: two pieces of one small cylinder
    can disagree on their axes more than any parameter test would allow, and the union
    fit decides. Regions that do not touch are candidates only with ``disjoint`` and when
    :func:`similar_models` says their parameters agree, or, for planes with the regions'
    label-wise ``moments`` (row = label), when the smaller one's points lie on the larger
    one's plane (:func:`pieces_on_planes` with ``rms_factor`` and ``noise``, each label's
    mean range noise by row as the moments, optional).
    """
    keys = sorted(models)
    out = []
    planes = [k for k in keys if isinstance(models[k], Plane)]
    if len(planes) > 1:
        # planes: every pair's tests in one compiled pass
        normals = np.array([models[k].normal for k in planes])
        offsets = np.array([float(models[k].d) for k in planes])
        rows, own_noise = np.zeros((len(planes), 10)), np.zeros(len(planes))
        if moments is not None and disjoint:
            inside = np.array(planes) < len(moments)
            rows[inside] = moments[np.array(planes)[inside]]
            if noise is not None:
                own_noise[inside] = noise[np.array(planes)[inside]]
        position = {k: i for i, k in enumerate(planes)}
        adjacent = np.array([(position[a], position[b]) for a, b in adjacency if a in position and b in position],
                            dtype=np.int64).reshape(-1, 2)
        first, second = kernels.plane_candidates(
            normals, offsets, np.array([float(models[k].rms) for k in planes]), rows, own_noise,
            adjacent[:, 0].copy(), adjacent[:, 1].copy(), float(np.cos(np.radians(max_angle_deg)) - 1e-12),
            float(tolerance), bool(disjoint), moments is not None and disjoint, noise is not None,
            float(rms_factor))
        out.extend((planes[i], planes[j]) for i, j in zip(first.tolist(), second.tolist()))
    others = [k for k in keys if not isinstance(models[k], Plane)]
    for i, a in enumerate(others):
        for b in others[i + 1:]:
            if models[a].kind != models[b].kind:
                continue
            if (a, b) in adjacency or (disjoint and similar_models(
                    models[a], models[b], max_angle_deg=max_angle_deg, tolerance=tolerance)):
                out.append((a, b))
    rms = {k: models[k].rms for k in keys}
    out.sort(key=lambda ab: (rms[ab[0]] + rms[ab[1]], ab))
    return out


def merge_regions(ctx: Context, labels: np.ndarray, fits: dict, adjacency: set, *,
                  max_angle_deg: float, tolerance: float, disjoint: bool, rms_factor: float,
                  only: set | None = None, held: set | None = None, steps_between_touching: bool = False):
    """Merge same-kind regions whose union one model explains (union-find over candidates).

    A union is accepted when its model keeps the kind and its rms is at most
    ``rms_factor`` times the larger of the parts'. Planes are tried from summed label-wise
    moments (no point is touched); other kinds refit the union's points. With ``only``,
    just pairs involving those labels. A pair ``(a < b)`` in ``held`` (a region found on
    pixels that lay, as a group, off the other's plane) merges only when, besides, the
    smaller part's mean distance to the union's plane is within the noise of a mean
    (:meth:`_Unions.part_centred`). Returns new ``(labels, fits, adjacency)``: merged
    regions touch whatever their parts touched. Over the whole grid (no ``only``), a plane
    apart is a candidate as far as its own range noise allows (:func:`pieces_on_planes`'
    ``noise``, each label's mean); the recovery's merge of the pieces it found (``only``),
    which holds them to the noise of their distances itself, does not pay a pass over the
    frame's noise for it. With ``steps_between_touching``, pieces that touch are held to
    :meth:`_Unions.no_step` too, as pieces apart are (see
    :func:`rangeseg_o3d.refinement._merge_turned_by_polish`).
    """
    fits = dict(fits)
    good = {k: m for k, m in fits.items() if m}
    # Moments serve pairs of planes only: with ``only`` holding no plane, every pair left is
    # refitted from its points, and the pass over the pixels for them is not needed.
    with_moments = only is None or any(isinstance(fits.get(k), Plane) for k in only)
    unions = _Unions(ctx, labels, fits, rms_factor, with_moments=with_moments)
    pairs = merge_candidates(good, max_angle_deg=max_angle_deg, tolerance=tolerance,
                             adjacency=adjacency, disjoint=disjoint,
                             moments=unions.moments if disjoint else None, rms_factor=rms_factor,
                             noise=_mean_noise(ctx, labels, unions.moments)
                             if disjoint and only is None and unions.moments is not None else None)
    if only is not None:
        pairs = [(a, b) for a, b in pairs if a in only or b in only]
    if disjoint:
        pairs = _in_sight(ctx, labels, fits, pairs, adjacency)
    if not pairs:
        return labels, fits, adjacency
    # the pairs that need not show no step between them: those that touch, unless asked
    step_exempt = frozenset() if steps_between_touching else adjacency
    if unions.plane_pairs_compiled(pairs):
        # pairs of planes join only planes and other pairs only their own kind: the planes'
        # loop runs apart, in their order (one compiled pass), the others' below
        planes = {k for k, m in fits.items() if isinstance(m, Plane)}
        planar = [a in planes and b in planes for a, b in pairs]  # (_both_planes of each pair)
        unions.merge_planes([pair for pair, flat in zip(pairs, planar) if flat], held or set(), max_angle_deg,
                            step_exempt)
        pairs = [pair for pair, flat in zip(pairs, planar) if not flat]
        if not pairs:
            lut = unions.lookup()
            return _relabelled(labels, lut), fits, _mapped_adjacency(adjacency, lut)
    unions.add(pairs)
    for a, b in pairs:
        ra, rb = unions.find(a), unions.find(b)
        if ra == rb or not fits[ra] or not fits[rb]:
            continue
        # a part merged since: this union is new (each other new one is computed on its
        # turn, from the same moments: the parts' rows change only when they merge)
        if (ra, rb) not in unions.cache:
            unions.add([(ra, rb)])
        union = unions.model(ra, rb)
        if union is not _NO_UNION and not union and isinstance(fits[ra], Plane) and isinstance(fits[rb], Plane):
            union = unions.plane_within_larger(ra, rb)
        limit = rms_factor * max(fits[ra].rms, fits[rb].rms)
        # the union against its parts' current pixels (part_rms); a part off the union's
        # plane against the models' own limit (parts_on)
        if (union and union.kind == fits[ra].kind
                and union.rms <= rms_factor * max(unions.part_rms(ra), unions.part_rms(rb))
                and unions.parts_on(ra, rb, union, limit, max_angle_deg)
                and unions.curved_parts_on(ra, rb, union)
                and ((a, b) not in (held or ()) or unions.part_centred(ra, rb, union))
                and ((a, b) in step_exempt or unions.no_step(ra, rb, union))):
            unions.join(ra, rb, union)
    lut = unions.lookup()
    return _relabelled(labels, lut), fits, _mapped_adjacency(adjacency, lut)


def _in_sight(ctx: Context, labels: np.ndarray, fits: dict, pairs: list, adjacency) -> list:
    """``pairs`` but those of two planes apart between which the camera sees past the
    larger's plane (:func:`rangeseg_o3d.refinement.sight.seen_past_plane`, the smaller
    region the piece, ``TRIM_SIGMAS``): two box tops of one height with the floor seen
    between them, a face and a pipe far behind it on its plane's extension, are two
    surfaces; a wall's pieces either side of a column in front of it stay a pair."""
    apart = [(a, b) for a, b in pairs if (a, b) not in adjacency and isinstance(fits[a], Plane)
             and isinstance(fits[b], Plane)]
    if not apart:
        return pairs
    pixels = region_indices(labels, only={k for pair in apart for k in pair})
    refused = set()
    for a, b in apart:
        if a not in pixels or b not in pixels:
            continue
        small, large = sorted((a, b), key=lambda k: (pixels[k].size, k))
        if seen_past_plane(ctx.xyz, ctx.sigma, labels, pixels[small], large, fits[large], TRIM_SIGMAS,
                           members=pixels[large], wrap_columns=ctx.wrap_columns):
            refused.add((a, b))
    return [pair for pair in pairs if pair not in refused] if refused else pairs


def _both_planes(fits: dict, pair) -> bool:
    return isinstance(fits.get(pair[0]), Plane) and isinstance(fits.get(pair[1]), Plane)


def _noise_sums(ctx: Context, labels: np.ndarray, rows: int) -> np.ndarray:
    # each label's summed range noise, ``rows`` rows (row = label, as the moments): one
    # compiled pass, the sums of np.bincount over the finite noise, to the bit
    flat = labels.ravel()
    if flat.dtype != np.int32:  # (the label images' type: one compiled signature)
        flat = flat.astype(np.int32)
    return kernels.label_noise_sums(np.ascontiguousarray(flat), np.ascontiguousarray(ctx.sigma.ravel(), dtype=np.float64),
                                    int(rows))


def _mean_noise(ctx: Context, labels: np.ndarray, moments: np.ndarray) -> np.ndarray:
    # each label's mean range noise (row = label, as the moments)
    return _noise_sums(ctx, labels, len(moments)) / np.maximum(moments[:, 0], 1.0)


def _mapped_adjacency(adjacency, lut: np.ndarray) -> set[tuple[int, int]]:
    """The pairs ``(a, b)`` of ``adjacency`` as ``(min, max)`` of ``(lut[a], lut[b])``, pairs
    the lookup makes one label dropped: the regions merged regions touch."""
    # Python ints from one list: indexing the array per label costs more than the pairs' work
    table = lut.tolist()
    out = set()
    for a, b in adjacency:
        first, second = table[a], table[b]
        if first < second:
            out.add((first, second))
        elif second < first:
            out.add((second, first))
    return out


def _relabelled(labels: np.ndarray, lut: np.ndarray) -> np.ndarray:
    # lut[labels] (a new int32 array); a copy when no union changed a label, one compiled
    # pass for a label image, instead of numpy's gather over the frame
    if np.array_equal(lut, np.arange(lut.size)):
        return labels.astype(np.int32)
    if labels.ndim == 2 and labels.dtype == np.int32:
        return kernels.relabel(labels, lut)
    return lut[labels]


class _Unions:
    """Union-find over the labels of ``fits`` (which it updates: a root holds its union's
    model) and the models of candidate unions, cached until a part merges."""

    def __init__(self, ctx: Context, labels: np.ndarray, fits: dict, rms_factor: float, *,
                 with_moments: bool = True):
        self.ctx, self.labels, self.fits, self.rms_factor = ctx, labels, fits, rms_factor
        # None: the fitter needs points (or no pair of planes is wanted)
        self.moments = ctx.fitter.moments(ctx.xyz, labels) if with_moments else None
        self.root = {k: k for k in fits}
        self.cache: dict = {}
        self.regions = None  # flat pixels per label, gathered when a union needs its points
        self.paired: set = set()  # the labels of the candidate pairs (add)
        self.current_rms: dict = {}  # plane roots: the rms of their current pixels' plane (part_rms)
        self.points: dict = {}  # curved roots: their current pixels' points (part_rms, curved_parts_on)
        self.noise = None  # each label's summed range noise, when a union needs it (plane_within_larger)

    def find(self, k: int) -> int:
        while self.root[k] != k:
            k = self.root[k]
        return k

    def add(self, pairs) -> None:
        """Cache the unions of ``pairs``' current roots not yet known, from summed moments in
        one call; None where the kind needs its points (or there are no moments)."""
        fits = self.fits
        keys = []
        self.paired.update(k for pair in pairs for k in pair)
        for a, b in pairs:
            key = (self.find(a), self.find(b))
            if key[0] != key[1] and key not in self.cache and fits.get(key[0]) and fits.get(key[1]):
                keys.append(key)
        if self.moments is None or not keys:
            self.cache.update(dict.fromkeys(keys))
            return
        if len(keys) == 1:  # the merge loop's new unions come one at a time
            self._add_one(*keys[0])
            return
        a_idx, b_idx = np.array(keys).T
        rows = self.moments[a_idx] + self.moments[b_idx]
        # No plane fits a union better than its least-squares plane: where that is over
        # the merge limit, the refit (and its model) is not needed. Most adjacent planes
        # meet at creases and end here.
        planar = np.array([isinstance(fits[a], Plane) and isinstance(fits[b], Plane) for a, b in keys])
        if planar.any():
            # the parts' current planes not known yet, in the same call as the unions' (each
            # row's plane is computed alone: the same values as a call per row)
            parts = sorted({k for key, flat in zip(keys, planar.tolist()) if flat for k in key
                            if k not in self.current_rms and k < len(self.moments)})
            union_rms = planes_from_moments(np.concatenate([rows, self.moments[parts]]) if parts else rows).rms
            self.current_rms.update(zip(parts, union_rms[len(rows):].tolist()))
            limits = self.rms_factor * np.maximum([self.part_rms(a) for a, _ in keys],
                                                  [self.part_rms(b) for _, b in keys])
            hopeless = planar & (union_rms[:len(rows)] > limits)
            self.cache.update((key, _NO_UNION) for key, no in zip(keys, hopeless.tolist()) if no)
            keys = [key for key, no in zip(keys, hopeless.tolist()) if not no]
            rows = rows[~hopeless]
        if keys:
            self.cache.update(zip(keys, self.ctx.fitter.refit_from_moments(rows, [fits[a] for a, _ in keys])))

    def _add_one(self, a: int, b: int) -> None:
        # add() for one union of roots with moments, in scalars: the same tests and values
        # (a row's plane is computed alone whatever the call holds) without numpy's
        # per-call overhead on one-element arrays
        fits = self.fits
        row = self.moments[a] + self.moments[b]
        if isinstance(fits[a], Plane) and isinstance(fits[b], Plane):
            parts = [k for k in (a, b) if k not in self.current_rms and k < len(self.moments)]
            rms = plane_rms_from_moments(np.array([row, *(self.moments[k] for k in parts)])).tolist()
            self.current_rms.update(zip(parts, rms[1:]))
            limit = self.rms_factor * np.maximum(self.part_rms(a), self.part_rms(b))
            if rms[0] > limit:
                self.cache[(a, b)] = _NO_UNION
                return
        self.cache[(a, b)] = self.ctx.fitter.refit_from_moments(row[None, :], [fits[a]])[0]

    def plane_pairs_compiled(self, pairs) -> bool:
        """Whether :meth:`merge_planes` can take the pairs of planes among ``pairs``: the
        union-find is fresh, every plane has its moments and the fitter refits planes from
        moments as :func:`rangeseg_o3d.fitting.classify.refit_planes_from_moments` does."""
        return (self.moments is not None and not self.cache and self.noise is None
                and all(root == k for k, root in self.root.items())
                and self.ctx.fitter.plugin.refit_moments is refit_planes_from_moments
                and any(_both_planes(self.fits, pair) for pair in pairs)
                and max(max(pair) for pair in pairs) < len(self.moments))

    def merge_planes(self, pairs, held, max_angle_deg: float, step_exempt=frozenset()) -> None:
        """merge_regions' loop over ``pairs`` of planes (in order): the same tests as
        :meth:`model`, :meth:`plane_within_larger`, :meth:`parts_on` and
        :meth:`part_centred` on the same values, the parts joined as :meth:`join` does, in one
        compiled pass (:func:`rangeseg_o3d.kernels.merge_plane_pairs`). ``held``: the pairs
        held as merge_regions' ``held``; the pairs not in ``step_exempt`` (merge_regions': the
        touching ones, unless it holds those to the step test too) are held to :meth:`no_step`."""
        n = len(self.moments)
        keys = sorted({k for pair in pairs for k in pair})
        normal, d, rms, count = np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros(n)
        models = [self.fits[k] for k in keys]
        # each table filled in one assignment from the models' values (per label and
        # field a numpy item assignment costs more than the pair loop itself)
        normal[keys] = [model.normal for model in models]
        d[keys] = [model.d for model in models]
        rms[keys] = [model.rms for model in models]
        count[keys] = [model.inliers for model in models]
        root = np.arange(n, dtype=np.int64)
        first, second = np.array(pairs, dtype=np.int64).reshape(-1, 2).T.copy()
        flat = self.labels.ravel()
        if flat.dtype != np.int32:  # (the label images' type: one compiled signature)
            flat = flat.astype(np.int32)
        params = self.ctx.fitter.params
        joined = kernels.merge_plane_pairs(
            first, second, np.array([pair in held for pair in pairs], dtype=np.bool_),
            np.array([pair not in step_exempt for pair in pairs], dtype=np.bool_), self.moments,
            normal, d, rms, count, root, np.ascontiguousarray(flat),
            np.ascontiguousarray(self.ctx.sigma.ravel(), dtype=np.float64), float(self.rms_factor),
            float(max_angle_deg), PART_SIGMAS, float(params["plane_rms"]), float(params["rms_per_range2"]),
            int(params["min_points"]), float(params["noise_floor"]), STEP_SIGMAS, GRAZING_COSINE)
        roots, joined = root.tolist(), joined.tolist()
        for k in keys:
            if roots[k] != k:
                self.root[k] = roots[k]
                self.fits.pop(k)
            elif joined[k]:
                self.fits[k] = Plane(normal=normal[k], d=float(d[k]), rms=float(rms[k]), inliers=int(count[k]))

    def part_rms(self, k: int) -> float:
        """The rms a union of root ``k`` is compared with: the larger of its model's and
        that of its current pixels (growth adds pixels without a refit, so the model's rms
        can be that of fewer, quieter pixels than the union's, which holds them all): for a
        plane with moments their least-squares plane's; for a curved model its distances
        to them (a pipe's tile model carried to its pixels, a flank recovered at full
        resolution grown by its rings); a plane without moments, its model's."""
        model = self.fits[k]
        if not isinstance(model, Plane):
            if k not in self.current_rms:
                self.current_rms[k] = float(np.sqrt(np.mean(model.distances(self._points(k)) ** 2)))
            return max(float(model.rms), self.current_rms[k])
        if self.moments is None or k >= len(self.moments):
            return float(model.rms)
        if k not in self.current_rms:
            self.current_rms[k] = float(plane_rms_from_moments(self.moments[k:k + 1])[0])
        return max(float(model.rms), self.current_rms[k])

    def _points(self, k: int) -> np.ndarray:
        # the fitter's points of label k's pixels, gathered once
        if k not in self.points:
            self.points[k] = self.ctx.fitter.points(self.ctx.xyz, self._regions()[k])
        return self.points[k]

    def _regions(self) -> dict:
        # the flat pixels of every label a pair may join, gathered when a union first needs them
        if self.regions is None:
            self.regions = region_indices(self.labels, only=self.paired)
        return self.regions

    def model(self, ra: int, rb: int):
        """The union's model: the cached one, else a refit of the union's points."""
        union = self.cache.get((ra, rb))
        if union is None:
            regions = self._regions()
            union_idx = np.concatenate([regions[ra], regions[rb]])
            union = self.ctx.fitter.refit(self.ctx.fitter.points(self.ctx.xyz, union_idx), self.fits[ra])
        return union

    def plane_within_larger(self, ra: int, rb: int):
        """The least-squares plane of the union of plane roots ``ra`` and ``rb`` (from their
        moments) when its rms is within the larger part's (:meth:`part_rms`) and the smaller
        part lies on it within what its own range noise leaves a plane fitted to as many
        points (:func:`rangeseg_o3d.kernels.linalg.noise_rms_bound`, up its chi-square, as
        the fitter's plane tolerance); else None.

        The fitter refuses a union whose rms is over its plane tolerance for that many
        points. Where the larger part, a plane already, is over it as well (a wall holding
        a few mixed returns at its jump edges) and the smaller part lies on the union's
        plane within its noise, the union adds no error to either (noise_20mm seed 89 scan
        7: a far wall of 1149 pixels at 21.7 mm rms, a 134-pixel piece of it below a box at
        20.0 mm, their union 21.3 mm, the tolerance 21.2 mm). A part turned from the union,
        or a parallel face a few noise sigmas off, is not within its noise there (a real
        SICK scan's plane of 0.33 m rms would otherwise take a wall 19 degrees from it)."""
        if self.moments is None or max(ra, rb) >= len(self.moments):
            return None
        larger, smaller = (ra, rb) if self.moments[ra, 0] >= self.moments[rb, 0] else (rb, ra)
        plane = planes_from_moments(self.moments[ra:ra + 1] + self.moments[rb:rb + 1])
        if not plane.ok[0] or plane.rms[0] > self.part_rms(larger):
            return None
        normal, d = plane.normal[0], float(plane.d[0])
        count = float(self.moments[smaller, 0])
        if self.noise is None:  # each root's summed range noise, once per merge (join adds them up)
            # by root, not by label: joins made before the first call hold their parts' pixels too
            self.noise = _noise_sums(self.ctx, self.lookup()[self.labels], len(self.moments))
        mean_noise = float(self.noise[smaller]) / max(count, 1.0)
        bound = noise_rms_bound.py_func(mean_noise, count - 3.0, NOISE_CHI2_SIGMAS)
        if _mean_square_distances(self.moments[[smaller]], normal, d)[0] > bound * bound:
            return None
        return Plane(normal=normal, d=d, rms=float(plane.rms[0]), inliers=int(plane.count[0]))

    def parts_on(self, ra: int, rb: int, union, limit: float, max_angle_deg: float) -> bool:
        """Whether the smaller part of a union of planes, when its own plane is turned from
        the union's by more than ``max_angle_deg``, lies on the union's plane within
        ``PART_SIGMAS * limit`` rms (from its moments; True for other kinds, parallel parts
        or without moments).

        The union's rms alone cannot refuse a small part: a face of two hundred pixels at 70
        degrees to a table of eighty thousand, 4 mm off its plane at the median, raises the
        table's rms by a few percent, within ``rms_factor``. Its own mean square distance to
        the union's plane does not shrink with the other part's size. A parallel part is
        left to the rms test: a bump of the camera's error on a face is one too."""
        if self.moments is None or not isinstance(union, Plane):
            return True
        small = ra if self.moments[ra, 0] <= self.moments[rb, 0] else rb
        if _angle_deg(self.fits[small].normal, union.normal) <= max_angle_deg:
            return True
        reach = PART_SIGMAS * limit
        return bool(_mean_square_distances(self.moments[[small]], union.normal, union.d)[0] <= reach * reach)

    def curved_parts_on(self, ra: int, rb: int, union) -> bool:
        """Whether the smaller part of a union of curved regions lies on the union's surface
        within ``rms_factor`` times the larger of its own rms (:meth:`part_rms`) and its range
        noise at the median (True for planes).

        The union's rms alone cannot refuse a small part: a wall 6.4-7.7 m away under a Kinect's
        7 cm of noise, bent into a cylinder of r 4.6 m, took a pipe of r 0.12 m at 2.9 m
        beside it (kinect_real_640x480 study seed 1260 scan 0): the union's rms stayed within
        the wall's, while the pipe's pixels lay 64 mm rms off it, five of their range sigmas."""
        if isinstance(union, Plane) or isinstance(self.fits[ra], Plane) or isinstance(self.fits[rb], Plane):
            return True
        regions = self._regions()
        small = min((ra, rb), key=lambda k: (regions[k].size, k))
        idx = regions[small]
        if not idx.size:
            return True
        rms = float(np.sqrt(np.mean(union.distances(self._points(small)) ** 2)))
        noise = float(np.median(self.ctx.sigma[idx]))  # (the context's noise is flat)
        return rms <= self.rms_factor * max(self.part_rms(small), noise)

    def part_centred(self, ra: int, rb: int, union) -> bool:
        """Whether the smaller part of a union of planes lies on the union's plane on the
        mean: its mean signed distance (from its moments) within ``CHI_SQUARE_SIGMAS`` of
        the noise of a mean of its points, its own model's rms over the root of their
        number (True for other kinds or without moments). A strip of a wall beside the
        corner it meets lies within the noise of the other wall point by point, and on one
        side of it as a whole."""
        if self.moments is None or not isinstance(union, Plane):
            return True
        small = ra if self.moments[ra, 0] <= self.moments[rb, 0] else rb
        count = float(self.moments[small, 0])
        if count <= 0:
            return True
        mean = float(self.moments[small, 1:4] @ union.normal) / count - union.d
        return abs(mean) <= CHI_SQUARE_SIGMAS * float(self.fits[small].rms) / np.sqrt(count)

    def no_step(self, ra: int, rb: int, union) -> bool:
        """Whether the smaller part of a union of planes lies on the larger part's plane, on
        the mean (from its moments), within ``STEP_SIGMAS`` times the scatter of its samples
        (its model's rms, at least their distance noise: its summed range noise times the
        incidence cosine at its centroid, floored at ``GRAZING_COSINE``) and the larger plane's
        own uncertainty at that centroid (:func:`rangeseg_o3d.kernels.plane_prediction_sd`)
        added in quadrature: :func:`rangeseg_o3d.kernels.part_within_step`, the test the
        compiled pair loop makes. True for other kinds
        or without moments, or with ``STEP_SIGMAS <= 0``. merge_regions asks it of pieces apart
        (not adjacent).

        Two box tops a couple of centimetres apart (two boxes of different heights) seen near
        grazing lie within a Kinect's range noise of each other's plane, and their union's rms
        stays within the parts' (their own planes are as noisy, turned by half a degree), but
        along their normals the step is many times the scatter of either: no piece of one
        surface stands that far off it. A floor's plane fitted to a patch seen near grazing
        under a laser's 20 mm noise, carried four metres to its other patch beyond the boxes
        standing on it, is itself a few millimetres uncertain there (noise_20mm seed 1007 scan
        1: two floor patches 3 cm off each other's planes were left apart)."""
        if STEP_SIGMAS <= 0 or self.moments is None or not isinstance(union, Plane) \
                or not isinstance(self.fits[ra], Plane) \
                or not isinstance(self.fits[rb], Plane) or max(ra, rb) >= len(self.moments):
            return True
        small, big = (ra, rb) if self.moments[ra, 0] <= self.moments[rb, 0] else (rb, ra)
        count = float(self.moments[small, 0])
        if count <= 0:
            return True
        if self.noise is None:  # each root's summed range noise (as plane_within_larger)
            self.noise = _noise_sums(self.ctx, self.lookup()[self.labels], len(self.moments))
        plane = self.fits[big]
        return bool(kernels.part_within_step(
            np.ascontiguousarray(self.moments[small], dtype=np.float64), float(self.noise[small]),
            float(self.fits[small].rms), np.ascontiguousarray(self.moments[big], dtype=np.float64), float(plane.rms),
            np.asarray(plane.normal, dtype=np.float64), float(plane.d), STEP_SIGMAS, GRAZING_COSINE))

    def join(self, ra: int, rb: int, union) -> None:
        """Merge root ``rb`` into root ``ra``, whose model becomes ``union``."""
        self.root[rb] = ra
        self.fits[ra] = union
        self.current_rms.pop(ra, None)
        self.points.pop(ra, None)
        self.points.pop(rb, None)
        self.fits.pop(rb)
        for key in [key for key in self.cache if ra in key or rb in key]:
            del self.cache[key]
        if self.moments is not None:
            self.moments[ra] += self.moments[rb]
        if self.noise is not None:
            self.noise[ra] += self.noise[rb]
        if self.regions is not None:
            self.regions[ra] = np.concatenate([self.regions[ra], self.regions.pop(rb)])

    def lookup(self) -> np.ndarray:
        """Label -> its root's label, for every label of the grid."""
        lut = np.arange(int(self.labels.max(initial=0)) + 1, dtype=np.int32)
        for k in self.root:
            lut[k] = self.find(k)
        return lut


#: Parameters of each kind's model: what the piece's own model is weighed by against the union's.
MODEL_PARAMETERS = {"plane": 3, "sphere": 4, "cylinder": 5}


def _own_model_resolves(ctx: Context, piece: np.ndarray, own, union) -> bool:
    """Whether the piece's ``own`` model lowers the squared distances of its pixels ``piece``
    from the ``union``'s by more than its parameters would on noise (the F-test of
    :func:`rangeseg_o3d.fitting.robust.curvature_resolved`): a strip of the curved surface
    lies on the union's model as closely as on its own, a pipe's end cap does not, though
    on a far stereo camera both fit within the range noise (the cap faces the sensor, its
    noise is the whole range noise; the pipe's flanks graze it)."""
    points = rows_at(ctx.xyz, piece)
    own_squares = squared_distances(own, points)
    union_squares = squared_distances(union, points)
    return curvature_resolved(union_squares, own_squares, piece.size, MODEL_PARAMETERS[own.kind])


def merge_into_curved(ctx: Context, labels: np.ndarray, fits: dict, adjacency: set, *,
                      rms_factor: float, only: set | None = None, near_sigmas: float | None = None,
                      apart: set = frozenset(), apart_sigmas: float | None = None):
    """Pieces of a curved surface taken by another kind go back to it: returns
    ``(labels, fits, adjacency)``, the labels a new array when a piece went back (else
    ``labels`` itself).

    A sphere or cylinder cut by an edge line can leave a strip that a plane (a flat-looking
    band of a column, the bottom of a ball) or the other curved kind fits on its own;
    :func:`merge_regions` pairs only regions of one kind, so the strip stays apart. Each
    adjacent pair of different kinds whose larger region is curved is tried, smallest
    piece first: the larger region's model refitted to the union must keep its kind, fit
    within ``rms_factor`` of the larger part's rms and at the noise (the chi-square bound of
    :func:`rangeseg_o3d.fitting.robust.beyond_noise`: a face of a box beside a column
    is not explained by the column's cylinder). A piece out of reach of every model near the
    curved one that keeps the larger part within that rms
    (:func:`rangeseg_o3d.fitting.robust.union_out_of_reach`, a first-order bound) is refused
    without the refit. With ``only``, just pairs involving those labels (the others were
    tried before). With ``near_sigmas``, a piece is refitted with the
    curved region only when the curved model as it stands lies within that many noise sigmas
    of the piece's pixels at the median (a refit is the step's cost). ``apart``: pairs that
    do not touch, tried too (not added to the adjacency returned), each only when the curved
    model lies within ``apart_sigmas`` noise sigmas of the piece at the median (that pretest
    whether or not ``near_sigmas`` is given).
    """
    mixed = [(a, b) for a, b in (adjacency if not apart else [*adjacency, *sorted(apart)])
             if fits.get(a) and fits.get(b) and fits[a].kind != fits[b].kind
             and (only is None or a in only or b in only)]
    if not mixed:  # no curved region touches another kind: no pass over the grid
        return labels, fits, adjacency
    regions, pairs, n = _curved_pairs(labels, fits, mixed)
    if not pairs:
        return labels, fits, adjacency
    fits = dict(fits)
    lut = np.arange(n, dtype=np.int32)
    pairs.sort()
    # the pretest of every pair in one compiled pass, against the models as they stand now
    # (a pair whose curved region took a piece since is tested again below)
    sigmas = _pretest_sigmas(pairs, near_sigmas, apart, apart_sigmas)
    near = _pieces_near(ctx, fits, regions, pairs, sigmas) if sigmas is not None else None
    as_tested = dict(fits)
    merged = False
    for turn, (_, big, small) in enumerate(pairs):
        if lut[big] != big or lut[small] != small:
            continue  # one of them was merged already
        if sigmas is not None and np.isfinite(sigmas[turn]):
            piece = regions[small]
            verdict = int(near[turn]) if fits[big] is as_tested[big] else -1
            if verdict < 0:  # (numpy's rounding decides: the compiled pass could not tell)
                verdict = int(_median_near(ctx, fits[big], piece, sigmas[turn]))
            if not verdict:
                continue
        parts = (regions[big], regions[small])  # the union's pixels, not concatenated unless it is taken
        n = parts[0].size + parts[1].size
        points = ctx.fitter.points_of(ctx.xyz, parts)
        limit = rms_factor * max(fits[big].rms, fits[small].rms)
        # a piece far beyond what any model near the curved one can reach (a wall beside
        # a column) is refused without the refit, the step's cost
        if union_out_of_reach(fits[big], points, ctx.fitter.kept(n, parts[0].size), limit):
            continue
        union = ctx.fitter.refit(points, fits[big])
        if not union or union.kind != fits[big].kind:
            continue
        if union.rms > limit:
            continue
        if beyond_median_noise(union.rms, ctx.sigma.reshape(-1), parts):
            continue
        if _own_model_resolves(ctx, regions[small], fits[small], union):
            continue
        fits[big] = union
        del fits[small]
        regions[big] = np.concatenate(parts)
        lut[small] = big
        merged = True
    adjacency = _mapped_adjacency(adjacency, lut)
    # nothing merged: the labels as they came, as the early returns above give them (a
    # copy of the frame costs 0.2-0.5 ms on a 640 x 480 frame)
    return (_relabelled(labels, lut) if merged else labels), fits, adjacency


def _curved_pairs(labels: np.ndarray, fits: dict, mixed: list):
    """``(regions, pairs, n)`` of merge_into_curved: the ``(size of small, big, small)`` of
    each pair of ``mixed`` whose larger region (more pixels) is curved, the flat pixels
    (increasing) of those pairs' labels only, and ``labels.max() + 1``.

    The sizes come from one counting pass over the labels of ``mixed``; the pixels are
    gathered for the pairs' labels only (a table's plane beside a mug's strip is counted,
    not gathered: on a 640 x 480 frame 200 000 pixels, where the pairs hold 3000-16000).
    """
    flat = np.ascontiguousarray(labels.ravel())
    if flat.dtype != np.int32:  # (the label images' type: one compiled signature)
        flat = flat.astype(np.int32)
    n = int(flat.max(initial=0)) + 1
    members = np.zeros(n, bool)
    members[[k for pair in mixed for k in pair if 0 < k < n]] = True
    counts = kernels.member_counts(flat, members)
    sizes = counts.tolist()
    pairs = []
    for a, b in mixed:
        if not (0 < a < n and 0 < b < n and sizes[a] and sizes[b]):
            continue  # a label without pixels
        big, small = (a, b) if sizes[a] >= sizes[b] else (b, a)
        if not isinstance(fits[big], Plane):
            pairs.append((sizes[small], big, small))
    if not pairs:
        return {}, pairs, n
    wanted = np.zeros(n, bool)
    wanted[[k for _, big, small in pairs for k in (big, small)]] = True
    order, starts = kernels.group_counted(flat, wanted, counts)
    bounds = starts.tolist()  # Python ints: slicing by numpy scalars costs more than the slice
    return {k: order[bounds[k]:bounds[k + 1]] for k in np.flatnonzero(wanted).tolist()}, pairs, n


def curved_pairs_apart(fits: dict, adjacency: set, among=None, *, any_kind: bool = False) -> set:
    """Pairs ``(min, max)`` of a cylinder or sphere of ``fits`` and a region of another kind
    (of any kind with ``any_kind``; one of ``among`` when given) that are not in
    ``adjacency``: the pairs :func:`merge_into_curved` may try as ``apart`` (with
    ``merge_disjoint``), and with ``any_kind`` those
    :func:`rangeseg_o3d.refinement.trimmed_pieces.join_trimmed_pieces` may."""
    curved = [k for k, m in fits.items() if m and m.kind in ("cylinder", "sphere")]
    others = fits if among is None else among
    return {(min(k, c), max(k, c)) for k in others if fits.get(k) for c in curved
            if c != k and (any_kind or fits[c].kind != fits[k].kind)} - set(adjacency)


def _pretest_sigmas(pairs: list, near_sigmas: float | None, apart: set, apart_sigmas: float | None):
    """Per ``(size, big, small)`` of ``pairs``, the noise sigmas of :func:`merge_into_curved`'s
    pretest (inf: none), or None when no pair has one."""
    if near_sigmas is None and not (apart and apart_sigmas is not None):
        return None
    adjacent = np.inf if near_sigmas is None else float(near_sigmas)
    far = adjacent if apart_sigmas is None else float(apart_sigmas)
    return np.array([far if (min(big, small), max(big, small)) in apart else adjacent for _, big, small in pairs])


def pieces_near(ctx: Context, fits: dict, regions: dict, pairs: list, near_sigmas: float) -> list[bool]:
    """Per ``(size, big, small)`` of ``pairs``: whether the model of ``big`` lies within
    ``near_sigmas`` noise sigmas of the pixels of ``small`` at the median (``regions``: flat
    pixels per label): the pretest :func:`merge_into_curved` makes, numpy deciding where the
    compiled pass leaves it to rounding."""
    near = _pieces_near(ctx, fits, regions, pairs, near_sigmas).tolist()
    return [verdict > 0 or (verdict < 0 and _median_near(ctx, fits[big], regions[small], near_sigmas))
            for verdict, (_, big, small) in zip(near, pairs)]


def _median_near(ctx: Context, model, piece: np.ndarray, near_sigmas: float) -> bool:
    # the pretest in numpy (where the compiled pass leaves it to rounding)
    return not median(np.abs(model.distances(rows_at(ctx.xyz, piece)))) > near_sigmas * median(ctx.sigma[piece])


def _pieces_near(ctx: Context, fits: dict, regions: dict, pairs: list, near_sigmas) -> np.ndarray:
    """Per ``(size, big, small)`` of ``pairs``: 1 when the median distance of the pixels of
    ``small`` (``regions``: flat pixels per label) to the model of ``big`` is within
    ``near_sigmas`` (one value, or one per pair; inf: 1) times their median range noise, 0
    when over, -1 where rounding could decide (:func:`rangeseg_o3d.kernels.pieces_near_models`:
    the numpy form is then asked)."""
    sigmas = np.broadcast_to(np.asarray(near_sigmas, dtype=float), (len(pairs),))
    out = np.ones(len(pairs), np.int8)
    for value in np.unique(sigmas[np.isfinite(sigmas)]).tolist():  # (one compiled pass per bound)
        turns = np.flatnonzero(sigmas == value).tolist()
        rows = [model_row(fits[pairs[t][1]]) for t in turns]
        pieces = [regions[pairs[t][2]] for t in turns]
        starts = np.zeros(len(pieces) + 1, np.int64)
        np.cumsum([piece.size for piece in pieces], out=starts[1:])
        out[turns] = kernels.pieces_near_models(
            np.ascontiguousarray(ctx.xyz, dtype=np.float64), np.ascontiguousarray(ctx.sigma, dtype=np.float64),
            np.ascontiguousarray(np.concatenate(pieces), dtype=np.int64), starts,
            np.array([kind for kind, _ in rows], np.int8), np.array([row for _, row in rows]),
            float(value), NEAR_RELATIVE, NEAR_ROUNDING)
    return out


#: Margins about the pretest's bound within which merge_into_curved asks numpy
#: (:func:`_pieces_near`): many times the rounding of a distance's few operations on its
#: terms, and the bound's own relative rounding.
NEAR_ROUNDING = 64 * np.finfo(np.float64).eps
NEAR_RELATIVE = 1e-9


#: Relative margin about the noise a union's rms is at the bound of, outside which counting
#: the pixels on either side tells where the median noise lies (:func:`beyond_median_noise`).
_MEDIAN_MARGIN = 1e-6


def beyond_median_noise(rms: float, sigma_flat: np.ndarray, parts) -> bool:
    """``beyond_noise(rms, median(sigma_flat[union]), n)`` of the union of the pixel arrays
    ``parts`` (``n`` pixels), the same answer without the median where counting can tell.

    The test is monotone in the noise: it holds for the median when it holds for a value
    the median cannot exceed (more than half the pixels at or below it, so both middle
    values are), and fails when it fails for a value the median cannot fall below. The
    values tried sit just either side of the noise at which ``rms`` meets the bound; only
    a median within that sliver (or a NaN, which makes the median NaN) needs the median
    (on a tunnel's 190000 pixels a partition costs four times the gather and counts).
    """
    from ..kernels import count_either_side

    n = sum(part.size for part in parts)
    half = n // 2
    at_bound = rms / noise_rms_bound.py_func(1.0, float(n), CHI_SQUARE_SIGMAS)
    low, high = at_bound * (1.0 - _MEDIAN_MARGIN), at_bound * (1.0 + _MEDIAN_MARGIN)
    if high > low:  # (a NaN rms: the median decides)
        counts = [count_either_side(sigma_flat, part, low, high) for part in parts]  # no gather
        if not any(nan for _, _, nan in counts):
            if sum(below for below, _, _ in counts) > half and beyond_noise(rms, low, n):
                return True  # the middle values are at most ``low``
            if sum(above for _, above, _ in counts) > n - half and not beyond_noise(rms, high, n):
                return False  # the middle values are at least ``high``
    return beyond_noise(rms, median(np.concatenate([sigma_flat[part] for part in parts])), n)


#: The algebraic circle about a crease line leaves up to this factor more squared distances
#: than the cylinder the fitter finds on the same arc (its fit is biased on a partial arc):
#: a pair whose circle leaves more than this times the planes' is not tried.
CIRCLE_SLACK = 2.0


def planes_into_curved(ctx: Context, labels: np.ndarray, fits: dict, adjacency: set, *, max_angle_deg: float):
    """Touching planes that are pieces of one column (or ball) become one curved region:
    returns new ``(labels, fits, adjacency)``.

    On a noisy sensor the two halves of a column seen from one side each fit a plane
    within the range noise, and the planes, turned from each other by more than
    ``max_angle_deg``, are never merged. A pair is tried when the planes meet in a convex
    crease as seen from the sensor (each region's centre beyond the other's plane: a column
    seen from outside; a room's corners are concave) and one of them is beyond the noise
    of its distances (:meth:`Context.plane_along_rays`: a flat face is not, the sagitta of
    an arc is), largest union first. The circle about the planes' crease line through the
    union's points must leave fewer than CIRCLE_SLACK times the planes' squared distances
    (one linear solve: a box's faces are far off any such circle, and the fitter's fit is
    the step's cost); then the fitter's own fit of the union must be curved, leave fewer
    squared distances over the union's pixels than the two planes leave on theirs (with
    fewer parameters) and fit at the noise.
    """
    turned = float(np.cos(np.radians(max_angle_deg)))  # _angle_deg(u, v) > max_angle_deg, without arccos
    pairs = _turned_plane_pairs(fits, adjacency, turned)
    if not pairs:
        return labels, fits, adjacency
    # the cheapest refusals first: the convex test needs the regions' centres alone (one
    # compiled pass), the pixels are grouped only for the pairs it keeps
    centres = _centres(ctx.xyz, labels, {k for pair in pairs for k in pair})
    pairs = _convex_pairs(fits, centres, pairs)
    if not pairs:
        return labels, fits, adjacency
    regions = region_indices(labels, only={k for pair in pairs for k in pair})
    bent = {}  # whether each plane is beyond the noise of its distances, asked once and when needed
    # a strip two grid lines across a column's axis fits a plane whatever the column's
    # curvature (two lines of returns along the axis are parallel, so coplanar) and tells no
    # bend of its own (a 0.3 m column at 4.7 m under 2 mm noise, cut into strips of one and
    # two columns by a 1-degree nodding laser's edge image)
    pairs = [(regions[a].size + regions[b].size, a, b) for a, b in pairs
             if _bent(ctx, fits, regions, bent, a) or _bent(ctx, fits, regions, bent, b)
             or min(lines_across(regions[a], ctx.width), lines_across(regions[b], ctx.width)) <= 2]
    if not pairs:
        return labels, fits, adjacency
    fits = dict(fits)
    squares = {}  # each plane's sum of squared distances over its pixels
    lut = np.arange(int(labels.max(initial=0)) + 1, dtype=np.int32)
    for _, a, b in sorted(pairs, reverse=True):
        if lut[a] != a or lut[b] != b or not (isinstance(fits[a], Plane) and isinstance(fits[b], Plane)):
            continue  # one of them was joined already (it may have kept its label: a pair's first)
        for k in (a, b):
            if k not in squares:
                squares[k] = squared_distances(fits[k], rows_at(ctx.xyz, regions[k]))
        planes = squares[a] + squares[b]
        parts = (regions[a], regions[b])
        points = ctx.fitter.points_of(ctx.xyz, parts)
        n = parts[0].size + parts[1].size
        if _crease_circle_mean_square(points, fits[a].normal, fits[b].normal) * n >= CIRCLE_SLACK * planes:
            continue
        union = ctx.fitter.fit(points)
        if not union or isinstance(union, Plane):
            continue
        union_squares = sum(squared_distances(union, rows_at(ctx.xyz, part)) for part in parts)
        if union_squares >= planes or beyond_median_noise(float(np.sqrt(union_squares / n)),
                                                           ctx.sigma.reshape(-1), parts):
            continue
        fits[a] = union
        del fits[b]
        regions[a] = np.sort(np.concatenate(parts))
        squares.pop(a, None)
        lut[b] = a
    return _relabelled(labels, lut), fits, _mapped_adjacency(adjacency, lut)


def _turned_plane_pairs(fits: dict, adjacency, turned: float) -> list[tuple[int, int]]:
    """The pairs ``(a, b)`` of ``adjacency`` (in its order) whose models are both planes with
    ``abs(float(normal_a @ normal_b)) < turned``: planes_into_curved's first filter.

    Each product is summed in Python floats from the normals as lists (a numpy product of
    two 3-vectors costs a microsecond, on every adjacent pair of a scan); only one within
    ``SCREEN_SLACK`` of ``turned`` (scaled by the normals' lengths when over 1) or not
    finite is asked of numpy, so the rounding of the sums decides nothing."""
    normals = {k: m.normal.tolist() for k, m in fits.items() if isinstance(m, Plane)}
    pairs = []
    for a, b in adjacency:
        u, v = normals.get(a), normals.get(b)
        if u is None or v is None:
            continue
        dot = abs(u[0] * v[0] + u[1] * v[1] + u[2] * v[2])
        margin = SCREEN_SLACK * max(1.0, (u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
                                    * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
        if dot < turned - margin:
            pairs.append((a, b))
        elif not dot >= turned + margin and abs(float(fits[a].normal @ fits[b].normal)) < turned:
            pairs.append((a, b))  # (near the limit, or not finite: numpy's product decides)
    return pairs


def _centres(xyz: np.ndarray, labels: np.ndarray, wanted: set) -> dict:
    # each wanted label with pixels: the mean of its points (the sums in raster order, as the
    # mean of its gathered points adds them)
    flat = np.ascontiguousarray(labels.ravel())
    if flat.dtype != np.int32:
        flat = flat.astype(np.int32)
    members = np.zeros(int(flat.max(initial=0)) + 1, bool)
    members[[k for k in wanted if 0 < k < members.size]] = True
    sums = kernels.member_centres(xyz, flat, members)
    return {k: sums[k, 1:] / sums[k, 0] for k in np.flatnonzero(sums[:, 0] > 0).tolist()}


def _bent(ctx: Context, fits: dict, regions: dict, bent: dict, k: int) -> bool:
    # ctx.plane_along_rays of plane k over its pixels, remembered in ``bent``
    if bent.get(k) is None:
        bent[k] = ctx.plane_along_rays(fits[k], regions[k])
    return bent[k]


def _convex_pairs(fits: dict, centres: dict, pairs: list) -> list[tuple[int, int]]:
    """The pairs ``(a, b)`` of ``pairs`` (planes, in their order) with both regions' centres
    in ``centres`` that meet in a convex crease as seen from the sensor (the origin): each
    region's centre beyond the other's plane, away from the sensor (:func:`_beyond_from_origin`;
    a column or ball seen from outside; a room's corners and a tunnel are concave). Each side
    is summed in Python floats (:func:`_surely_beyond`: numpy's products of 3-vectors cost
    more than the test)."""
    floats = {}  # label: (its normal, d and centre as Python floats)
    out = []
    for a, b in pairs:
        if a not in centres or b not in centres:
            continue
        for k in (a, b):
            if k not in floats:
                floats[k] = (fits[k].normal.tolist(), float(fits[k].d), centres[k].tolist())
        if (_surely_beyond(floats[a][0], floats[a][1], floats[b][2], fits[a], centres[b])
                and _surely_beyond(floats[b][0], floats[b][1], floats[a][2], fits[b], centres[a])):
            out.append((a, b))
    return out


def _surely_beyond(normal: list, d: float, point: list, plane: Plane, point_array: np.ndarray) -> bool:
    # _beyond_from_origin(plane, point_array) from the same values as Python floats: the
    # side's sign is certain when the side is beyond the rounding of either sum (many times
    # over); else, or not finite, or a plane through the origin, numpy's form decides
    terms = (normal[0] * point[0], normal[1] * point[1], normal[2] * point[2])
    side = terms[0] + terms[1] + terms[2] - d
    if abs(side) > SCREEN_SLACK * (abs(terms[0]) + abs(terms[1]) + abs(terms[2]) + abs(d)) and abs(d) > 1e-100:
        return side * d > 0.0
    return _beyond_from_origin(plane, point_array)


def _beyond_from_origin(plane: Plane, point: np.ndarray) -> bool:
    # whether ``point`` lies on the far side of ``plane`` from the origin
    side = float(plane.normal @ point - plane.d)  # the origin's is -d
    return side * plane.d > 0.0


def _crease_circle_mean_square(points: np.ndarray, first: np.ndarray, second: np.ndarray) -> float:
    """The mean squared distance of ``points`` to the circle fitted to them (algebraic least
    squares) in the plane across the crease line of two planes of normals ``first`` and
    ``second``: the axis a cylinder both planes touch would have."""
    axis = _cross(first, second)
    axis /= np.linalg.norm(axis)
    u = _cross(axis, first)
    x, y = points @ first, points @ u
    x, y = x - x.mean(), y - y.mean()
    a, b, c = _circle_coefficients(x, y)
    radius = np.sqrt(max(c + a * a + b * b, 0.0))
    off = np.hypot(x - a, y - b) - radius
    return float(off @ off) / x.size


def _circle_coefficients(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    # the least-squares (a, b, c) of 2ax + 2by + c = x^2 + y^2 (centre (a, b)), from its 3 x 3
    # normal equations: the points are centred, so they are well conditioned, and the solve
    # costs a third of lstsq's SVD on these few hundred points; lstsq where they are singular
    # (points on one line)
    squares = x * x + y * y
    sx, sy = float(x.sum()), float(y.sum())
    sxy = float(x @ y)
    normal = np.array([[4.0 * float(x @ x), 4.0 * sxy, 2.0 * sx],
                       [4.0 * sxy, 4.0 * float(y @ y), 2.0 * sy],
                       [2.0 * sx, 2.0 * sy, float(x.size)]])
    rhs = np.array([2.0 * float(x @ squares), 2.0 * float(y @ squares), float(squares.sum())])
    try:
        a, b, c = np.linalg.solve(normal, rhs).tolist()
    except np.linalg.LinAlgError:
        design = np.column_stack([2.0 * x, 2.0 * y, np.ones_like(x)])
        (a, b, c), *_ = np.linalg.lstsq(design, squares, rcond=None)
    return a, b, c


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    # the cross product of two 3-vectors (np.cross's generality costs more than the product)
    return np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])
