"""The leftover strips too thin for a blob's 3x3 core (a face seen edge-on), recovered in one
batched step whose cost follows the strips, not the frame.

A VGA depth frame leaves tens of such strips along its edges once the blobs' surfaces have
grown and merged. Each is one of these things: a band of a surface the scan already has
(its pixels lie within the noise of a region it touches), a face of its own (its plane
explains it within the noise of its distances), or a band across the viewing rays of a
curved surface or a crease (its least-squares plane lies along its rays: beyond the noise
of its distances), or, on a stereo camera, a face seen near grazing whose depth the range
noise spans (its plane fitted along the rays explains it). Every test reads the strips'
pixels alone, in compiled passes over all strips at once (:mod:`rangeseg_o3d.kernels.strips`;
the stereo camera's planes along the rays strip by strip, few strips); only the faces found
grow their rims, each within its own box.
"""

from __future__ import annotations

import numpy as np

from ._numeric import unique_ints
from . import kernels
from .fitting.batch_planes import planes_from_moments, region_moments
from .fitting.region_fitter import extended_table, fresh_label, model_table
from .kernels.linalg import CHI_SQUARE_SIGMAS, noise_rms_bound
from .ray_planes import ray_plane, ray_terms, robust_ray_plane
from .refinement.recover import grown_box

__all__ = ["recover_strips"]

#: The share of a strip's pixels a model must explain (within its noise band) to take it,
#: as a blob's plane must (:func:`rangeseg_o3d.refinement.recover._one_plane`).
EXPLAINED_SHARE = 0.9
#: A strip whose plane leaves it an rms under this share of the noise of its distances shows
#: no noise at all: its pixels sit on one level of a quantised depth (a far wall's terrace
#: on a Kinect frame, every pixel at one depth), whatever surface they sample.
NO_NOISE_SHARE = 0.1
#: A face found in a strip takes back this many rings of its rim, then its model may claim
#: this many rings from its neighbours (as :func:`rangeseg_o3d.refinement.recover.recover_pixels`).
RIM_RINGS, CLAIM_RINGS = 2, 3
#: The distance-noise band of a pixel a face keeps of what it took after its fit (as
#: ``refinement.context.TRIM_SIGMAS``).
TRIM_SIGMAS = 3.0


