"""Step 7, ``dissolve``: small blobs at junctions go to the larger neighbours that explain them.

A blob where surfaces meet can pass for a small curved patch; its kind differs from its
neighbours', so the ``merge`` step never pairs it. Runs after ``merge`` on its adjacency.
:func:`dissolve_fragments` does it at the end of a laser's refinement for regions of any
size whose larger neighbours explain them within the noise (a crease strip at 20 mm).

:func:`absorb_ripples` does the same for curved patches inside a plane, whatever their
size: a bump of the camera's large-scale error that a curved model happened to fit.
"""

from __future__ import annotations

import numpy as np

from .._numeric import rows_at, unique_ints

from .. import kernels  # the package: its names load on first use (no compiler at import)
from ..fitting.primitives import Plane, squared_distances
from ..fitting.region_fitter import label_sizes, model_table, region_indices
from ..fitting.robust import beyond_noise, curvature_resolved
from .context import SCREEN_SLACK, Context, touching
from .merge import ADJACENCY_MATRIX_LABELS, MODEL_PARAMETERS, region_adjacency, region_adjacency_matrix

__all__ = ["FRAGMENT_SHARE", "absorb_ripples", "dissolve_fragments", "dissolve_small", "explained_by_hosts"]


def dissolve_small(ctx: Context, labels: np.ndarray, fits: dict, adjacency: set, *, k_sigma: float):
    """Hand small regions to larger neighbours whose surfaces already explain them.

    When at least 80 % of a region smaller than ``3 * ctx.min_size`` lies within
    ``k_sigma max(sigma, rms)`` of larger neighbours' models (neighbours by
    ``adjacency``, pairs of labels), each such point joins the neighbour that explains it
    best and the rest become unlabelled; the neighbours are refitted where moments suffice
    (planes; spheres and cylinders in the ``polish`` step). Returns new ``(labels, fits)``.
    """
    sizes = label_sizes(labels)
    if not np.any((sizes[1:] > 0) & (sizes[1:] < 3 * ctx.min_size)):
        return labels, fits
    labels, fits = labels.copy(), dict(fits)
    regions = region_indices(labels)
    small_ones = [k for k in regions if regions[k].size < 3 * ctx.min_size]
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
        explained, best, _ = explained_by_hosts(ctx, idx, fits, hosts, np.array([fits[k].rms for k in hosts])[:, None],
                                                k_sigma)
        if explained.mean() < FRAGMENT_SHARE or _stands_apart(rows_at(ctx.xyz, idx), fits.get(small),
                                                               [fits[k] for k in hosts], best, explained):
            continue
        new_labels = np.where(explained, np.asarray(hosts)[best], 0)
        flat[idx] = new_labels
        for k in set(new_labels[explained].tolist()):
            regions[k] = np.concatenate([regions[k], idx[new_labels == k]])
            changed.add(k)
        del regions[small]
        fits.pop(small, None)
    for k, refit in ctx.fitter.refit_regions(
            ctx.xyz, labels, fits, [k for k in changed if k in regions], from_points=False).items():
        if refit:
            fits[k] = refit
    return labels, fits