def recover_strips(cloud, labels: np.ndarray, fits: dict, stats, *, fitter, config, sensor,
                   ranges: np.ndarray, sigma: np.ndarray, inlier_factor: float):
    """The leftover strips (4-connected pieces of free pixels with no 3x3 core, of at least
    :func:`rangeseg_o3d.fullres.recovered_region_floor` pixels) each joined to a region
    they touch whose model explains them, made a plane region of their own, or left free.
    Returns ``(labels, fits, stats)``; the inputs when nothing changed.

    A strip whose least-squares plane leaves its pixels beyond the noise of their distances
    to it (range noise times the incidence cosine, chi-square bound) lies along its viewing
    rays and is left free; except on a stereo camera (range noise growing with the range and
    erring together over a matching window, ``noise.correlation_px > 1``), where it may be a
    face seen near grazing whose depth the noise spans: it becomes a region when its plane
    fitted along the rays explains it (:meth:`_Strips.faces_along_rays`); so too, where the
    range noise grows with the range alone and spans more than a pixel's footprint at every
    range (a Kinect, :func:`rangeseg_o3d.scales.noise_spans_the_grid`), a strip the frame's edge cuts thin, lying
    along it, unless a region's model explains it within the range noise
    (:func:`_on_a_found_surface`). A strip
    of which a touching region's model explains
    ``EXPLAINED_SHARE`` of the pixels within ``k_sigma`` of that noise (at least the model's
    rms), with an rms distance within its chi-square bound, joins the region that explains
    it best; with ``config.merge_disjoint`` (pieces of one surface apart are one region), so
    does a strip no touching region takes, of the plane regions anywhere. Otherwise a strip
    the fitter's batch settles as a plane explaining that share within ``3 max(sigma, rms)``
    becomes a region; it takes back its rim and claims the rings its model explains better
    than their regions' (in its box), and keeps of those gains only the pixels within
    ``TRIM_SIGMAS`` of their distance noise.
    """
    from .fullres import leftover_blob_labels, recovered_region_floor, smallest_region, stats_with_moved
    from .scales import noise_spans_the_grid, with_derived_refinement

    config = with_derived_refinement(config, sensor, cloud)
    min_size = smallest_region(config, sensor, cloud)
    floor = recovered_region_floor(config, min_size, sensor.noise.correlation_px)
    first = fresh_label(labels, fits)
    found = leftover_blob_labels(labels, cloud.valid, min_size=min_size, first_label=first, thin_min_size=floor)
    if found is None:
        return labels, fits, stats
    candidates, boxes, first_thin = found
    boxes = np.ascontiguousarray(boxes[first_thin - first:], dtype=np.int64)
    if not boxes.shape[0]:
        return labels, fits, stats
    pixels, starts = kernels.box_members(np.ascontiguousarray(candidates, dtype=np.int32), boxes, first_thin)
    xyz = np.ascontiguousarray(cloud.xyz.reshape(-1, 3), dtype=np.float64)
    noise = np.ascontiguousarray(sigma, dtype=np.float64).ravel()
    strips = _Strips(xyz, noise, pixels, starts, float(config.k_sigma))
    across = strips.across_rays()
    open_ = across & (strips.sizes >= floor)
    noise_model = sensor.noise
    # a stereo camera's grazing faces: the strips whose least-squares plane lies along their
    # rays may be faces whose depth its range noise spans (_Strips.faces_along_rays); only
    # where that noise grows with the range and errs together over a matching window. Where
    # it grows with the range alone (a Kinect), the strips the frame's edge cuts: a face the
    # edge leaves a few pixels wide lies in the partial, mixed tiles there (640 = 106 x 6 + 4),
    # and its few columns' least-squares plane turns towards the rays as a grazing face's does
    # (a strip along the edge: one across it, a pipe's limb from the top edge down, is not cut
    # thin by it), where the range noise spans more than a pixel's footprint at every range
    # (a laser whose noise is stated growing with the range spans less at the ranges it sees)
    along = ~across & (strips.sizes >= floor)
    if not noise_model.matched_window:
        h, w = labels.shape
        along &= _along_the_frames_edge(boxes, h, w)
        if along.any() and not noise_spans_the_grid(sensor, cloud):
            along[:] = False
    if not (open_.any() or along.any()):
        return labels, fits, stats
    table = model_table(fits, first)  # (the regions' models: the strips change none of them)
    joins, merges = strips.joins(labels, table, open_, stats, config.merge_rms_factor if config.merge else None,
                                 apart=config.merge_disjoint)
    faces = strips.faces(fitter, open_ & (joins == 0) & (merges == 0), floor)
    along_faces = strips.faces_along_rays(along, floor, 1.0 / noise_model.correlation_px ** 2, labels.shape[1])
    if along_faces and not noise_model.matched_window:  # (a band of a surface found: no face)
        along_faces = [f for f in along_faces if not _on_a_found_surface(xyz, noise, fits, f[1])]
    faces += along_faces
    if not (joins.any() or merges.any() or faces):
        return labels, fits, stats
    out = np.array(labels, dtype=np.int32, order="C", copy=True)
    flat = out.ravel()
    for s in np.flatnonzero(joins).tolist():
        flat[pixels[starts[s]:starts[s + 1]]] = joins[s]
    # a strip the merge takes into a plane keeps its pixels on that plane's surface
    merged, owner = strips.within_band(merges, table)
    flat[merged] = owner
    fits = dict(fits)
    grown_boxes = []
    for j, (s, kept, model) in enumerate(faces):
        flat[kept] = first + j
        fits[first + j] = model
        grown_boxes.append(grown_box(boxes[s], RIM_RINGS + CLAIM_RINGS, out.shape))
    table = extended_table(table, [model for _, _, model in faces])
    moved = ([pixels[starts[s]:starts[s + 1]] for s in np.flatnonzero(joins)] + [merged]
             + [kept for _, kept, _ in faces])
    if faces:
        moved.append(_grow_faces(xyz, out, table, noise, first, grown_boxes, config.k_sigma))
    changed = unique_ints(np.concatenate(moved))
    return out, fits, stats_with_moved(stats, xyz, noise, labels, out, table, changed, inlier_factor)


class _Strips:
    """The strips' flat pixels (``pixels[starts[s]:starts[s + 1]]`` for strip ``s``) and
    their least-squares planes, from one moments pass over their pixels."""

    def __init__(self, xyz: np.ndarray, sigma: np.ndarray, pixels: np.ndarray, starts: np.ndarray,
                 k_sigma: float):
        self.xyz, self.sigma, self.pixels, self.k_sigma = xyz, sigma, pixels, k_sigma
        self.starts = np.ascontiguousarray(starts, dtype=np.int64)
        self.sizes = np.diff(self.starts)
        n = self.sizes.size
        ids = np.repeat(np.arange(1, n + 1, dtype=np.int32), self.sizes)
        self.ids = ids
        self.points = xyz[pixels]
        self.planes = planes_from_moments(region_moments(self.points, ids, n + 1))

    def _stats(self, rows: np.ndarray, kinds: np.ndarray, params: np.ndarray, rms: np.ndarray):
        # (counts, rms, noise rms, within) of strip ``rows[i]`` under model row i
        counts, squares, noise_squares, within = kernels.strip_fit_stats(
            self.xyz, self.sigma, self.pixels, self.starts[rows], self.starts[rows + 1],
            np.ascontiguousarray(kinds, dtype=np.int8), np.ascontiguousarray(params, dtype=np.float64),
            np.ascontiguousarray(rms, dtype=np.float64), self.k_sigma)
        n = np.maximum(counts, 1).astype(float)
        return counts, np.sqrt(squares / n), np.sqrt(noise_squares / n), within

    def across_rays(self) -> np.ndarray:
        """Per strip: whether its least-squares plane explains its pixels within the noise of
        their distances (a band lying along its rays does not; see
        :meth:`rangeseg_o3d.refinement.context.Context.plane_along_rays`), nor far within it
        (an rms under ``NO_NOISE_SHARE`` of that noise: a terrace of quantised depth)."""
        from .kernels.kinds import PLANE

        n = self.sizes.size
        params = np.zeros((n, 7))
        params[:, :3] = self.planes.normal[1:]
        params[:, 3] = self.planes.d[1:]
        counts, rms, noise_rms, _ = self._stats(np.arange(n), np.full(n, PLANE, np.int8), params, np.zeros(n))
        ok = self.planes.ok[1:].astype(bool) & (counts > 0)
        dof = counts.astype(float)
        # a plane that explains the strip far better than the noise of its distances allows
        # is not the surface's: the strip lies on one terrace of a quantised depth (every
        # pixel at one depth, a plane of rms 0 where the range noise is centimetres)
        terrace = rms < NO_NOISE_SHARE * noise_rms
        return ok & ~terrace & ~(rms > noise_rms_bound.py_func(noise_rms, dof, CHI_SQUARE_SIGMAS))

    def joins(self, labels: np.ndarray, table: tuple, open_: np.ndarray, stats, rms_factor: float | None,
              apart: bool = False):
        """``(explained, merged)``, per strip a region (0: none) of those it touches
        (``table``: their models, :func:`rangeseg_o3d.fitting.region_fitter.model_table`):
        the one whose model explains it best, when one does (see :func:`recover_strips`);
        else, with ``rms_factor`` (merging on), the plane region a union with which the
        merge would take (:meth:`_union_rms`), the lowest union rms first. With ``apart``
        (pieces of one surface apart are one region), a strip no touching region takes joins
        the plane region anywhere whose model explains it best, when one does."""
        from .kernels.kinds import PLANE

        kinds = table[0]
        strip, label = kernels.strip_touching(np.ascontiguousarray(labels, dtype=np.int32).ravel(),
                                              labels.shape[0], labels.shape[1], self.pixels, self.starts, kinds)
        keep = open_[strip]
        strip, label = strip[keep], label[keep]
        explained, merged = np.zeros(self.sizes.size, np.int64), np.zeros(self.sizes.size, np.int64)
        if strip.size:
            counts, pair_rms = self._explained(strip, label, table, explained)
            if rms_factor is not None:
                union, limit = self._union_rms(strip, label, counts, pair_rms, stats, rms_factor)
                _best(merged, strip, label, (kinds[label] == PLANE) & (union <= limit) & (explained[strip] == 0),
                      union / np.maximum(limit, 1e-12))
        if apart:
            # (a far wall's strip between two pipes at the frame's top edge, beside none of its pixels)
            alone = np.flatnonzero(open_ & (explained == 0) & (merged == 0))
            planes = np.flatnonzero(kinds == PLANE)
            planes = planes[planes > 0]
            if alone.size and planes.size:
                self._explained(np.repeat(alone, planes.size), np.tile(planes, alone.size), table, explained)
        return explained, merged

    def _explained(self, strip: np.ndarray, label: np.ndarray, table: tuple, explained: np.ndarray):
        # of the (strip, region) pairs, per strip the region whose model explains it best, when
        # one does (written into ``explained``); returns the pairs' pixel counts and rms
        kinds, params, rms = table
        counts, pair_rms, noise_rms, within = self._stats(strip, kinds[label], params[label], rms[label])
        fine = ((counts > 0) & (within >= EXPLAINED_SHARE * self.sizes[strip])
                & ~(pair_rms > noise_rms_bound.py_func(noise_rms, counts.astype(float), CHI_SQUARE_SIGMAS)))
        _best(explained, strip, label, fine, pair_rms / np.maximum(noise_rms, 1e-12))
        return counts, pair_rms

    def _union_rms(self, strip, label, counts, pair_rms, stats, rms_factor: float):
        # per (strip, plane region) pair: the rms of the union under the region's plane (a
        # bound on the union's refit), and the merge's limit on it, ``rms_factor`` times the
        # larger of the parts' rms (the region's pixels' under its model, the strip's plane's).
        # Adjacent planes are always merge candidates: the union decides
        # (:func:`rangeseg_o3d.refinement.merge.merge_candidates`).
        inside = label < stats.counts.size
        own = np.where(inside, label, 0)
        region_n = np.where(inside, stats.counts[own], 0).astype(float)
        region_sq = np.where(inside, stats.squares[own], 0.0)
        union = np.sqrt((region_sq + counts * pair_rms ** 2) / np.maximum(region_n + counts, 1.0))
        region_rms = np.sqrt(region_sq / np.maximum(region_n, 1.0))
        return union, rms_factor * np.maximum(region_rms, self.planes.rms[strip + 1])

    def within_band(self, chosen: np.ndarray, table: tuple):
        """``(pixels, regions)``: the flat pixels of the strips with a plane region in
        ``chosen`` (0: none) within ``TRIM_SIGMAS`` of their distance noise to its plane
        (range noise x incidence cosine, at least its rms), and that region for each."""
        kinds, params, rms = table
        rows = np.flatnonzero(chosen)
        if not rows.size:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        pick = np.flatnonzero(chosen[self.ids - 1])
        idx, owner = self.pixels[pick], chosen[self.ids[pick] - 1]
        points = self.points[pick]
        along = np.einsum("ij,ij->i", points, params[owner, :3])
        cosine = np.abs(along) / np.maximum(np.linalg.norm(points, axis=1), 1e-12)
        near = np.abs(along - params[owner, 3]) <= TRIM_SIGMAS * np.maximum(self.sigma[idx] * cosine, rms[owner])
        return idx[near], owner[near]

    def faces(self, fitter, asked: np.ndarray, floor: int) -> list:
        """``(strip, kept pixels, plane)`` of each strip of ``asked`` the fitter's batch settles
        as a plane explaining ``EXPLAINED_SHARE`` of it within ``3 max(sigma, rms)``, its
        kept pixels (those within) at least ``floor``."""
        if not asked.any():
            return []
        rows = np.flatnonzero(asked[self.ids - 1])
        settled = fitter.fit_batch(self.points[rows], self.ids[rows])
        found = sorted(k - 1 for k, m in settled.items() if m and m.kind == "plane")
        if not found:
            return []
        # every settled strip's pixels against its plane at once
        normal = np.zeros((self.sizes.size, 3))
        offset, spread = np.zeros(self.sizes.size), np.zeros(self.sizes.size)
        for s in found:
            normal[s], offset[s], spread[s] = settled[s + 1].normal, settled[s + 1].d, settled[s + 1].rms
        on = np.zeros(self.sizes.size, bool)
        on[found] = True
        rows = np.flatnonzero(on[self.ids - 1])
        owner = self.ids[rows] - 1
        distance = np.einsum("ij,ij->i", self.points[rows], normal[owner]) - offset[owner]
        near = np.abs(distance) <= 3.0 * np.maximum(self.sigma[self.pixels[rows]], spread[owner])
        count = np.bincount(owner[near], minlength=self.sizes.size)
        kept = rows[near]
        out = []
        for s in found:
            if count[s] >= EXPLAINED_SHARE * self.sizes[s] and count[s] >= floor:
                out.append((s, self.pixels[kept[owner[near] == s]], settled[s + 1]))
        return out

    def faces_along_rays(self, asked: np.ndarray, floor: int, share: float, width: int) -> list:
        """``(strip, kept pixels, plane)`` of each strip of ``asked`` whose plane fitted along
        its rays (:func:`rangeseg_o3d.ray_planes.robust_ray_plane`) explains ``EXPLAINED_SHARE`` of it within
        ``TRIM_SIGMAS`` of the noise of its inverse ranges, the kept pixels (at least
        ``floor``) scattering about it no more than that noise: their mean square in noise
        units within the chi-square bound of their independent returns (``share`` per pixel:
        a stereo camera's noise errs together over its matching window). ``width``: the
        grid's columns (the strips' pixels are flat indices).

        A face seen near grazing by a camera whose range noise is a good part of the face's
        depth (a box's top a few pixels high, a few metres off) is a thin cloud spread along
        its rays: its least-squares plane turns towards the rays and leaves the pixels
        beyond the noise of their distances (:meth:`across_rays` refuses it). The range
        errors move only the inverse ranges along the rays, which the face's plane fits
        within their noise (:func:`rangeseg_o3d.ray_planes.ray_terms`)."""
        out = []
        for s in np.flatnonzero(asked).tolist():
            idx = self.pixels[self.starts[s]:self.starts[s + 1]]
            points = self.points[self.starts[s]:self.starts[s + 1]]
            rays, inverse, weight = ray_terms(points, self.sigma[idx])
            rows, cols = np.divmod(idx, width)
            found = robust_ray_plane(rays, inverse, weight, rows, cols)
            if found is None:
                continue
            a, keep, mean_square = found
            n = int(np.count_nonzero(keep))
            if n < EXPLAINED_SHARE * idx.size or n < floor:
                continue
            # (the noise band trims the tails: a normal's mean square within it is under 1)
            if mean_square > noise_rms_bound.py_func(1.0, share * n, CHI_SQUARE_SIGMAS) ** 2:
                continue
            plane = ray_plane(a, points[keep])
            if plane is not None:
                out.append((s, idx[keep], plane))
        return out