def dissolve_fragments(ctx: Context, labels: np.ndarray, fits: dict, *, k_sigma: float,
                       wrap_columns: bool = False, jumps: np.ndarray | None = None):
    """Hand a region to larger touching regions whose models explain its pixels within the
    noise: a fragment of their surfaces, whatever its size and kind.

    A laser's single returns at 20 mm of range noise hold pieces that some model of their
    own fits within the noise without being a surface: a strip two or three grid lines high
    along a box's foot fits a horizontal plane (its height is under the noise along the
    rays) as well as its face's vertical one does, a column's flank or a ball's rim fits a
    plane. Such a piece keeps a region through the steps before (too large for
    :func:`dissolve_small`, of another kind than its host, or no merge partner: the merge
    asks one model to explain the union, not the host to explain the piece), and its
    surface counts as over-segmented (noise_20mm: 29 of the 70 surfaces missed on 34 seeds).

    Smallest first, a region with a model whose touching fitted regions (within two pixels,
    :func:`rangeseg_o3d.refinement.merge.region_adjacency`) are larger: each pixel goes to
    the host that explains it best, within ``k_sigma max(sigma, rms)``. Those explained
    must be at least FRAGMENT_SHARE (80 %) of the region's pixels, not counting the ones on a range jump
    (``jumps``) that no host explains (mixed returns between a surface and the one behind
    it, which the region's own model took along its rays), and more than half of all of
    them (a column two grid lines wide lies on jumps all over); and the hosts' rms over them
    must be within the noise (:func:`rangeseg_o3d.fitting.robust.beyond_noise` at their
    median ``sigma``). The region's own model is no judge: its pixels are the ones it took
    for fitting them better, so it always fits them better. A face of its own, even a small
    one beside a larger face, stands off the host by more than the noise over most of its
    pixels. The explained pixels join their hosts, the rest are freed; the hosts are
    refitted (planes from moments, curved ones on their points; a refit of another kind or
    none keeps the old model). Returns new ``(labels, fits)``, or the inputs when nothing
    changed.
    """
    fitted = [k for k, m in fits.items() if m and k > 0]
    if len(fitted) < 2:
        return labels, fits
    sizes = label_sizes(labels, minlength=max(fitted) + 1).astype(np.int64)
    # one compiled pass over every region refuses what the tests below certainly refuse while
    # no region has changed (a laser scan's walls and box faces: all of them, most scans)
    hopeful, adjacency = _may_dissolve(ctx, labels, fits, fitted, sizes, k_sigma, jumps, wrap_columns)
    if hopeful is not None and not hopeful.any():
        return labels, fits
    if adjacency is None:
        pairs = region_adjacency(labels, wrap_columns=wrap_columns)
    else:  # the pretest's matrix: region_adjacency's pairs a < b
        first, second = np.nonzero(adjacency)
        upper = first < second
        pairs = zip(first[upper].tolist(), second[upper].tolist())
    neighbours: dict[int, set[int]] = {}
    for a, b in pairs:
        if fits.get(a) and fits.get(b):
            neighbours.setdefault(a, set()).add(b)
            neighbours.setdefault(b, set()).add(a)
    # a region is looked at only when some touching fitted region is larger (cheap: no pixels read)
    candidates = [k for k in neighbours if any(sizes[h] > sizes[k] for h in neighbours[k])]
    if not candidates:
        return labels, fits
    regions = region_indices(labels, only=candidates)
    out, kept, changed = labels, fits, set()
    for small in sorted(candidates, key=lambda k: (sizes[k], k)):
        if hopeful is not None and out is labels and not hopeful[small]:  # (its hosts are the pretest's until then)
            continue
        idx = regions.get(small)
        own = kept.get(small)
        hosts = [h for h in sorted(neighbours[small]) if h in kept and sizes[h] > sizes[small]]
        if idx is None or not own or not hosts or small in changed:  # (a host that grew: its pixels moved)
            continue
        scatter = np.array([kept[h].rms for h in hosts])[:, None]
        if idx.size > _FRAGMENT_SAMPLE:
            # most of a fragment's pixels are explained: a region whose every so many pixels
            # mostly are not (below the half by three binomial sigmas) is skipped unread
            sample = idx[:: idx.size // _FRAGMENT_SAMPLE]
            share = np.count_nonzero(explained_by_hosts(ctx, sample, kept, hosts, scatter, k_sigma)[0]) / sample.size
            if share < 0.5 - 1.5 / np.sqrt(sample.size):
                continue
        explained, best, distance = explained_by_hosts(ctx, idx, kept, hosts, scatter, k_sigma)
        n = int(explained.sum())
        # (a pixel on a range jump no host explains is a mixed return, not the region's own;
        # yet most of the region must be explained: a thin column is on jumps all over)
        counted = idx.size if jumps is None else int(np.count_nonzero(explained | ~jumps.ravel()[idx]))
        if n < FRAGMENT_SHARE * counted or 2 * n <= idx.size:
            continue
        # the hosts' distances on what they explain within the noise alone: the region's own
        # model is no judge (its pixels are the ones it took for fitting it better)
        host_rms = float(np.sqrt(np.mean(distance[explained] ** 2)))
        if beyond_noise(host_rms, float(np.median(ctx.sigma[idx[explained]])), n):
            continue
        if out is labels:  # the first fragment: the inputs stay as they are
            out, kept = labels.copy(), dict(fits)
        new_labels = np.where(explained, np.asarray(hosts)[best], 0)
        out.ravel()[idx] = new_labels
        for h in unique_ints(new_labels[explained]).tolist():
            sizes[h] += int(np.count_nonzero(new_labels == h))
            changed.add(h)
        sizes[small] = 0
        del kept[small]
        changed.discard(small)
    hosts = [k for k in changed if k in kept]
    for k, refit in ctx.fitter.refit_regions(ctx.xyz, out, kept, hosts).items():
        if refit and refit.kind == kept[k].kind:
            kept[k] = refit
    return out, kept


#: A region of more pixels is first looked at through every so many of its pixels (about
#: this many): a face or a wall far from every host costs no pass over its pixels.
_FRAGMENT_SAMPLE = 64

#: The least share of a region's pixels (for :func:`dissolve_fragments`, but those on a range
#: jump no host explains) its larger neighbours must explain for :func:`dissolve_small` and
#: :func:`dissolve_fragments` to hand it to them: a piece of which more than a fifth stands
#: off every host beyond the noise is kept as a surface of its own.
FRAGMENT_SHARE = 0.8


def _may_dissolve(ctx: Context, labels: np.ndarray, fits: dict, fitted: list, sizes: np.ndarray,
                  k_sigma: float, jumps: np.ndarray | None, wrap_columns: bool):
    """``(hopeful, adjacency)``: per label below the largest + 1, False where
    :func:`dissolve_fragments`' tests (its sample's share, the half, FRAGMENT_SHARE) certainly
    keep the region from its larger fitted neighbours while no region has changed, True where
    they may not; and the regions' adjacency matrix it used
    (:func:`rangeseg_o3d.refinement.merge.region_adjacency_matrix`). ``(None, None)`` when the
    labels are too many for an adjacency matrix. One compiled pass over the grid
    (:func:`rangeseg_o3d.kernels.fragments_may_pass`), its counts at least
    :func:`explained_by_hosts`'s."""
    n = int(labels.max(initial=0)) + 1
    if n > ADJACENCY_MATRIX_LABELS:
        return None, None
    adjacency = region_adjacency_matrix(labels, n, wrap_columns=wrap_columns)
    has_model = np.zeros(sizes.size, np.bool_)
    has_model[fitted] = True
    kinds, params, rms = model_table(fits, sizes.size)
    flat = np.ascontiguousarray(labels.ravel(), dtype=np.int32)
    jumps = np.zeros(flat.size, np.bool_) if jumps is None else np.ascontiguousarray(jumps.ravel(), dtype=np.bool_)
    hopeful = kernels.fragments_may_pass(flat, ctx.xyz, np.ascontiguousarray(ctx.sigma, dtype=np.float64), jumps,
                                         adjacency, has_model, kinds, params, rms, sizes,
                                         float(k_sigma), FRAGMENT_SHARE, _FRAGMENT_SAMPLE, SCREEN_SLACK)
    return hopeful, adjacency


def explained_by_hosts(ctx: Context, idx: np.ndarray, fits: dict, hosts: list, scatter: np.ndarray, k_sigma: float):
    """For the flat pixels ``idx``: whether a host explains each within ``k_sigma max(sigma,
    rms)`` (``scatter``: the hosts' rms, a column), the host explaining it best (its index
    in ``hosts``) and the pixels' distances to that host."""
    pts = rows_at(ctx.xyz, idx)
    distance = np.abs(np.stack([fits[h].distances(pts) for h in hosts]))
    score = distance / np.maximum(ctx.sigma[idx], scatter)
    best = np.argmin(score, axis=0)
    at = (best, np.arange(idx.size))
    return score[at] <= k_sigma, best, distance[at]


def _stands_apart(points: np.ndarray, own, hosts: list, best: np.ndarray, explained: np.ndarray) -> bool:
    """Whether the region's ``own`` model, of a kind none of the ``hosts`` that would take
    its ``points`` has (``best``, per point, for those ``explained``), lowers their squared
    distances from those to the hosts by more than its parameters would on noise (an
    F-test): a surface of its own (a pipe's end cap, within a far stereo camera's range
    noise of the pipe's cylinder), not a blob at a junction. Hosts of its own kind were
    weighed by the merge already (a piece of a plane whose small fit a quantised camera
    tilts stays with its plane). The hosts nearest to the points no host explains take
    none of them: a box's side face, 25 tile means at 4.5 m that a cylinder fitted over the
    box's top and front explains but for three, was handed to it because a plane beside it
    was nearest to those three (kinect_real_640x480 study seed 1412 scan 5)."""
    if not own or any(hosts[i].kind == own.kind for i in unique_ints(best[explained]).tolist()):
        return False
    host_squares = sum(squared_distances(host, points[best == i]) for i, host in enumerate(hosts))
    own_squares = squared_distances(own, points)
    return curvature_resolved(host_squares, own_squares, len(points), MODEL_PARAMETERS[own.kind])


def absorb_ripples(xyz: np.ndarray, labels: np.ndarray, fits: dict, sigma: np.ndarray,
                   scatter: dict, *, k_sigma: float,
                   sizes: np.ndarray | None = None, min_cosine: float = 1.0,
                   jump: tuple[float, float] | None = None) -> tuple[np.ndarray, dict, set]:
    """Curved regions that a larger plane within two pixels explains within that plane's
    own scatter, and meets without a range jump, go to the plane: a ripple of the surface,
    not a surface.

    A real camera errs by more than its per-pixel noise: calibration ripple and depth
    quantisation bend a large plane by about its rms over patches of tens to hundreds of
    pixels (the ABW table: pixel rms 0.6 mm against 0.36 mm of quantisation, bumps of
    1.2-1.6 mm). A curved model fits such a bump better than the plane through it, yet
    the surrounding plane explains it as well as it explains its own pixels, that error
    being what the plane's rms measured. So a curved region whose pixels lie, at the
    median, within ``k_sigma max(sigma, scatter)`` of such a plane (``scatter`` the
    plane's rms) is handed to the plane explaining it best; its pixels beyond that become
    unlabelled. A real column or ball stands out of the planes around it by about its
    radius, many times their scatter.

    ``xyz`` (N, 3) and ``sigma`` (N,) are flat; ``scatter`` maps a plane's label to the
    rms of its pixels about it (its model's rms where absent); ``sizes`` is the pixel
    count per label when known (one pass less). ``min_cosine`` below 1: the range noise is
    scaled by each pixel's incidence cosine on the plane, at least ``min_cosine`` (the noise
    of its distance to the plane, :func:`_ripple_spread`); 1 (default): the range noise
    itself. ``jump``: ``(jump_ratio, jump_min)``, the grid's range-jump test
    (:func:`_meets_without_jump`); a plane behind which, or in front of which, the patch
    lies across a jump along their common border is no host, however close the patch lies
    to the plane's extension (kinect_real_640x480 seed 1993 scan 0: a 0.375 m ball at 4.4 m
    half sunk into the plane of a wall seen at 67 degrees, 0.43 m behind the wall's edge
    along the rays, lay at the median 2.3 of the wall's scatters from its plane and was
    absorbed); the plane's pixels along that border count where the plane explains them
    within ``k_sigma`` of their spread (its strays on the patch do not). None: no such
    test. Returns ``(labels, fits, changed)``: the
    new labels (``labels`` itself when nothing changed), ``fits`` without the absorbed
    regions, and the labels whose pixels changed (absorbed regions and the planes that
    took them).
    """
    n = int(labels.max(initial=0)) + 1
    planes = [k for k, m in fits.items() if isinstance(m, Plane) and 0 < k < n]
    curved = [k for k, m in fits.items() if m and not isinstance(m, Plane) and 0 < k < n]
    if not (curved and planes):
        return labels, fits, set()
    labels = np.ascontiguousarray(labels, dtype=np.int32)
    sizes = kernels.label_counts(labels) if sizes is None else np.asarray(sizes)
    table = _PlaneTable(planes, fits, scatter, sizes)
    # only a patch smaller than some plane can be one's ripple (a frame-wide column is
    # skipped without looking at its pixels)
    candidates = np.zeros(n, bool)
    largest = int(table.sizes.max())
    candidates[[k for k in curved if sizes[k] < largest]] = True
    if not candidates.any() or _no_ripple_host(xyz, labels, candidates, sizes, table, sigma, k_sigma):
        return labels, fits, set()
    out, kept, changed = labels, fits, set()
    regions = _candidate_pixels(xyz, labels, candidates, sizes, table, sigma, k_sigma, min_cosine)
    for k in sorted(regions, key=lambda k: regions[k].size):
        idx = regions[k]
        host = _ripple_host(xyz, out, idx, table, sigma, k_sigma, min_cosine, jump)
        if host is None:
            continue
        if out is labels:  # the first ripple: the inputs stay as they are
            out, kept = labels.copy(), dict(fits)
        plane = kept[host]
        points = rows_at(xyz, idx)
        spread = _ripple_spread(points, sigma[idx], plane.normal[None, :],
                                np.array([scatter.get(host, plane.rms)]), min_cosine)[:, 0]
        explained = np.abs(plane.distances(points)) <= k_sigma * spread
        out.ravel()[idx] = np.where(explained, host, 0)
        del kept[k]
        changed |= {k, host}
    return out, kept, changed


class _PlaneTable:
    """The planes a ripple may join, as arrays: labels, normals, offsets, scatter, sizes."""

    def __init__(self, planes: list, fits: dict, scatter: dict, sizes: np.ndarray):
        self.labels = np.array(planes, np.int64)
        self.normals = np.array([fits[k].normal for k in planes])
        self.offsets = np.array([fits[k].d for k in planes])
        self.scatter = np.array([scatter.get(k, fits[k].rms) for k in planes])
        self.sizes = sizes[self.labels]


#: Candidate pixels times planes up to which :func:`_no_ripple_host` reads every candidate's
#: pixels (a laser scan's columns and balls: a few thousand pixels, a few planes); beyond,
#: the candidates are looked at one by one (:func:`_candidate_pixels` samples the large ones).
_RIPPLE_PRETEST_BUDGET = 1 << 16


def _no_ripple_host(xyz, labels, candidates, sizes, table: _PlaneTable, sigma, k_sigma) -> bool:
    """Whether no candidate patch can have a host: for each, no larger plane holds half of its
    pixels within ``k_sigma`` of the largest spread (:func:`_ripple_spread` at cosine 1), in
    one compiled pass over every candidate (:func:`rangeseg_o3d.kernels.ripples_may_pass`, with
    :data:`~rangeseg_o3d.refinement.context.SCREEN_SLACK`); False when their pixels times the
    planes are over the budget.
    :func:`_ripple_host`'s median within ``k_sigma`` of a plane needs that half."""
    if int(np.sum(sizes[:candidates.size][candidates])) * table.labels.size > _RIPPLE_PRETEST_BUDGET:
        return False
    return not kernels.ripples_may_pass(labels.ravel(), np.ascontiguousarray(xyz, dtype=np.float64),
                                        np.ascontiguousarray(sigma, dtype=np.float64), candidates, table.normals,
                                        np.ascontiguousarray(table.offsets, dtype=np.float64), table.scatter,
                                        np.ascontiguousarray(table.sizes, dtype=np.int64), float(k_sigma),
                                        SCREEN_SLACK).any()


def _grouped(pixels: np.ndarray, labels: np.ndarray) -> dict:
    # the flat pixels grouped by their label (each group increasing)
    owner = labels.ravel()[pixels]
    order = np.argsort(owner, kind="stable")
    present, starts = np.unique(owner[order], return_index=True)
    return dict(zip(present.tolist(), np.split(pixels[order], starts[1:])))


#: A curved patch of more pixels is looked at through every ``_RIPPLE_STRIDE``-th row and
#: column first: its pixels are gathered only when that sample may pass.
_RIPPLE_LARGE = 4096
_RIPPLE_STRIDE = 4


def _candidate_pixels(xyz, labels, candidates, sizes, table: _PlaneTable, sigma, k_sigma, min_cosine) -> dict:
    """The flat pixels, by label, of the candidate patches that may be ripples: the small
    ones, and the large ones whose sample on a coarser grid does not rule it out. The
    sample rules a plane out when even its quantile ``0.5 - 1.5 / sqrt(m)`` (m samples: the
    median's three-sigma binomial bound) is beyond ``k_sigma``; a column filling half of a
    frame then costs a sixteenth of its pixels."""
    large = candidates & (sizes[:candidates.size] >= _RIPPLE_LARGE)
    wanted = candidates & ~large
    if large.any():
        grid = labels[::_RIPPLE_STRIDE, ::_RIPPLE_STRIDE]
        rows, cols = np.divmod(np.flatnonzero(large[grid]), grid.shape[1])
        sampled = (rows * labels.shape[1] + cols) * _RIPPLE_STRIDE
        for k, sample in _grouped(sampled, labels).items():
            bigger = table.sizes > sizes[k]
            level = max(0.0, 0.5 - 1.5 / np.sqrt(sample.size))
            wanted[k] = bigger.any() and bool(np.any(
                np.quantile(_scores(xyz, sample, table, bigger, sigma, min_cosine), level, axis=0) <= k_sigma))
    # grouped by one compiled counting sort of the wanted labels (region_indices' ``only``): the
    # same pixels in the same order as _grouped of their member_pixels, without its argsort,
    # np.unique and np.split (~50 us a scan)
    return region_indices(labels, only=np.flatnonzero(wanted).tolist()) if wanted.any() else {}


def _scores(xyz, idx, table: _PlaneTable, which, sigma, min_cosine: float = 1.0) -> np.ndarray:
    # (pixels, planes) distances of the pixels idx from the planes ``which`` of the table,
    # in units of their spread about each plane (:func:`_ripple_spread`)
    points = rows_at(xyz, idx)
    distances = np.abs(points @ table.normals[which].T - table.offsets[which])
    return distances / _ripple_spread(points, sigma[idx], table.normals[which], table.scatter[which], min_cosine)


def _ripple_spread(points: np.ndarray, sigma: np.ndarray, normals: np.ndarray, scatter: np.ndarray,
                   min_cosine: float = 1.0) -> np.ndarray:
    """(pixels, planes) spread a ripple's pixels may have about each plane: the range noise
    ``sigma`` times the incidence cosine of the pixel's ray on the plane (range noise moves
    a point along its ray), the cosine at least ``min_cosine`` (1: the range noise itself),
    and at least the plane's ``scatter``. A plane seen near grazing holds the rays beside
    it: a ball or a box face behind it, a metre away along those rays, lies within the
    range noise of it but not within the noise its incidence leaves."""
    if min_cosine >= 1.0:
        return np.maximum(sigma[:, None], scatter[None, :])
    rays = points / np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-12)
    cosines = np.maximum(np.abs(rays @ normals.T), min_cosine)
    return np.maximum(sigma[:, None] * cosines, scatter[None, :])


#: Scores of a patch against every larger plane are computed before looking for the planes
#: within two pixels when there are at most this many (a small grid's patches: the look
#: costs more than the scores).
_PRESCORE_BUDGET = 16384


def median_may_pass(scores: np.ndarray, limit: float) -> np.ndarray:
    """Per column of ``scores`` (pixels, planes): False where ``np.median`` of the column is
    certainly over ``limit`` (fewer than half of its values, rounded up, are at most
    ``limit``), True where it may not be.

    The median of n values is at least its ``ceil(n / 2)``-th smallest (the mean of the two
    middle ones for even n is at least the lower one, in floating point too), so a column
    with fewer values at most ``limit`` has its median over it: a necessary test, one
    comparison and one count per value instead of a partition per column.
    :func:`_ripple_host` asks it compiled, with a slack over the rounding
    (:func:`_may_pass_somewhere`).
    """
    # a sum of the booleans: np.count_nonzero with an axis costs several times more
    return (scores <= limit).sum(axis=0) >= (scores.shape[0] + 1) // 2


def _may_pass_somewhere(xyz, idx, table: _PlaneTable, which, sigma, k_sigma) -> bool:
    """Whether the median of some plane's (``which``) column of :func:`_scores` of the pixels
    ``idx`` may be within ``k_sigma`` (:func:`median_may_pass`, in one compiled pass with a
    slack over the rounding: False only where numpy's answer is False too)."""
    return bool(kernels.planes_may_hold_half(xyz, sigma, np.ascontiguousarray(idx, dtype=np.int64),
                                             table.normals[which], table.offsets[which], table.scatter[which],
                                             float(k_sigma), SCREEN_SLACK).any())