def _best(out: np.ndarray, strip: np.ndarray, label: np.ndarray, fine: np.ndarray, score: np.ndarray) -> None:
    # out[s] = the label of strip s's fine pair of lowest score (in place; strips without one keep 0)
    order = np.lexsort((score, strip))
    for i in order[fine[order]][::-1]:  # the last written is the best
        out[strip[i]] = label[i]


def _grow_faces(xyz, out, table, sigma, first, boxes, k_sigma):
    # the faces first, first + 1, ... of ``out`` (one per box) take back their rims and
    # claim the rings they explain better, each within its box (in place), and keep of
    # that the pixels within TRIM_SIGMAS of their distance noise; returns the flat pixels
    # they took (kept or given back)
    kinds, params, rms = table
    return kernels.grow_faces(xyz, out.ravel(), out.shape[0], out.shape[1], kinds, params, rms, sigma, first,
                              np.array(boxes, np.int64).reshape(-1, 4), RIM_RINGS, CLAIM_RINGS, float(k_sigma),
                              TRIM_SIGMAS)


def _along_the_frames_edge(boxes: np.ndarray, h: int, w: int) -> np.ndarray:
    """Per strip box ``(row0, row1, col0, col1)`` (ends exclusive) in an ``h`` x ``w`` frame:
    whether it touches the frame's left or right edge and is narrower in columns than in
    rows, or its top or bottom edge and narrower in rows than in columns: a strip the edge
    cut thin, lying along it."""
    tall = (boxes[:, 1] - boxes[:, 0]) > (boxes[:, 3] - boxes[:, 2])
    wide = (boxes[:, 3] - boxes[:, 2]) > (boxes[:, 1] - boxes[:, 0])
    sides = (boxes[:, 2] == 0) | (boxes[:, 3] == w)
    ends = (boxes[:, 0] == 0) | (boxes[:, 1] == h)
    return (sides & tall) | (ends & wide)


def _on_a_found_surface(xyz: np.ndarray, sigma: np.ndarray, fits: dict, idx: np.ndarray) -> bool:
    """Whether any region's model in ``fits`` explains the pixels ``idx`` (flat) within their
    range noise: their distances to it, in range sigmas ``sigma``, with a mean square within
    the chi-square bound of their count. Such a strip is a band of a surface already found
    (a large plane's edge the frame's edge cuts off from its region, a pipe's flank) whose
    depth the noise spreads along the rays, not a face of its own."""
    bound = noise_rms_bound.py_func(1.0, float(idx.size), CHI_SQUARE_SIGMAS) ** 2
    points = xyz[idx]
    for label, model in fits.items():
        if label <= 0 or not model or not hasattr(model, "distances"):  # (no model: a failed fit)
            continue
        units = model.distances(points) / sigma[idx]
        if float(np.mean(units * units)) <= bound:
            return True
    return False