def _ripple_host(xyz, labels, idx, table: _PlaneTable, sigma, k_sigma, min_cosine: float = 1.0, jump=None):
    """The label of the larger plane within two pixels of the patch ``idx`` whose scatter
    explains it best at the median, within ``k_sigma`` (spreads: :func:`_ripple_spread`),
    and, with ``jump``, that the patch meets without a range jump (:func:`_meets_without_jump`);
    None when there is none. The compiled pre-test judges by the range noise, the largest
    spread: what it refuses, the scores refuse too."""
    larger = table.sizes > idx.size
    if not larger.any():
        return None
    if idx.size * np.count_nonzero(larger) <= _PRESCORE_BUDGET and not _may_pass_somewhere(
            xyz, idx, table, larger, sigma, k_sigma):
        return None  # no larger plane anywhere explains it at the median: none nearby does
    # only the planes within two pixels can host it: their columns alone are scored (each
    # plane's median is its own column's)
    near = touching(labels, idx, reach=2)
    larger &= np.fromiter((k in near for k in table.labels.tolist()), bool, count=table.labels.size)
    if not larger.any():
        return None
    middle = np.median(_scores(xyz, idx, table, larger, sigma, min_cosine), axis=0)
    passing = middle <= k_sigma
    hosts = sorted(zip(middle[passing].tolist(), table.labels[larger][passing].tolist()))
    for _, host in hosts:
        if jump is None or _meets_without_jump(
                xyz, labels, idx, host, *jump, noise=(sigma, k_sigma),
                on_plane=lambda pixels: _scores(xyz, pixels, table, table.labels == host, sigma,
                                                min_cosine)[:, 0] <= k_sigma):
            return host
    return None


#: The least share of the neighbour pairs a ripple and its plane share that must step by no
#: range jump: a ripple is the plane's own surface along its whole border.
RIPPLE_CONTACT = 0.5


def _meets_without_jump(xyz, labels, idx, host: int, jump_ratio: float, jump_min: float, on_plane=None,
                        noise=None) -> bool:
    """Whether the patch ``idx`` (flat, increasing) meets the region ``host`` of ``labels``
    without a range jump: of the pairs of a patch pixel and a host pixel next to each other
    (rows, columns and diagonals), at least :data:`RIPPLE_CONTACT` step in range by no more
    than ``max(jump_min, jump_ratio * r)``, r the nearer range (the growth's test), or than
    the two pixels' range noise allows (``noise``: flat sigma and k_sigma; ``k_sigma`` times
    their sigmas combined): a stereo camera's pixels on one wall at 5.5 m step by more than
    the jump test (stereo_1280x720 study seed 1262 scan 0: a cylinder over a box and the
    wall 1.2 m behind it, whose wall pixels go to the wall and free the box's faces, met
    the wall "across jumps" along its own wall pixels). Where the
    two do not touch, the pairs two pixels apart are judged with twice the step allowed.

    ``on_plane``: a function of flat pixels telling which lie on the host's plane; only
    those count as the host's (None: all of its pixels). A region holds strays off its
    plane, and a ball's region meets the strays the wall's region took on the ball without
    a jump (kinect_640x480 study seed 1414 scan 0: 184 of the 359 pixels of the box top's
    region about a ball behind it lay on the ball, off the top's plane)."""
    height, width = labels.shape
    rows, cols = np.divmod(np.asarray(idx, dtype=np.int64), width)
    top, left = max(int(rows.min()) - 2, 0), max(int(cols.min()) - 2, 0)
    bottom, right = min(int(rows.max()) + 3, height), min(int(cols.max()) + 3, width)
    box = (slice(top, bottom), slice(left, right))
    ranges = np.linalg.norm(np.asarray(xyz).reshape(height, width, 3)[box], axis=-1)
    spread = np.zeros(ranges.shape) if noise is None else noise[1] * np.asarray(noise[0]).reshape(height, width)[box]
    patch = np.zeros(ranges.shape, bool)
    patch[rows - top, cols - left] = True
    plane = labels[box] == host
    if on_plane is not None:
        from scipy import ndimage

        # only the host's pixels within two pixels of the patch can pair with it: those alone are scored
        plane &= ndimage.binary_dilation(patch, structure=np.ones((5, 5), bool))
        inside = np.flatnonzero(plane)
        box_rows, box_cols = np.divmod(inside, plane.shape[1])
        plane.ravel()[inside] = on_plane((box_rows + top) * width + box_cols + left)
    for reach in (1, 2):
        steps, allowed = [], []
        for dr in range(-reach, reach + 1):
            for dc in range(-reach, reach + 1):
                if max(abs(dr), abs(dc)) != reach:
                    continue
                a, b = _shifted_pair(ranges.shape, dr, dc)
                pairs = patch[a] & plane[b]
                near, far = ranges[a][pairs], ranges[b][pairs]
                steps.append(np.abs(near - far))
                allowed.append(np.maximum(reach * np.maximum(jump_min, jump_ratio * np.minimum(near, far)),
                                          np.hypot(spread[a][pairs], spread[b][pairs])))
        steps, allowed = np.concatenate(steps), np.concatenate(allowed)
        if steps.size:
            return bool(np.count_nonzero(steps <= allowed) >= RIPPLE_CONTACT * steps.size)
    return True  # (no pair within two pixels: nothing says the patch lies across a jump)


def _shifted_pair(shape, dr: int, dc: int):
    # slices a, b of an array of ``shape`` such that [a] and [b] are neighbours dr rows and
    # dc columns apart (b = a + (dr, dc))
    height, width = shape
    a = (slice(max(-dr, 0), height - max(dr, 0)), slice(max(-dc, 0), width - max(dc, 0)))
    b = (slice(max(dr, 0), height - max(-dr, 0)), slice(max(dc, 0), width - max(-dc, 0)))
    return a, b
