"""Step 3, ``recover``: compact blobs of unlabelled pixels are split into every surface they hold.

Small curved objects far away have a residual above the threshold everywhere, so no
region seeds them and growth cannot reach them: the edge band swallows them whole. Runs
after ``grow``, so only what no neighbour explains is left over; recovered blobs then take
back their rims (two rings of growth, timed with this step).

:func:`recover_pixels` is the same step at full resolution after a run on tile means.
"""

from __future__ import annotations

import numpy as np

from .._numeric import rows_at, unique_ints
from ..fitting.region_fitter import fresh_label, model_row, model_table, region_indices
from ..kernels.kinds import PARAM_SLOTS
from ..fitting.plane import fit_plane
from ..fitting.primitives import FitFailure, Plane
from ..fitting.robust import CHI_SQUARE_SIGMAS, beyond_noise, distance_noise, lateral_distance_noise
from .. import kernels  # the package: its names load on first use (no compiler at import)
from ..kernels.grid import free_pixels, free_pixels_in_boxes
from ..kernels.leftovers import free_near_planes_reach, pieces_apart, strip_pool
from ..kernels.labelwise import claim_parts, rows_with_any, voted_columns, within_plane_noise
from ..scales import GRAZING_COSINE, GRAZING_TAN, pixelwise_noise_spans_the_grid
from .context import SCREEN_SLACK, TRIM_SIGMAS, Context, returns_across, touching
from .grow import grow_into_edges, grow_regions, refit_grown
from .curved_refused import curved_for_refused, full_resolution_samples
from .sight import seen_past_plane
from .merge import curved_pairs_apart, merge_into_curved, merge_regions

__all__ = ["along_rays_max_cosine", "claim_grazing_limbs", "differing_pixels", "faces_of_unexplained",
           "fits_refused_along_rays", "leftover_candidates", "planes_fitted_along_rays", "split_blobs",
           "claim_occluded_strips", "claim_thin_strips", "recover_leftovers", "recover_pixels"]


def leftover_candidates(labels: np.ndarray, valid: np.ndarray, jumps: np.ndarray, *,
                        min_size: int, first_label: int) -> np.ndarray:
    """Compact blobs of valid, unlabelled, non-jump pixels: regions the edge band swallowed whole.

    Small curved objects far away have a residual above the threshold everywhere, so no
    region seeds them and growth cannot reach them. The leftover pixels form a network of
    thin crease bands with such blobs attached; one 3x3 erosion cuts the bands, the
    surviving cores are flood-filled, then dilated back by one pixel within the leftover.

    Returns
    -------
    (H, W) int32 candidate labels numbered from ``first_label`` (0 elsewhere); each must
    still be accepted by a fit.
    """
    if np.shape(valid) != labels.shape or np.shape(jumps) != labels.shape:
        raise ValueError(f"leftover_candidates: valid and jumps must have the labels' shape {labels.shape}, "
                         f"got {np.shape(valid)} and {np.shape(jumps)}")
    # one compiled pass (kernels.leftover_blobs: the erosion, OpenCV's raster-order numbering of
    # the cores, the dilation within the leftover, the sizes and the renumbering) on the pixels
    # that are no jump: a dozen OpenCV and numpy calls over the grid cost ~0.2 ms an LMS200 scan
    leftover = np.ascontiguousarray(np.logical_and(valid, np.logical_not(jumps)), dtype=np.bool_)
    candidates, _, _, _ = kernels.leftover_blobs(np.ascontiguousarray(labels, dtype=np.int32), leftover,
                                                 int(min_size), int(first_label))
    return candidates


def _one_plane(ctx: Context, idx: np.ndarray, plain, *, thin: bool = False):
    """``(pixels, model)`` when the plane ``plain`` fitted to the blob ``idx`` explains 90 %
    of it (its largest connected piece of them), else ``(None, None)``; a plane seen near
    grazing beyond the noise of its pixels' distances gives way to the plane a search at
    that noise finds (:meth:`Context.grazing_piece`), when it finds one, unless the blob is
    ``thin`` (a strip a few pixels across holds one face: the search takes a sliver of it)."""
    if not plain:
        return None, None
    near = np.abs(plain.distances(rows_at(ctx.xyz, idx))) <= 3.0 * np.maximum(ctx.sigma[idx], plain.rms)
    if near.mean() < 0.9:
        return None, None
    chosen, model = ctx.largest_piece(idx[near]), plain
    if chosen.size < 0.9 * near.sum():  # a piece was cut off: fit the piece itself
        model = ctx.fitter.refit(ctx.fitter.points(ctx.xyz, chosen), plain)
    if model and ctx.grazing_search and not thin and ctx.seen_along_rays(model, chosen):
        # seen near grazing, the range-noise band holds what is not one plane (two parallel
        # faces a few centimetres apart): the plane the blob's distance noise finds instead
        grazing = ctx.grazing_piece(idx, float(np.median(ctx.sigma[idx])), model)
        if grazing is not None:
            return grazing
    return chosen, model


def split_blobs(ctx: Context, labels: np.ndarray, fits: dict, candidates: np.ndarray, *,
                regions: dict | None = None, thin_from: int | None = None, face_band: bool = False,
                correlation_px: int = 1, min_angle_deg: float = 0.0):
    """Split each candidate blob into every surface it holds; free what none explains.

    ``candidates`` numbers the blobs (0 elsewhere, numbers above every label). A blob
    left over at full resolution may hold several faces (small faces between creases
    the tile grid could not see): the ``split`` step's sequential robust extraction
    (:func:`rangeseg_o3d.refinement.split.split_regions`) gives each its region, where
    explaining the blob by one dominant surface would drop the rest. Returns new
    ``(labels, fits)``; the first surface of a blob keeps the blob's number. ``regions``
    (optional): each blob's flat pixels (increasing), when the caller has them.

    Blobs numbered from ``thin_from`` on are thin strips (no pixel of them has a 3x3
    neighbourhood of leftover pixels: a box side seen edge-on): a strip two or three pixels
    across resolves no curvature across it and holds no second surface a split could find,
    so it becomes one plane, kept when that plane explains it as :func:`_one_plane` asks and
    its piece has the fewest returns that tell a plane (``scales.MIN_PIXELS``), or is freed.
    ``face_band``: the split's (:meth:`Context.dominant_piece`).

    On a sensor whose range noise errs together over ``correlation_px`` x ``correlation_px``
    pixels (> 1), a blob one plane explains within its range noise may still be two faces:
    a small far box's top and side lie within three sigmas of the plane bent over both, and
    no pixel stands out, yet over the blob's independent returns the crease shows. Its plane
    is then offered to :func:`rangeseg_o3d.plane_faces.faces_of_plane` (the faces at least
    ``min_angle_deg`` apart), as the tile grid's plane regions are on such a sensor. And a
    blob of two faces' floor of pixels or more that the split explains nothing of is given
    the faces its crease lines cut (:func:`faces_of_unexplained`) before it is freed: stereo
    study seed 1365 scan 1, a box seen corner-on at 3.6-4.9 m, its top and two sides one blob
    of 16478 px in which the trimmed search found no surface; its faces now hold 3407 of the
    top's 3418 px, 7538 of 7971 and 6968 of 7443.
    """
    from .split import split_regions

    if regions is None:
        regions = region_indices(candidates)
    pool = np.sort(np.concatenate(list(regions.values()))) if regions else np.zeros(0, np.int64)
    # the candidates' numbers are above every label: a maximum puts them in (at their pixels
    # alone: elsewhere the candidates are 0)
    labels, fits = np.array(labels, dtype=np.int32, order="C"), dict(fits)
    flat = labels.ravel()
    flat[pool] = np.maximum(candidates.reshape(-1)[pool], flat[pool])
    # blobs that are one plane need no search (one batched pass settles them); the batch
    # reads each blob's pixels in raster order, so the blobs' pixels alone give the same
    # moments, planes and counts as the whole grid
    settled = ctx.fitter.fit_batch(rows_at(ctx.xyz, pool), candidates.reshape(-1)[pool]) if regions else {}
    mixed = []
    for k, idx in regions.items():
        if thin_from is not None and k >= thin_from:
            _one_thin_plane(ctx, flat, fits, k, idx)
            continue
        chosen, model = _one_plane(ctx, idx, settled.get(k))
        # a plane explaining 90 % of the blob may leave a face of its own beside it (a box
        # side of 100 pixels in a blob of the table's 1100): that blob is split, its
        # surfaces found one after the other
        if chosen is None or not model or chosen.size < ctx.min_size or idx.size - chosen.size >= ctx.min_size:
            mixed.append(k)
            continue
        flat[idx] = 0
        flat[chosen] = k
        fits[k] = model
    first_split = fresh_label(labels, fits)  # (the split's surfaces past the first take labels from here)
    labels, fits = split_regions(ctx, labels, {**fits, **dict.fromkeys(mixed)}, mixed,
                                 pixels={k: regions[k] for k in mixed}, own=True,  # (its copy above)
                                 face_band=face_band)
    flat = labels.ravel()
    for k in [k for k in mixed if not fits.get(k)]:  # a blob nothing explains keeps its pixels
        del fits[k]
        flat[regions[k]] = 0
        if correlation_px > 1 and regions[k].size >= 2 * ctx.min_size:
            # (or its crease lines' faces, where the noise errs together: see above)
            _give_faces(labels, fits, k, faces_of_unexplained(ctx, regions[k], min_angle_deg))
    if correlation_px > 1:
        _faces_of_blob_planes(ctx, labels, fits, pool, [k for k in regions if thin_from is None or k < thin_from],
                              first_split, correlation_px, min_angle_deg)
    return labels, fits


def _faces_of_blob_planes(ctx: Context, labels: np.ndarray, fits: dict, pool: np.ndarray, blobs: list,
                          first_split: int, correlation_px: int, min_angle_deg: float) -> None:
    """Each plane :func:`split_blobs` found in the cored blobs ``blobs`` (their labels, and
    the split's from ``first_split`` on; pixels among the flat ``pool``) that hides two faces
    over correlated returns (:func:`rangeseg_o3d.plane_faces.faces_of_plane`, the faces at
    least ``min_angle_deg`` apart) gives way to them, the largest keeping its label (in place)."""
    from ..plane_faces import faces_of_plane  # (plane_faces imports the refinement's context)

    flat = labels.reshape(-1)
    owners = flat[pool]
    found = set(blobs)
    planes = [k for k in unique_ints(owners[owners > 0]).tolist()
              if (k in found or k >= first_split) and fits.get(k) and fits[k].kind == "plane"]
    for k in planes:
        idx = pool[owners == k]  # (increasing, as the pool)
        faces = sorted(faces_of_plane(ctx, fits[k], idx, correlation_px=correlation_px, min_angle_deg=min_angle_deg),
                       key=lambda face: -face[0].size)
        if not faces:
            continue
        flat[idx] = 0
        _give_faces(labels, fits, k, faces)


def _give_faces(labels: np.ndarray, fits: dict, k: int, faces: list) -> None:
    # the faces ``[(pixels, plane)]`` (flat pixels) labelled in ``labels`` (C-ordered) and
    # ``fits``, in place: the first keeps ``k``, the others take new labels
    flat = labels.reshape(-1)
    for i, (face, plane) in enumerate(faces):
        label = k if i == 0 else fresh_label(labels, fits)
        flat[face] = label
        fits[label] = plane


def _one_thin_plane(ctx: Context, flat: np.ndarray, fits: dict, k: int, idx: np.ndarray) -> None:
    # the thin blob ``idx`` (numbered k in ``flat``) as one plane, or freed (in place); the
    # fitter decides the kind (the batch's plane by moments would take a strip the decision
    # calls curved: a border strip of a face turning into a crease)
    from ..scales import MIN_PIXELS

    floor = min(MIN_PIXELS, ctx.min_size)
    model = ctx.fitter.fit(ctx.fitter.points(ctx.xyz, idx))
    chosen = None
    if model and model.kind == "plane":
        chosen, model = _one_plane(ctx, idx, model, thin=True)
    flat[idx] = 0
    if chosen is not None and model and model.kind == "plane" and chosen.size >= floor:
        flat[chosen] = k
        fits[k] = model


def claim_occluded_strips(ctx: Context, labels: np.ndarray, fits: dict, *, valid: np.ndarray,
                          k_sigma: float):
    """Unlabelled strips that lie on a plane region's surface join that region; returns
    new ``(labels, fits)``.

    A wall seen between two columns standing in front of it can be a strip one or two
    pixels wide: its far side of the occlusions is marked as a jump, the 3x3 window there
    straddles the columns, and no growth reaches it across the jumps, while the blobs of
    :func:`leftover_candidates` erode it away. Such a strip is a piece of a surface the
    scan already has. The unlabelled valid pixels that a plane region's model explains
    within ``k_sigma x max(sigma, rms)`` (no jump or adjacency test: the occluder is in
    between) form connected pieces; each piece goes to the plane explaining most of it,
    and its pixels that plane explains join the region where they make a connected part
    of at least ``min_size`` (isolated pixels near some plane's extension stay free).
    A part that touches its plane's region is growth's to judge, unless the plane is seen
    there closer to grazing than the jump test allows (``scales.GRAZING_TAN``: a box top
    a few degrees from grazing is a range jump at every row) and the part lies on it
    within the noise of its distances (the range noise times the incidence cosine): then
    it joins, whatever its size. A part apart from its region joins only where the camera
    does not see past the plane between them (:func:`rangeseg_o3d.refinement.sight.seen_past_plane`:
    columns stand in front of the wall behind them; the floor and walls seen between a box
    face and a pipe 5 m behind it lie behind that face's plane, which therefore ends before
    the pipe).
    Planes only: a strip of a curved surface cannot be told from its extension this way.
    """
    planes = [k for k, m in fits.items() if m and m.kind == "plane"]
    if not planes:
        return labels, fits
    normals = np.array([fits[k].normal for k in planes])
    offsets = np.array([fits[k].d for k in planes])
    rms = np.array([fits[k].rms for k in planes])
    # a compiled screen: fewer than the size floor of free pixels within the bound of any
    # plane (widened far beyond rounding) claim nothing below, where the numpy steps cost
    # ~0.2 ms an LMS200 scan and all but a few of the suite's calls claim nothing
    if not free_near_planes_reach(np.ascontiguousarray(labels), np.ascontiguousarray(valid, dtype=np.bool_),
                                  ctx.xyz, ctx.sigma, np.ascontiguousarray(normals, dtype=np.float64),
                                  np.ascontiguousarray(offsets, dtype=np.float64),
                                  np.ascontiguousarray(rms, dtype=np.float64), float(k_sigma), int(ctx.min_size),
                                  SCREEN_SLACK):
        return labels, fits
    free = np.flatnonzero((valid & (labels == 0)).ravel())
    if free.size < ctx.min_size:
        return labels, fits
    # which planes explain which free pixel (pixels x planes)
    within = (np.abs(rows_at(ctx.xyz, free) @ normals.T - offsets)
              <= k_sigma * np.maximum(ctx.sigma[free, None], rms))
    near = np.flatnonzero(within.any(axis=1))
    if near.size < ctx.min_size:
        return labels, fits
    member, plane_of = _voted_members(ctx, free[near], within[near])
    # the members of different pieces never touch: one pass finds their connected parts
    pixels, owner = free[near[member]], np.asarray(planes)[plane_of[member]]
    parts, sizes = ctx.piece_ids(pixels)
    # a part touching a region whose plane explains it is growth's to judge (its jump test
    # guards that border)
    # (a plane's region may have lost every pixel, its number above the labels')
    column = np.full(max(int(labels.max()), max(planes)) + 1, -1)
    column[planes] = np.arange(len(planes))
    touching = _touches_explaining(labels, pixels, within[near[member]], column)
    touches = np.bincount(parts, weights=touching, minlength=sizes.size) > 0
    kept = (sizes >= ctx.min_size)[parts] & ~touches[parts]
    # a part touching its plane's region across the range jumps the plane's own slant makes
    # (a face seen closer to grazing than the jump test's angle, scales.GRAZING_TAN: growth
    # stops at every row) joins it when all its pixels are seen that close to grazing and
    # its rms distance to that plane is within the noise of their distances
    if touches.any():
        kept |= _grazing_on_plane(ctx, pixels, column[owner], (normals, offsets, rms), parts,
                                  touches)[parts]
    if not kept.any():
        return labels, fits
    # a part apart from its region that the camera sees past the plane to reach is another
    # surface the plane's extension crosses (sight.seen_past_plane)
    apart = np.flatnonzero(kept & ~touches[parts])  # (whole parts: kept is decided per part)
    for rows in _grouped(apart, parts[apart], unique_ints(parts[apart]).tolist()).values():
        k = int(owner[rows[0]])
        if seen_past_plane(ctx.xyz, ctx.sigma, labels, pixels[rows], k, fits[k], k_sigma,
                           wrap_columns=ctx.wrap_columns):
            kept[rows] = False
    if not kept.any():
        return labels, fits
    grown = labels.copy()
    grown.ravel()[pixels[kept]] = owner[kept]
    return grown, refit_grown(ctx, labels, grown, fits)


def claim_thin_strips(ctx: Context, labels: np.ndarray, fits: dict, candidates: np.ndarray, *,
                      valid: np.ndarray, k_sigma: float) -> np.ndarray:
    """The leftover strips no blob took join a plane region they touch where they lie on its
    surface within the noise of their distances; returns new labels (``labels`` is not changed).

    The free pixels outside the blobs of ``candidates`` (:func:`leftover_candidates`: the
    strips too thin for a 3x3 core), in 4-connected strips of at least the size floor, are
    offered to the planes as :func:`claim_on_distance_noise` offers them (each connected
    part within ``k_sigma`` noises of its distance to the plane most of its piece lies on,
    its rms within the chi-square bound of that noise), to a region they touch only. A
    face's border row or column beside a range step is marked a jump itself, and growth
    never crosses a jump edge: that band stays free beside the region of its own surface,
    too thin to be a blob (a box side five columns wide in front of a wall loses a fifth of
    its pixels there; on a 32-row lidar a face seen in a few rows loses more).
    """
    # one compiled pass (kernels.strip_pool: the free mask, its 4-connected strips and their
    # sizes on the listed pixels; OpenCV's components over the grid and numpy's masks cost
    # ~0.1 ms an LMS200 scan)
    pool = strip_pool(np.ascontiguousarray(labels), np.ascontiguousarray(valid, dtype=np.bool_),
                      np.ascontiguousarray(candidates), int(ctx.min_size))
    if not pool.size:
        return labels
    return claim_on_distance_noise(ctx, np.array(labels, dtype=np.int32, order="C"), fits, pool,
                                   k_sigma=k_sigma, apart=False)


def _voted_members(ctx: Context, pixels: np.ndarray, within: np.ndarray):
    # connected pieces of the flat ``pixels`` first, then their plane (the column of
    # ``within``, pixels x planes, explaining most of the piece): coplanar regions not
    # merged yet (pieces of one wall) would otherwise share a strip between them, each part
    # under the floor. Returns (whether each pixel is explained by its piece's plane, that
    # plane's column per pixel).
    ids, _ = ctx.piece_ids(pixels)
    return voted_columns(ids, within, int(ids.max()) + 1)  # compiled: no (pieces x planes) argmax or gather


def claim_on_distance_noise(ctx: Context, labels: np.ndarray, fits: dict, pool: np.ndarray, *,
                            k_sigma: float, apart: bool = True) -> np.ndarray:
    """The free pixels of the flat ``pool`` that lie on a plane region's surface join it;
    returns the labels (changed in place when C-contiguous).

    A band of a far wall left over above an object, too thin for its own plane to be told
    from the plane along its viewing rays, is a piece of a wall the scan already has. Each
    free pixel within ``k_sigma`` noises of a plane (the noise of its distance: range noise
    times the incidence cosine, or the plane's rms when larger) votes for it; each
    connected piece goes to the plane most of it lies on, and its pixels on that plane join
    the region where they make a connected part of at least the size floor whose rms
    distance to it is within the chi-square bound of that noise; a smaller part joins only
    a region it touches, and so does every part unless ``apart`` (pieces of one surface
    apart are one region: see :func:`recover_leftovers`). Planes only, as in
    :func:`claim_occluded_strips`.
    """
    planes = [k for k, m in fits.items() if m and m.kind == "plane"]
    if not planes:
        return labels
    # the planes' table once: the rounds change labels, not models (and each label's
    # column in it, -1 for labels that are no plane)
    column_of = np.full(max(planes) + 1, -1, np.int64)
    column_of[planes] = np.arange(len(planes))
    table = (np.array(planes, np.int64), np.array([fits[k].normal for k in planes]),
             np.array([fits[k].d for k in planes]), np.array([fits[k].rms for k in planes]), column_of)
    free = pool[labels.reshape(-1)[pool] == 0]
    if free.size < ctx.min_size:
        return labels
    # compiled: the numpy form's (pixels x planes) temporaries cost office1 ~16 ms a frame
    within = within_plane_noise(rows_at(ctx.xyz, free), ctx.sigma[free], *table[1:4], k_sigma)
    # only a pixel within the noise of some plane can be claimed; the others still count
    # towards the size floor of the free pool
    near = rows_with_any(within)  # within.any(axis=1)'s rows without numpy's reduction over short rows
    n_free, free, within = free.size, free[near], within[near]
    # a piece lying on two planes (a band across a room's corner) goes to the one most of
    # it lies on first; what is left of it is a piece of its own the next time round (the
    # models do not change: the pixels left keep their rows of ``within``)
    while n_free >= ctx.min_size and _claim_once(ctx, labels, table, free, within, apart):
        still = labels.reshape(-1)[free] == 0
        n_free -= int(still.size - np.count_nonzero(still))
        free, within = free[still], within[still]
    return labels


#: Rings a curved region grows into the leftover blobs beside it before they are split.
RIM_RINGS = 32


def claim_curved_rims(ctx: Context, labels: np.ndarray, fits: dict, pool: np.ndarray, *, ranges: np.ndarray,
                      k_sigma: float, boxes=None, rings: int = RIM_RINGS) -> np.ndarray:
    """The free pixels of the flat ``pool`` that a curved region beside them explains join
    it, ring by ring from the region (up to ``rings``; :func:`grow_into_edges`' test, no
    jump test: the model's distance decides); returns the labels, changed in place (they
    must be C-contiguous: ValueError otherwise).

    A ball's or pipe's limb seen under a depth camera's noise: the tile means there mix
    the surface with what lies behind it, so its tile region stops short of the limb, and
    the pixels left lie on its model within the noise (kinect seed 1042 scan 3: 489 px of a
    ball at 4.3 m, 0.26 noise sigmas off its sphere on the median, up to 28 px from its
    region). Left in a blob beside another surface, they make that surface too small a
    share of the blob for the split's search to find it, and both stay unlabelled.
    :func:`claim_on_distance_noise` gives blob pixels to planes; this, to curved regions.
    ``boxes`` (optional, (K, 4)): boxes holding the pool, where alone the growth is sought.
    """
    if not labels.flags.c_contiguous:
        raise ValueError(f"claim_curved_rims: labels must be C-contiguous (changed in place), got strides "
                         f"{labels.strides} for shape {labels.shape}")
    curved = {k: m for k, m in fits.items() if m and m.kind != "plane"}
    if not curved or not pool.size:
        return labels
    flat = labels.reshape(-1)
    # the free pixels outside the pool are held, for the growth, by a label no model grows
    held = flat == 0
    held[pool] = False
    blocker = fresh_label(labels, fits)
    flat[held] = blocker
    grown = grow_into_edges(ctx.xyz.reshape(labels.shape + (3,)), labels, curved, ctx.sigma.reshape(labels.shape),
                            ranges, iterations=rings, k_sigma=k_sigma, jump_ratio=np.inf, jump_min=np.inf, box=boxes)
    flat[held] = 0
    taken = pool[grown.reshape(-1)[pool] != flat[pool]]
    flat[taken] = grown.reshape(-1)[taken]
    return labels


def _claim_once(ctx: Context, labels: np.ndarray, table: tuple, free: np.ndarray, within: np.ndarray,
                apart: bool) -> bool:
    # one round of claim_on_distance_noise over the free pixels ``free`` within the noise of
    # a plane (``within``: pixels x planes, each row with a True; ``table``: the planes'
    # labels, normals, offsets and rms, and each label's column); whether it claimed any pixel
    plane_labels, normals, offsets, plane_rms, column_of = table
    if free.size < ctx.min_size:
        return False
    member, plane_of = _voted_members(ctx, free, within)
    rows = np.flatnonzero(member)
    pixels = free[rows]
    parts, sizes = ctx.piece_ids(pixels)
    # compiled: each part's rms distance and distance noise, whether it touches its plane's
    # region, the bound and the labels in one pass (numpy took some thirty passes a round)
    return claim_parts(labels.reshape(-1), labels.shape[1], ctx.xyz, ctx.sigma, pixels, plane_of[rows], parts,
                       sizes, normals, offsets, plane_rms, plane_labels, column_of, ctx.min_size, bool(apart),
                       CHI_SQUARE_SIGMAS)


def _distance_and_noise(points: np.ndarray, sigma: np.ndarray, normals: np.ndarray, offsets: np.ndarray,
                        plane_rms: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    # each point's signed distance to its own plane (row of ``normals``, ``offsets``), the
    # noise of that distance (range noise times the incidence cosine, or the plane's rms when
    # larger: kernels.within_plane_noise's, the same operations in order) and that cosine
    along = points[:, 0] * normals[:, 0] + points[:, 1] * normals[:, 1] + points[:, 2] * normals[:, 2]
    norms = np.sqrt(points[:, 0] * points[:, 0] + points[:, 1] * points[:, 1] + points[:, 2] * points[:, 2])
    cosines = np.abs(along) / np.maximum(norms, 1e-12)
    return along - offsets, np.maximum(sigma * cosines, plane_rms), cosines


def _grazing_on_plane(ctx: Context, pixels: np.ndarray, owner: np.ndarray, planes: tuple,
                      parts: np.ndarray, asked: np.ndarray) -> np.ndarray:
    # per part (``parts`` numbers the flat ``pixels``; False where not ``asked``): whether each of its pixels sees the
    # plane of its region (row ``owner`` of ``planes``: normals, offsets, rms) closer to grazing than atan(GRAZING_TAN),
    # and their rms distance to it is within the noise's chi-square bound (fitting.robust.beyond_noise) of
    # the rms of max(distance noise, the plane's rms) (distance noise: the range noise
    # times the incidence cosine, fitting.robust.distance_noise)
    normals, offsets, plane_rms = planes
    # the asked parts' pixels alone, in order: each part's sums add the same terms in the same order
    # (and each pixel's plane is gathered from the table, not looked up per pixel in Python)
    rows = np.flatnonzero(asked[parts])
    pixels, owner, parts = pixels[rows], owner[rows], parts[rows]
    distances, noise, cosines = _distance_and_noise(
        rows_at(ctx.xyz, pixels), ctx.sigma[pixels], normals[owner].reshape(-1, 3), offsets[owner], plane_rms[owner])
    n_parts = asked.size
    steep = np.bincount(parts, weights=cosines > GRAZING_TAN / np.hypot(1.0, GRAZING_TAN), minlength=n_parts)
    counts = np.bincount(parts, minlength=n_parts)
    mean_squares = np.bincount(parts, weights=distances * distances, minlength=n_parts) / np.maximum(counts, 1)
    noise_squares = np.bincount(parts, weights=noise * noise, minlength=n_parts) / np.maximum(counts, 1)
    answer = np.zeros(n_parts, bool)
    for i in np.flatnonzero(asked & (steep == 0) & (counts > 0)):
        answer[i] = not beyond_noise(float(np.sqrt(mean_squares[i])), float(np.sqrt(noise_squares[i])), int(counts[i]))
    return answer


def _neighbour_columns(labels: np.ndarray, pixels: np.ndarray, column: np.ndarray):
    # for each 4-neighbour direction: the positions in ``pixels`` (flat) whose neighbour is on
    # the grid, and ``column`` of that neighbour's label
    rows, cols = np.divmod(pixels, labels.shape[1])
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        r, c = rows + dr, cols + dc
        inside = np.flatnonzero((r >= 0) & (r < labels.shape[0]) & (c >= 0) & (c < labels.shape[1]))
        yield inside, column[labels[r[inside], c[inside]]]


def _touches_explaining(labels: np.ndarray, pixels: np.ndarray, within: np.ndarray,
                        column: np.ndarray) -> np.ndarray:
    # whether each flat pixel has a 4-neighbour in a region whose plane explains it
    # (``within[p, column[label]]``; ``column`` -1 for labels that are no plane)
    hit = np.zeros(pixels.size, bool)
    for inside, j in _neighbour_columns(labels, pixels, column):
        hit[inside] |= (j >= 0) & within[inside, np.maximum(j, 0)]
    return hit


def recover_leftovers(ctx: Context, labels: np.ndarray, fits: dict, *, xyz: np.ndarray,
                      valid: np.ndarray, jumps: np.ndarray, ranges: np.ndarray, sigma: np.ndarray,
                      k_sigma: float, jump_ratio: float, jump_min: float, claim_strips: bool = True,
                      thin_strips: bool = False, strips_apart: bool = False):
    """Turn the compact leftover blobs into one region per surface they hold (:func:`split_blobs`);
    returns new ``(labels, fits)``.

    ``valid`` and ``jumps`` are (H, W) masks (no blob crosses a jump edge); ``xyz``,
    ``ranges`` and ``sigma`` the grids the rims grow on (see
    :func:`rangeseg_o3d.refinement.grow.grow_into_edges`). ``claim_strips``: then the
    unlabelled strips on a plane region's surface that touch no region explaining them
    join it (:func:`claim_occluded_strips`). Such a strip is a piece of the region apart
    from it, so the caller asks for this only where pieces of one surface apart are one
    region (``merge_disjoint``): where they are not (SegComp's ABW truth labels each
    connected patch), a strip would join whichever region's plane passes through it,
    however far (a face of another block in line with it). ``thin_strips`` (asked at sensor
    resolution): first, the leftover strips too thin for a blob join a plane region they
    touch and lie on (:func:`claim_thin_strips`), and with ``strips_apart`` (a laser's single
    returns) those that range jumps set apart from the regions around them are blobs too
    (:func:`strips_apart_as_blobs`); and a blob piece
    neither trimmed search explains is searched once more for a face (``face_band`` of
    :meth:`Context.dominant_piece`: after growth, which gave the corner's pixels to the faces
    around the blob).
    """
    first = fresh_label(labels, fits)
    candidates = leftover_candidates(labels, valid, jumps, min_size=ctx.min_size, first_label=first)
    if thin_strips:
        labels = claim_thin_strips(ctx, labels, fits, candidates, valid=valid, k_sigma=k_sigma)
    if thin_strips and strips_apart:
        labels, candidates = strips_apart_as_blobs(ctx, labels, fits, candidates, first=first, valid=valid,
                                                   ranges=ranges, jump_ratio=jump_ratio, jump_min=jump_min,
                                                   k_sigma=k_sigma, apart=claim_strips)
    # A blob may hold several faces: a box far away whose faces are narrower than the
    # closed edge band around them (the closing fills gaps of up to four pixels) is one
    # blob of two or three faces, and explaining it by its dominant surface alone would
    # drop the others. Each blob is split into every surface it holds.
    if candidates.any():  # (no blob: nothing to split, no rim to take back)
        labels, fits = split_blobs(ctx, labels, fits, candidates, face_band=thin_strips)
    if labels.max(initial=0) >= first:  # recovered blobs take back their rims
        labels, fits = grow_regions(ctx, labels, fits, xyz=xyz, ranges=ranges, sigma=sigma, iterations=2,
                                    k_sigma=k_sigma, jump_ratio=jump_ratio, jump_min=jump_min)
    if not claim_strips:
        return labels, fits
    return claim_occluded_strips(ctx, labels, fits, valid=valid, k_sigma=k_sigma)


def strips_apart_as_blobs(ctx: Context, labels: np.ndarray, fits: dict, candidates: np.ndarray, *, first: int,
                          valid: np.ndarray, ranges: np.ndarray, jump_ratio: float, jump_min: float,
                          k_sigma: float, apart: bool) -> tuple[np.ndarray, np.ndarray]:
    """``(labels, candidates)`` with the leftover strips that range jumps set apart from the
    regions around them added to ``candidates`` as blobs (numbered on from ``first`` and the
    blobs there), once the planes took the pixels on their surfaces.

    A far column seen between nearer ones is a strip two to four returns wide: every window
    of the residual straddles it and its border returns are jump pixels, so it is no region,
    too thin for a blob's 3x3 core, and touches no region it lies on
    (:func:`claim_thin_strips`): it was left in no region (nodding_0.5deg study seeds 1266
    and 1268, columns of r 0.22-0.24 m at 3.6-5.3 m, 238 and 467 px). Here the free
    pixels (valid, unlabelled, in no blob) are joined where neighbours differ by no range
    jump (:func:`rangeseg_o3d.kernels.leftovers.pieces_apart`: the border returns with the
    strip), and a piece of at least the size floor becomes a blob when most of its links out
    of it are jumps, to a region or to free returns (a band along a crease or a rim touches
    its regions without one; a far column's sides often meet a wall's edge band in no
    region, while its foot meets the floor without a jump: nodding_1deg study seed 1436
    scan 1, a column of r 0.18 m at 5.1-5.6 m, 152 px in no region, its links to regions 5
    without a jump and 2 jumps) and it spans at least two returns across (a line of mixed
    returns along a limb spans one). Its pixels within the noise of a plane region's surface
    join that region first (:func:`claim_on_distance_noise`; ``apart``: also a region it
    does not touch, as ``config.merge_disjoint`` allows): a wall's strip seen between two
    columns is the wall's.
    """
    pixels, starts, contact, jumped = pieces_apart(
        np.ascontiguousarray(labels, dtype=np.int32), np.ascontiguousarray(valid, dtype=np.bool_),
        np.ascontiguousarray(candidates, dtype=np.int32), np.ascontiguousarray(ranges, dtype=np.float64),
        float(jump_ratio), float(jump_min), int(ctx.min_size), bool(ctx.wrap_columns))
    bounds = starts.tolist()
    strips = [pixels[bounds[s]:bounds[s + 1]] for s in range(contact.size) if jumped[s] > contact[s]]
    strips = [idx for idx in strips if returns_across(idx, ctx.width) >= 2]
    if not strips:
        return labels, candidates
    labels = np.array(labels, dtype=np.int32, order="C")
    claim_on_distance_noise(ctx, labels, fits, np.sort(np.concatenate(strips)), k_sigma=k_sigma, apart=apart)
    flat = labels.reshape(-1)
    out, label = None, max(int(candidates.max(initial=0)), first - 1) + 1
    for idx in strips:
        free = idx[flat[idx] == 0]
        # (what the planes took may leave a line: span counted again only then)
        if free.size < ctx.min_size or (free.size < idx.size and returns_across(free, ctx.width) < 2):
            continue
        idx = free
        if out is None:
            out = np.array(candidates, dtype=np.int32, order="C")
        out.reshape(-1)[idx] = label
        label += 1
    return labels, (candidates if out is None else out)


def _members_in_box(labels: np.ndarray, members: np.ndarray, box) -> np.ndarray:
    # kernels.member_pixels (flat indices, increasing) of the pixels within ``box``
    # (top, bottom, left, right; clipped to the grid), or within the boxes of a (K, 4)
    # array: every member pixel must lie in it (in one of them). One compiled pass over the
    # boxes (a pixel of overlapping boxes listed once), no copy of each box's labels
    from ..kernels import member_pixels_in_boxes

    return member_pixels_in_boxes(np.ascontiguousarray(labels), np.ascontiguousarray(members, dtype=np.bool_),
                                  _box_rows(box))


def _box_rows(box) -> np.ndarray:
    # a (row0, row1, col0, col1) box or a (K, 4) array of them as a C-contiguous (K, 4) int64 array
    return np.ascontiguousarray(np.asarray(box, dtype=np.int64).reshape(-1, 4))


def _grouped(pixels: np.ndarray, owner: np.ndarray, only) -> dict[int, np.ndarray]:
    # the flat ``pixels`` (increasing) of each label of ``only`` by their labels ``owner``, as
    # region_indices(labels, only=only) gives them when all those labels' pixels are among them
    # (a look-up by label, not np.isin's sort of both: the labels are small numbers)
    wanted = [k for k in only if k >= 0]
    lut = np.zeros(max(int(owner.max(initial=0)), max(wanted, default=0)) + 1, bool)
    lut[wanted] = True
    keep = lut[owner]
    pixels, owner = pixels[keep], owner[keep]
    order = np.argsort(owner, kind="stable")  # each label's pixels stay increasing
    keys, starts = np.unique(owner[order], return_index=True)
    bounds = starts.tolist() + [pixels.size]
    pixels = pixels[order]
    return {k: pixels[bounds[i]:bounds[i + 1]] for i, k in enumerate(keys.tolist())}


def _read_only_bool(mask: np.ndarray) -> np.ndarray:
    # a C-contiguous read-only bool view (or copy): one compiled signature whatever the cloud holds
    view = np.ascontiguousarray(mask, dtype=np.bool_).view()
    view.flags.writeable = False
    return view


#: At most this many boxes are looked in one by one (:func:`_blob_boxes`); past it, the box
#: holding them all (a test per box for every pixel a claim lists).
_MAX_BOXES = 32


def _blob_boxes(boxes: np.ndarray, by: int, shape: tuple[int, int]):
    """Where the surfaces found in the blobs of ``boxes`` (one ``(row0, row1, col0, col1)``
    row each) reach within ``by`` pixels: each blob's box grown by ``by``, as a ``(K, 4)``
    int64 array, when those boxes cover fewer pixels than the one box holding them all
    grown by ``by`` (which is returned instead, as a tuple). The same pixels are reached
    either way; blobs scattered over a frame leave most of the box holding them all
    untouched (office1: six blobs of 15500 pixels in a box of 217000)."""
    whole = grown_box((boxes[:, 0].min(), boxes[:, 1].max(), boxes[:, 2].min(), boxes[:, 3].max()), by, shape)
    if len(boxes) < 2 or len(boxes) > _MAX_BOXES:
        return whole
    each = np.array([grown_box(box, by, shape) for box in boxes.tolist()], np.int64)
    area = int(np.sum((each[:, 1] - each[:, 0]) * (each[:, 3] - each[:, 2])))
    return each if area < (whole[1] - whole[0]) * (whole[3] - whole[2]) else whole


def grown_box(box, by: int, shape: tuple[int, int] | None = None) -> tuple[int, int, int, int]:
    """A ``(row0, row1, col0, col1)`` box grown by ``by`` pixels on every side, clipped to a
    grid of ``shape`` when given (else not clipped)."""
    grown = int(box[0]) - by, int(box[1]) + by, int(box[2]) - by, int(box[3]) + by
    if shape is None:
        return grown
    return max(grown[0], 0), min(grown[1], shape[0]), max(grown[2], 0), min(grown[3], shape[1])


def recover_pixels(cloud, labels, fits, *, fitter, config, sensor, ranges: np.ndarray,
                   sigma: np.ndarray, candidates: np.ndarray, min_size: int, boxes: np.ndarray | None = None,
                   thin_from: int | None = None, released: np.ndarray | None = None,
                   changes: dict | None = None, free: np.ndarray | None = None):
    """After a run on tile means: recover, at full resolution, the surfaces the tiles lost.

    A table top seen at a grazing angle may be a band 5-15 pixels thick: under three 6x6
    tiles, so the tile grid's 3x3 window always straddles it, and the tile models leave
    its pixels unlabelled. Small faces between creases vanish the same way, and so do
    faces of a region that leaked through creases the tile grid could not see when the
    split left them over. Those leftovers, cut into compact blobs (``candidates``,
    numbered above every label: :func:`rangeseg_o3d.fullres.leftover_blob_labels`), are each
    split into every surface they hold (:func:`split_blobs`; a piece neither trimmed search
    explains gets the one-sigma face band, for faces only: :attr:`Context.band_faces_only`;
    a cylinder or sphere found beyond the noise of its distances gives way to the face a
    search at that noise finds, down to the recovered-region floor:
    :meth:`Context.dominant_search`).
    At grazing angles every pixel step is a depth jump by the range test, so neither the blobs nor the 2-pixel
    rim their regions take back are limited by it: the model distance decides. Before the
    blobs are fitted, their pixels on a plane region's surface join it
    (:func:`claim_on_distance_noise`; apart from it only with ``config.merge_disjoint``);
    after, a recovered plane beyond the noise of its pixels' distances
    (:func:`_planes_along_rays`; unless the fitter's bend test calls its pixels a cylinder or
    sphere within that noise: :func:`rangeseg_o3d.refinement.curved_refused.curved_for_refused`;
    or, where the returns err along their rays beyond the blob's width
    (:func:`fits_refused_along_rays`), its plane fitted along its pixels' rays explains them:
    :func:`planes_fitted_along_rays`; or, where the sensor states a lateral noise, it is one
    of several pieces of one face the jump edges cut: :func:`_join_grazing_pieces`) merges
    into no plane and, unless it rejoins a curved region,
    keeps only its piece within that noise (:func:`_within_distance_noise_or_back`); with
    ``config.merge_disjoint`` the free pixels are offered to the planes once more.
    ``boxes`` (optional): blob ``first + j``'s bounding box in row ``j`` (its pixels are then
    gathered from it, not from the whole grid). Blobs numbered from ``thin_from`` on are
    thin strips, each one plane or none (:func:`split_blobs`). A plane found in the blobs
    keeps the pixels it took after its fit (its rim, its claims) only within the noise of
    their distances to it (:func:`_gains_within_distance_noise`). ``released`` (optional, (H, W)): the plane
    each pixel was freed from because as a group it lay off that plane
    (:func:`rangeseg_o3d.off_model.off_model_blocks`), 0 elsewhere; a surface found
    on such pixels merges back into that plane only when it lies on the union's plane on
    the mean (:func:`_released_from`, :func:`rangeseg_o3d.refinement.merge.merge_regions`).
    ``changes`` (optional, a dict): receives ``where``, a box or boxes (as
    :func:`differing_pixels` takes them) holding every pixel whose label this call changed but
    those the last claim of free pixels took (None: they may lie anywhere), ``claimed``,
    the labels those took, and ``claimed_at``, their flat indices (increasing). ``free``
    (optional): the flat indices (increasing) of the valid unlabelled pixels of ``labels``
    (:func:`rangeseg_o3d.fullres.leftover_blob_labels` lists them); with ``boxes`` the last
    claim's free pixels are then found from them and the boxes where this call changed
    labels, not by a pass over the grid.
    """
    from ..fullres import recovered_region_floor

    first = fresh_label(labels, fits)
    ctx = Context(cloud, fitter, sigma, min_size, wrap_columns=sensor.wrap_columns, grazing_search=True,
                  correlation_px=sensor.noise.correlation_px, band_faces_only=True,
                  face_floor=recovered_region_floor(config, min_size, sensor.noise.correlation_px))
    regions = None
    if boxes is not None:
        from ..kernels import box_members

        order, starts = box_members(np.ascontiguousarray(candidates, dtype=np.int32),
                                    np.ascontiguousarray(boxes, dtype=np.int64), first)
        bounds = starts.tolist()
        regions = {first + j: order[bounds[j]:bounds[j + 1]] for j in range(len(boxes))
                   if bounds[j + 1] > bounds[j]}
    # a blob's pixels on the plane of a region the scan has (a piece of it left over where
    # its tile model drifts from the noisy pixels) are that region's before any is fitted
    labels = np.array(labels, dtype=np.int32, order="C")
    pool = (np.flatnonzero(candidates.reshape(-1)) if regions is None
            else np.sort(np.concatenate(list(regions.values()))))
    claim_on_distance_noise(ctx, labels, fits, pool, k_sigma=config.k_sigma, apart=config.merge_disjoint)
    claimed = labels.reshape(-1)[pool] > 0
    if claimed.any():
        candidates = candidates.copy()
        candidates.reshape(-1)[pool[claimed]] = 0
        if regions is not None:
            regions = {k: kept for k, idx in regions.items() if (kept := idx[labels.reshape(-1)[idx] == 0]).size}
    # the labels before and after the split, kept without a copy: split_blobs changes a copy of
    # its input, and what it returns is not changed after (the growth below starts a new array)
    before = labels
    labels, fits = split_blobs(ctx, labels, fits, candidates, regions=regions, thin_from=thin_from, face_band=True,
                               correlation_px=sensor.noise.correlation_px, min_angle_deg=config.merge_angle_deg)
    labels, fits = _curved_rims_then_split(ctx, labels, fits, candidates, regions, ranges=ranges, config=config,
                                           thin_from=thin_from, correlation_px=sensor.noise.correlation_px,
                                           below=first)
    found = labels
    new = {k: m for k, m in fits.items() if k >= first and m}
    tile_regions = [k for k in fits if k < first]  # (the regions the blobs' surfaces may merge into)
    # The surfaces found are pieces of the blobs: with the blobs' boxes known, each step
    # below looks only in their boxes grown by the rings it may add (same answers).
    blobs = None if boxes is None or not len(boxes) else np.asarray(boxes, dtype=np.int64)
    refused = _planes_along_rays(ctx, labels, fits, new, pool)
    # The bend test speaks first: where the noise spans a blob's width, a pipe's pixels fitted
    # along their rays fit a plane within that noise as well (kinect seed 1079 scan 1: a
    # cylinder of r 0.18 m at 4.1 m, 2535 px, taken as a plane). (A curved model taking a
    # refused plane's place is recovered as any: its rim, claims, merges.)
    samples = full_resolution_samples(sensor)
    if refused and samples:
        labels, refused = curved_for_refused(ctx, labels, fits, new, refused, samples, config,
                                             pixels=_grouped(pool, labels.reshape(-1)[pool], refused),
                                             step=_means_step(sensor, cloud))
    if refused and fits_refused_along_rays(sensor, cloud):
        refused = planes_fitted_along_rays(ctx, labels, fits, new, refused, pool,
                                           max_cosine=along_rays_max_cosine(sensor, cloud))
    if refused and sensor.lateral_noise_px > 0:
        refused = _join_grazing_pieces(ctx, labels, fits, new, refused, pool, _lateral_step(sensor, cloud))
    # each plane's rms on the pixels it was found on: what it takes from here on (rim,
    # claims, merges) raises its fit's rms, and must not raise the bar it is held to
    found_rms = {k: m.rms for k, m in new.items() if m and m.kind == "plane"}
    rim, iterations = 2, 3  # rings taken back, then rings the challengers may claim
    # where every label this call changes lies (but the last claim of free pixels): the blobs'
    # boxes grown by those rings, unless a merge below takes a region the tiles had (its
    # pixels anywhere); None: anywhere
    where = None if blobs is None else _blob_boxes(blobs, rim + iterations, labels.shape)
    if new:
        from ..kernels import claim_rings_in_boxes, member_pixels

        labels = grow_into_edges(cloud.xyz, labels, new, sigma, ranges, iterations=rim,
                                 k_sigma=config.k_sigma, jump_ratio=np.inf, jump_min=np.inf,
                                 box=None if blobs is None else _blob_boxes(blobs, rim, labels.shape))
        # the tile models took what they could explain before these regions existed
        n = fresh_label(labels, fits)
        kinds, params, rms = model_table(fits, n)
        challengers = np.zeros(n, bool)
        challengers[list(new)] = True
        if where is not None:
            box = where
        else:
            rows, cols = np.divmod(member_pixels(labels, challengers), labels.shape[1])
            box = (rows.min() - iterations, rows.max() + iterations + 1,
                   cols.min() - iterations, cols.max() + iterations + 1)
        claim_rings_in_boxes(np.ascontiguousarray(cloud.xyz.reshape(-1, 3)), labels, kinds, params, rms,
                             np.ascontiguousarray(sigma).ravel(), challengers, iterations, float(config.k_sigma),
                             np.array(box, np.int64).reshape(-1, 4))
        if config.merge:  # a recovered piece of a surface the tile grid already has
            claimed = _members_in_box(labels, challengers, box)
            owner = labels.ravel()[claimed]
            regions = {k: claimed[owner == k] for k in unique_ints(owner).tolist()}
            near = {(min(k, j), max(k, j)) for k, idx in regions.items()
                    for j in touching(labels, idx, reach=2) if j != k}
            # a plane beyond its distance noise would tilt the plane it merged into: it may
            # only rejoin a curved region (below), as a strip of a pipe does
            apart = {k: fits.pop(k) for k in refused}
            labels, fits, near = merge_regions(ctx, labels, fits, {p for p in near if not apart.keys() & set(p)},
                                               max_angle_deg=config.merge_angle_deg,
                                               tolerance=config.merge_tolerance, disjoint=config.merge_disjoint,
                                               rms_factor=config.merge_rms_factor, only=set(new) - refused,
                                               held=_released_from(regions, released))
            fits.update(apart)
            # their neighbours as the merges left them; their pixels are those claim_rings
            # left them (the merges took none of them, and merge_into_curved below only
            # moves a plane it merges, whose model then is gone)
            kept_apart = {k: regions[k] for k in refused if k in regions}
            near = set(near) | {(min(k, j), max(k, j)) for k, idx in kept_apart.items()
                                for j in touching(labels, idx, reach=2) if j != k}
            if config.merge_disjoint:
                # a piece of a pipe or ball seen apart from the rest of it (a box in front of the
                # column between them) is a strip the tile grid left, which a plane fits within
                # the noise at full resolution, as the turning side of a column is: offered to the
                # curved regions apart too (merge_into_curved refits only a piece the curved
                # model as it stands explains within its noise sigmas at the median)
                near |= curved_pairs_apart(fits, (), among=new)
            # The side of a column or pipe turning away from the camera: the tile means
            # there straddle the turn, so the tile grid left it, and at full resolution
            # its strip fits a plane within the noise. It rejoins the curved region when
            # that model, refitted to both, keeps its kind and fits at the noise (pairs of
            # tile regions were tried on the tile grid).
            labels, fits, _ = merge_into_curved(ctx, labels, fits, near, rms_factor=config.merge_rms_factor,
                                                only=set(new), near_sigmas=config.k_sigma)
        labels, fits = _within_distance_noise_or_back(ctx, before, labels, fits, refused,
                                                      pixels=kept_apart if config.merge else None, below=first,
                                                      min_angle_deg=config.merge_angle_deg)
        if not all(k in fits for k in tile_regions):  # a merge took a region the tiles had
            where = None
        labels = _gains_within_distance_noise(ctx, before, found, labels, fits, refused, below=first,
                                              where=where, found_rms=_merged_rms_as_found(found_rms, fits, found,
                                                                                          labels, pool))
    if changes is not None:  # every step above changes the blobs or pixels the rings reach from them
        changes["where"] = where
        changes["claimed"] = set()
        changes["claimed_at"] = np.zeros(0, np.int64)
    if config.merge_disjoint:  # what is left of the blobs may be a piece of a plane the scan has
        labels, valid = np.ascontiguousarray(labels), _read_only_bool(cloud.valid)
        if free is not None and where is not None:  # outside ``where`` no label changed
            if free.ndim != 1 or (free.size and (free[0] < 0 or free[-1] >= labels.size)):
                raise ValueError(f"recover_pixels: free must be flat indices (increasing) of the {labels.shape} "
                                 f"labels, got shape {free.shape}")
            free = free_pixels_in_boxes(labels, valid, np.ascontiguousarray(free, dtype=np.int64), _box_rows(where))
        else:
            free = free_pixels(labels, valid)
        labels = claim_on_distance_noise(ctx, labels, fits, free, k_sigma=config.k_sigma)
        if changes is not None:
            taken = free[labels.reshape(-1)[free] > 0]
            changes["claimed"] = set(unique_ints(labels.reshape(-1)[taken]).tolist())
            changes["claimed_at"] = taken
    return labels, fits


def _curved_rims_then_split(ctx: Context, labels: np.ndarray, fits: dict, candidates: np.ndarray, regions,
                            *, ranges: np.ndarray, config, thin_from: int | None, correlation_px: int,
                            below: int):
    """After :func:`split_blobs`: the blobs it found nothing in (every pixel left free) give
    the curved regions beside them that the scan had (labels under ``below``) the pixels
    those explain (:func:`claim_curved_rims`), and what is left of each is split again.
    Returns ``(labels, fits)``: the claims change ``labels`` in place, a second split returns
    new ones. Only there: a pipe's model also explains, within the noise, the small face
    beside it that a split finds on its own (kinect seed 0 scan 0: 402 of a 442-px face)."""
    if regions is None:
        regions = region_indices(candidates)
    flat = labels.reshape(-1)
    left = {k: idx for k, idx in regions.items()
            if (thin_from is None or k < thin_from) and k not in fits and not flat[idx].any()}
    if not left:
        return labels, fits
    pool = np.sort(np.concatenate(list(left.values())))
    rows, cols = np.divmod(pool, labels.shape[1])
    box = np.array([[rows.min(), rows.max() + 1, cols.min(), cols.max() + 1]], np.int64)
    # (not those the split found in other blobs: on the real 3dtk_scan002 under sick_3dtk a
    # cylinder of r 2.0 m found there took 80 px of a blob, whose rest then gave one of r 3.9 m
    # that grew to 275 px; the limbs this is for are those of the tile grid's regions)
    claim_curved_rims(ctx, labels, {k: m for k, m in fits.items() if k < below}, pool, ranges=ranges,
                      k_sigma=config.k_sigma, boxes=box)
    rest = {k: kept for k, idx in left.items()
            if (kept := idx[flat[idx] == 0]).size < idx.size and kept.size >= ctx.min_size}
    if not rest:
        return labels, fits
    again = np.zeros(labels.shape, np.int32)
    for k, idx in rest.items():
        again.reshape(-1)[idx] = k
    return split_blobs(ctx, labels, fits, again, regions=rest, correlation_px=correlation_px,
                       min_angle_deg=config.merge_angle_deg)


def _released_from(regions: dict, released: np.ndarray | None) -> set:
    """Pairs ``(min, max)`` of each region of ``regions`` (flat pixels per label) and every
    plane some of its pixels were freed from (``released``, see :func:`recover_pixels`): as
    a group they lay off that plane."""
    if released is None:
        return set()
    flat, pairs = released.reshape(-1), set()
    for k, idx in regions.items():
        for source in unique_ints(flat[idx]).tolist():
            if source > 0 and source != k:
                pairs.add((min(k, source), max(k, source)))
    return pairs


def _planes_along_rays(ctx: Context, labels: np.ndarray, fits: dict, new: dict, pool: np.ndarray) -> set:
    """The planes found in the blobs (``new``, their pixels among the flat ``pool``,
    increasing) that do not explain their pixels within the noise of their distances
    (:meth:`Context.plane_along_rays`).

    A band a few pixels thick, of any surface or of two faces across a crease, lies within
    the range noise of the plane through its viewing rays; the fitter, which holds a plane
    to the range noise, takes it. Such a plane's distances carry almost none of the range
    noise (its incidence cosine is near zero), so its rms is far beyond them.
    """
    planes = [k for k, m in new.items() if m.kind == "plane"]
    if not planes:
        return set()
    pixels = _grouped(pool, labels.reshape(-1)[pool], planes)  # the blobs' pixels read, not the grid
    return {k for k in planes if k in pixels and ctx.plane_along_rays(fits[k], pixels[k])}


def _median_cosine(ctx: Context, plane, idx: np.ndarray) -> float:
    # the median |cosine| between the flat pixels' viewing rays and the plane's normal
    return float(np.median(np.abs(ctx.viewing_rays(idx) @ np.asarray(plane.normal, dtype=float))))


def along_rays_max_cosine(sensor, cloud=None) -> float | None:
    """The largest median incidence cosine of a face :func:`planes_fitted_along_rays` may find
    for :func:`recover_pixels` on ``sensor`` (and ``cloud``, whose grid step
    :func:`rangeseg_o3d.scales.grid_step` measures where the sensor states none): none on a
    stereo camera (``noise.matched_window``) nor where single returns err beyond the grid's
    footprint (:func:`rangeseg_o3d.scales.pixelwise_noise_spans_the_grid`, a Kinect's): there
    a narrow face's noise spans its width at any incidence; else
    :data:`rangeseg_o3d.scales.GRAZING_COSINE` (about 80.5 degrees from head-on).

    Where the depths come in steps, the fit along the rays is for a face seen near grazing, the
    band the jump edges cut (past that incidence every pixel step is a jump) whose
    least-squares plane a few pixels of its neighbour turn to the rays; a piece seen nearer
    head-on that its plane does not explain within the noise of its distances is no face of
    its own (tabletop_abw seed 1001 scan 1: pieces of 35 and 26 px at 45 and 70 degrees, taken
    along their rays, cut a 1700-px face in two)."""
    return None if _noise_spans_narrow_faces(sensor, cloud) else GRAZING_COSINE


def fits_refused_along_rays(sensor, cloud=None) -> bool:
    """Whether :func:`recover_pixels` fits the planes it refuses along their pixels' rays
    (:func:`planes_fitted_along_rays`) before it gives them up: where the sensor's range
    noise errs together over a matching window (a stereo camera's, ``noise.matched_window``),
    where single returns err beyond the grid's footprint
    (:func:`rangeseg_o3d.scales.pixelwise_noise_spans_the_grid`, a Kinect's; ``cloud`` gives
    the grid step where the sensor states none), and where its depths come in steps
    (``depth_step`` > 0, ABW's 8-bit structured light).

    Under noise wider than the footprint a face a few pixels wide spreads farther along its
    rays than across them, and its least-squares plane turns towards the rays: a box face
    9 px wide seen 18 degrees from head-on at 3.5 m (kinect seed 1070 scan 1, 1103 px under
    18 mm of noise) has its least-squares plane 54 degrees off its own, beyond the noise of
    its distances, and was freed whole.

    A quantised depth moves each return along its own ray (ABW's conversion computes x and y
    from the depth byte: x = (c - 255) z / |F|), so a blob's plane is the one its rays meet
    within the range noise, which the robust fit along the rays finds while it leaves out
    the few pixels of a neighbouring face the blob holds; the least-squares plane those
    pixels pull towards the rays (a face seen at 88 degrees: 0.23 mm rms from 2 of 83 pixels,
    against 0.005 mm of distance noise) is refused with the bands the test is for.
    """
    return bool(sensor.depth_step > 0 or _noise_spans_narrow_faces(sensor, cloud))


def _noise_spans_narrow_faces(sensor, cloud=None) -> bool:
    # a stereo camera's (noise.matched_window) or single returns erring beyond the grid's
    # footprint (a Kinect's): a face a few pixels wide spreads farther along its rays than across
    return bool(sensor.noise.matched_window or pixelwise_noise_spans_the_grid(sensor, cloud))


def planes_fitted_along_rays(ctx: Context, labels: np.ndarray, fits: dict, new: dict, refused: set,
                             pool: np.ndarray, max_cosine: float | None = None) -> set:
    """The planes of ``refused`` (found in the blobs, their pixels among the flat ``pool``,
    increasing) that stay refused once each is fitted along its pixels' rays; the others
    take that plane in ``fits`` and ``new`` (both changed in place).

    The fitter's plane is the least squares of the orthogonal distances. Where a return errs
    along its ray only (a stereo camera's or a Kinect's disparity noise: ``sigma / range**2``
    in inverse range, the same for every pixel) and that error spans the blob's width (a face
    20 pixels wide at 4-5 m under stereo: 0.1 m across, a range sigma of 0.04-0.08 m), those
    distances spread along the rays, and the least-squares plane turns towards them: a face
    seen head-on gets a plane seen at grazing, beyond the noise of its distances, and is
    refused with the bands that plane test is for. The likeliest plane under that noise is
    the weighted least squares of the inverse ranges (:func:`rangeseg_o3d.ray_planes.ray_fits`); the same test
    (:meth:`Context.plane_along_rays`: the noise of the distances, range noise times incidence
    cosine, chi-square bound) asked of that plane tells a face from a band, whose pixels no
    one plane meets within the range noise. The fit is
    :func:`rangeseg_o3d.ray_planes.robust_ray_plane` (a blob may hold a few pixels of the
    surfaces beside it), and the face is the pixels it keeps within TRIM_SIGMAS of their
    range noise, at least ``ctx.min_size``; the others go free (``labels``, C-ordered, is
    changed in place). ``max_cosine`` (optional): a face whose median incidence cosine exceeds
    it stays refused (:func:`along_rays_max_cosine`)."""
    from ..ray_planes import ray_plane, ray_terms, robust_ray_plane

    if max_cosine is not None and not 0.0 <= max_cosine <= 1.0:
        raise ValueError(f"planes_fitted_along_rays: max_cosine must be None or a cosine in [0, 1], got {max_cosine!r}")
    if not (isinstance(labels, np.ndarray) and labels.ndim == 2 and labels.flags.c_contiguous):
        raise ValueError("planes_fitted_along_rays: labels must be a C-ordered (H, W) array (the pixels a face "
                         f"leaves go free in place), got {type(labels).__name__} of shape {np.shape(labels)}")
    flat = labels.reshape(-1)
    pixels = _grouped(pool, flat[pool], sorted(refused))
    kept = set()
    for k in sorted(refused):
        idx = pixels.get(k)
        found = None if idx is None else robust_ray_plane(*ray_terms(rows_at(ctx.xyz, idx), ctx.sigma[idx]),
                                                          *np.divmod(idx, labels.shape[1]))
        if found is None:
            kept.add(k)
            continue
        a, keep, _ = found
        face = idx[keep]
        plane = ray_plane(a, rows_at(ctx.xyz, face))
        if (plane is None or face.size < ctx.min_size or ctx.plane_along_rays(plane, face)
                or (max_cosine is not None and _median_cosine(ctx, plane, face) > max_cosine)):
            kept.add(k)
            continue
        flat[idx[~keep]] = 0  # (a few pixels of the surfaces beside it, off its plane along their rays)
        fits[k] = new[k] = plane
    return kept


def _means_step(sensor, cloud) -> float:
    # the grid's angular step (radians) where a refused plane's block means are fitted for a
    # curved model (curved_for_refused): where the range noise exceeds the grid's footprint
    # and its returns err one by one (a Kinect; scales.pixelwise_noise_spans_the_grid); 0 elsewhere
    from ..scales import grid_step, pixelwise_noise_spans_the_grid

    return float(grid_step(sensor, cloud)) if pixelwise_noise_spans_the_grid(sensor, cloud) else 0.0


def _lateral_step(sensor, cloud) -> float:
    # the sensor's lateral noise in radians: its grid steps (the coarser axis: a return's spot
    # spans at least its pixel's larger side) times ``lateral_noise_px``
    if sensor.row_spacing_deg is not None and sensor.column_spacing_deg is not None:
        step = np.radians(max(sensor.row_spacing_deg, sensor.column_spacing_deg))
    else:
        from ..scales import measured_spacing

        step = max(measured_spacing(cloud))
    return float(sensor.lateral_noise_px * step)


def _join_grazing_pieces(ctx: Context, labels: np.ndarray, fits: dict, new: dict, refused: set,
                         pool: np.ndarray, lateral: float) -> set:
    """``refused`` less the planes of :func:`_planes_along_rays` that, with refused planes
    they touch (within 2 pixels), make one plane within the noise of its distances with the
    sensor's ``lateral`` noise (radians, :func:`rangeseg_o3d.fitting.robust.lateral_distance_noise`;
    chi-square bound), of at least two pieces and the size floor: each such group becomes one
    region (``labels``, ``fits`` and ``new`` changed in place, under its smallest label).

    A face seen at 80-89 degrees from head-on is a band a few pixels thick whose every pixel
    step is a depth jump by the range test, so the jump edges cut it into thin pieces, each a
    blob of its own. Each piece lies near the plane through its viewing rays, and where the
    sensor measures the surface somewhat beside its rays (``lateral``) the distances to the
    true face carry that offset, not the range noise times the incidence cosine, so each is
    refused alone. Joined, the pieces of one face share its plane within that noise. One
    thin piece alone stays refused: mixed pixels strung along the rays at an occluding
    contour, or a band across a crease, fit a plane through the rays as well.
    """
    flat = labels.reshape(-1)
    pixels = _grouped(pool, flat[pool], refused)
    pieces = sorted(k for k in refused if k in pixels)
    root = {k: k for k in pieces}

    def find(k):
        while root[k] != k:
            k = root[k]
        return k

    def members(group):
        return np.sort(np.concatenate([pixels[j] for j in pieces if find(j) == group]))

    def face(idx):  # the plane of the flat pixels idx if it explains them within the noise
        plane = fit_plane(rows_at(ctx.xyz, idx))
        if not plane:
            return None
        points = rows_at(ctx.xyz, idx)
        noise = lateral_distance_noise(plane, points, ctx.sigma[idx], lateral)
        rms = float(np.sqrt(np.mean(plane.distances(points) ** 2)))
        return None if beyond_noise(rms, float(np.sqrt(np.mean(noise * noise))), int(idx.size)) else plane

    for k in pieces:  # a few dozen refused pieces per frame at most: plain union-find
        for j in sorted(touching(labels, pixels[k], reach=2)):
            a, b = find(k), find(j) if j in root else None
            if b is None or a == b:
                continue
            both = np.sort(np.concatenate([members(a), members(b)]))
            if face(both) is not None:
                root[max(a, b)] = min(a, b)
    groups: dict[int, list] = {}
    for k in pieces:
        groups.setdefault(find(k), []).append(k)
    kept = set(refused)
    for first, group in groups.items():
        idx = members(first)
        if len(group) < 2 or idx.size < ctx.min_size or (plane := face(idx)) is None:
            continue
        flat[idx] = first
        for k in group:
            kept.discard(k)
            if k != first:
                fits.pop(k, None)
                new.pop(k, None)
        fits[first] = new[first] = plane
    return kept


def _within_distance_noise_or_back(ctx: Context, before: np.ndarray, labels: np.ndarray, fits: dict,
                                   refused: set, *, pixels: dict | None = None, below: int | None = None,
                                   min_angle_deg: float | None = None):
    """``(labels, fits)`` with each plane of ``refused`` that no curved region took cut to
    the largest piece of its pixels within their distance noise of it, refitted, when that
    piece keeps the size floor and is explained (a true face the band held beside a few
    pixels of its neighbours, :meth:`Context.within_distance_noise`); its other pixels go
    back to the regions they had ``before`` (free where that region is gone). ``pixels``
    (optional): the flat pixels (increasing) of each plane of ``refused`` still in ``fits``,
    when the caller has them (saves a pass over the grid). ``below`` (optional): a number
    above every label of ``before`` (saves a pass for its largest).

    With ``min_angle_deg``, on a sensor whose noise errs together over a window
    (``ctx.correlation_px`` > 1), a plane with no such piece is first offered to
    :func:`rangeseg_o3d.plane_faces.faces_of_plane` (faces at least ``min_angle_deg`` apart):
    each face it finds keeps its piece within its own distance noise, the first the plane's
    label, the others new ones. At 3.3 m a stereo camera's range noise (36 mm) holds a box's
    front seen 18 degrees from head-on and its side seen at 81 degrees within one plane through
    their corner (stereo study seed 1344 scan 2: 5129 px, 33 mm rms, 12 mm of distance noise), which no
    piece of either face lies within; freed, both faces were missed, while the crease line
    cuts them apart (2538 of 2629 and 2369 of 2500 px each face's).
    """
    left = [k for k in refused if fits.get(k)]
    if not left:
        return labels, fits
    labels = np.ascontiguousarray(labels)
    if pixels is None:
        pixels = region_indices(labels, only=left)
    flat, old = labels.reshape(-1), before.reshape(-1)
    alive = _alive(fits, old, below)
    for k in left:
        idx = pixels.get(k)
        if idx is None:
            continue
        piece, model = ctx.within_distance_noise(idx, fits[k])
        faces = [] if piece is not None or min_angle_deg is None or ctx.correlation_px <= 1 else \
            _faces_within_distance_noise(ctx, idx, fits[k], min_angle_deg)
        previous = old[idx]
        flat[idx] = np.where(alive[previous], previous, 0)
        if piece is not None:
            flat[piece] = k
            fits[k] = model
        elif faces:
            _give_faces(labels, fits, k, faces)
        else:
            del fits[k]
    return labels, fits


def _faces_within_distance_noise(ctx: Context, idx: np.ndarray, model, min_angle_deg: float) -> list:
    """``[(pixels, plane)]``: the faces :func:`rangeseg_o3d.plane_faces.faces_of_plane` finds in
    the plane region ``idx`` (flat pixels, increasing) of ``model``, each cut to its piece within
    the distance noise of its plane along the rays (:meth:`Context.within_distance_noise`, not
    refitted: the fitter's plane by distances turned a head-on face's beyond that noise), largest
    first; when fewer than two such faces keep the size floor, those of
    :func:`faces_of_unexplained`.

    One crease line leaves two of a far box's three faces on one side, which no plane fits
    within the noise: stereo study seed 1354 scan 3, a box's top (at 79 degrees), side and front
    at 3.7-4.5 m in one recovered plane of 3204 px, was freed whole; its crease line cuts off
    the side (749 of its 983 px), and the second cut parts the top (1019 of 1247) from the front
    (1401 of 2093). The top is found now; the side and the front stay short of four fifths: a
    plane region over both that the tile grid recovered keeps 842 of their pixels."""
    from ..plane_faces import faces_of_plane  # (plane_faces imports the refinement's context)

    kept = _pieces_within_distance_noise(ctx, faces_of_plane(ctx, model, idx, correlation_px=ctx.correlation_px,
                                                             min_angle_deg=min_angle_deg))
    if len(kept) < 2:
        return faces_of_unexplained(ctx, idx, min_angle_deg)
    return sorted(kept, key=lambda item: -item[0].size)


def faces_of_unexplained(ctx: Context, idx: np.ndarray, min_angle_deg: float) -> list:
    """``[(pixels, plane)]``: the faces the flat pixels ``idx`` (increasing), which no plane
    explains within their noise, hold as a region no model fits
    (:func:`rangeseg_o3d.plane_faces.faces_of_unfitted`, each of its pieces that holds two faces
    split again: :func:`rangeseg_o3d.plane_faces.faces_of_faces`; faces at least
    ``min_angle_deg`` apart), each cut to its piece within the distance noise of its plane along
    the rays, largest first; empty when fewer than two such faces keep the size floor. For a
    sensor whose noise errs together over ``ctx.correlation_px`` > 1 pixels (the splits count
    its independent returns)."""
    from ..plane_faces import faces_of_faces, faces_of_unfitted  # (plane_faces imports the refinement's context)

    found = faces_of_unfitted(ctx, _NO_PLANE, idx, correlation_px=ctx.correlation_px,
                              min_angle_deg=min_angle_deg)
    window = float(ctx.correlation_px) ** 2
    kept = _pieces_within_distance_noise(
        ctx, faces_of_faces(ctx, found, window, ctx.correlation_px, min_angle_deg) if found else [])
    return sorted(kept, key=lambda item: -item[0].size) if len(kept) >= 2 else []


#: What :func:`faces_of_unexplained` tells the faces of a region no model fits (the recovery's
#: plane refused, or a blob the split explained nothing of).
_NO_PLANE = FitFailure("plane", "no plane within the noise of its pixels")


def _pieces_within_distance_noise(ctx: Context, faces: list) -> list:
    # each plane face of ``faces`` (``[(pixels, model)]``) cut to its piece within the distance
    # noise of its plane along the rays, where it has one
    kept = []
    for face, plane in faces:
        if isinstance(plane, Plane):
            piece, fitted = ctx.within_distance_noise(face, plane, refit=False)
            if piece is not None:
                kept.append((piece, fitted))
    return kept


def _alive(fits: dict, old: np.ndarray, below: int | None) -> np.ndarray:
    # per label of the flat ``old`` (all below ``below`` when given, else measured): whether
    # it still has a model in ``fits``
    alive = np.zeros(int(old.max(initial=0)) + 1 if below is None else int(below), bool)
    alive[[j for j in range(1, alive.size) if fits.get(j)]] = True
    return alive


def differing_pixels(a: np.ndarray, b: np.ndarray, where=None) -> np.ndarray:
    """Flat indices (increasing) of the pixels where the label images ``a`` and ``b`` differ:
    ``np.flatnonzero(a != b)``, compared only in ``where`` (a ``(row0, row1, col0, col1)``
    box or a ``(K, 4)`` array of them, clipped to the grid) when given, which must hold every
    such pixel."""
    if a.shape != b.shape:  # (the kernel reads both at the same indices)
        raise ValueError(f"differing_pixels: the label images must have one shape, got {a.shape} and {b.shape}")
    if where is None:
        return np.flatnonzero(a.reshape(-1) != b.reshape(-1))
    from ..kernels import differing_in_boxes

    # one compiled pass over the boxes (a pixel of overlapping boxes listed once)
    return differing_in_boxes(np.ascontiguousarray(a), np.ascontiguousarray(b), _box_rows(where))


def _merged_rms_as_found(found_rms: dict, fits: dict, found: np.ndarray, labels: np.ndarray,
                         pool: np.ndarray) -> dict:
    """``found_rms`` (per plane found in the blobs, its rms on the pixels it was found on, all
    among the flat ``pool``, increasing) with, for each region of ``fits`` that took such
    planes by a merge, the largest of theirs and its own (a tile region has none): the rms of
    pixels of its surface found apart from those it took with them. A plane found in the
    blobs that merged others is held to the largest too, not to its own: which of the pieces
    kept its label is the merge's choice, and the pieces' own pixels, taken by the survivor,
    would be held to the smaller rms of another piece. ``found``: the labels when they were
    found; ``labels``: now."""
    gone = [k for k in found_rms if k not in fits]
    if not gone:
        return found_rms
    floors, now = dict(found_rms), labels.reshape(-1)
    for k, idx in _grouped(pool, found.reshape(-1)[pool], gone).items():
        owner = int(np.bincount(now[idx]).argmax())
        if owner and fits.get(owner):
            floors[owner] = max(floors.get(owner, 0.0), found_rms[k])
    return floors


def _gains_within_distance_noise(ctx: Context, before: np.ndarray, found: np.ndarray, labels: np.ndarray,
                                 fits: dict, refused: set, *, below: int | None = None, where=None,
                                 found_rms: dict | None = None) -> np.ndarray:
    """``labels`` with the pixels each plane region took after the blobs were fitted
    (``found``: the labels then; by its rim, its claims, or a merge with a plane found in
    them) that lie beyond ``TRIM_SIGMAS`` times the noise of their distances to its plane
    (range noise x incidence cosine, at least the plane's rms) given back to the regions
    they had ``before`` (free where that region has no model). The planes of ``refused``
    were cut to their distance noise already. ``below`` (optional): a number above every
    label of ``before``; ``where`` (optional): a box or boxes holding every pixel whose label
    changed since ``found`` (:func:`differing_pixels`). ``found_rms`` (optional): per plane found in
    the blobs, its rms on the pixels it was found on; when smaller, that is the floor instead
    of the plane's rms now, which the pixels it took since may have raised (a box side seen
    at 87 degrees whose pieces merged after their rims took pixels of the table and of the
    box's other faces: rms 0.10 mm, its own pixels 0.05 mm, the pixels taken 0.10 mm off it,
    76 % of its region on the face, tabletop_abw seed 71 scan 1).

    The rim and the claims test a pixel against ``k_sigma`` range-noise sigmas: a face seen
    edge-on has its plane along the rays beside its image line, within that of the pixels
    of the faces next to it (a box side took 97 pixels of the table and of the box's other
    faces, tabletop_abw), while a pixel of the face itself moves off it by the range noise
    times the incidence cosine only.
    """
    labels = np.ascontiguousarray(labels)
    flat, old = labels.reshape(-1), before.reshape(-1)
    # the few pixels whose label changed since the fit, not a pass per region over the grid
    moved = differing_pixels(labels, found, where)
    owner = flat[moved]
    order = np.argsort(owner, kind="stable")
    moved, owner = moved[order], owner[order]
    alive = _alive(fits, old, below)  # the regions of ``before`` that still have a model
    bounds = np.flatnonzero(np.diff(owner)) + 1
    for first, idx in zip([0, *bounds.tolist()], np.split(moved, bounds)):
        k = int(owner[first]) if idx.size else 0
        model = fits.get(k) if k and k not in refused else None
        if not model or model.kind != "plane":
            continue
        points = rows_at(ctx.xyz, idx)
        floor = model.rms if found_rms is None else min(model.rms, found_rms.get(k, model.rms))
        noise = np.maximum(distance_noise(model, points, ctx.sigma[idx]), floor)
        far = idx[np.abs(model.distances(points)) > TRIM_SIGMAS * noise]
        if far.size:
            previous = old[far]
            flat[far] = np.where(alive[previous], previous, 0)
    return labels


def claim_grazing_limbs(ctx: Context, labels: np.ndarray, fits: dict, *, valid: np.ndarray,
                        k_sigma: float, rings: int = 3) -> np.ndarray:
    """Free pixels beside a region that its model explains within the noise of their
    distances join it, ring by ring (at most ``rings``); returns new labels. The cylinders
    and spheres claim first, then the planes.

    A column's or ball's limbs turn to grazing: there every grid step is a range jump, so
    growth (which never crosses a jump edge) leaves the last columns of the limb free, a
    fifth to a quarter of a 0.1-0.2 m column at 0.5 deg (nodding_0.5deg seeds 37, 89, 19:
    46 of 66, 70 of 93, 51 of 71 px). A laser's return errs along its ray only, so its
    distance to the surface carries the range noise times the incidence cosine of the
    model's normal there: a limb pixel lies within ``k_sigma`` of that noise, a mixed return
    or the wall behind the limb (centimetres along its ray) does not. The models are kept
    (the limbs hardly move them). Laser single returns only (the caller's gate); on a
    360-degree grid the rings do not cross the seam (a limb there stays free, as before).
    A plane seen near grazing is the same: each row of a box top a spinning lidar sees four
    rows deep at 2 m is a range jump (spinning_64x1024 seed 929: its far row left free, the
    top 67 % found); its distance noise is the range noise times the cosine of its normal on
    the ray, and a return beyond its edge (the wall or floor behind) is decimetres off it.
    One compiled pass per ring (:func:`rangeseg_o3d.kernels.claim_limbs`); a test within
    rounding of its bound is left to the numpy form, as the noise tests of
    :class:`~rangeseg_o3d.refinement.context.Context` do.
    """
    if not (isinstance(labels, np.ndarray) and labels.ndim == 2):
        raise ValueError(f"claim_grazing_limbs: labels must be an (H, W) array, got {np.shape(labels)}")
    if np.shape(valid) != labels.shape:
        raise ValueError(f"claim_grazing_limbs: valid must have the labels' shape {labels.shape}, "
                         f"got {np.shape(valid)}")
    claiming = [k for k, m in fits.items() if m and m.kind in ("cylinder", "sphere")]
    claiming += [k for k, m in fits.items() if m and m.kind == "plane"]
    if not claiming:
        return labels
    # one compiled pass per ring over the free pixels beside the claiming regions (the numpy
    # form's masks and gathers per region and ring cost 0.2-0.4 ms an LMS200 scan)
    kinds = np.empty(len(claiming), np.int64)
    params = np.zeros((len(claiming), PARAM_SLOTS))
    for t, k in enumerate(claiming):
        kinds[t], params[t] = model_row(fits[k])
    if not kinds.all():  # another plugin's model (no table row): its own distances decide
        return _claim_grazing_limbs_numpy(ctx, labels, fits, claiming, valid=valid, k_sigma=k_sigma, rings=rings)
    origins = ctx.row_origins
    origins = np.zeros((labels.shape[0], 3)) if origins is None else np.ascontiguousarray(origins, dtype=np.float64)
    claimed, unsure = kernels.claim_limbs(
        np.ascontiguousarray(labels), np.ascontiguousarray(valid, dtype=np.bool_), np.ascontiguousarray(ctx.xyz, dtype=np.float64),
        np.ascontiguousarray(ctx.sigma, dtype=np.float64), origins, np.asarray(claiming, dtype=np.int64), kinds, params,
        float(k_sigma), int(rings), _LIMB_ROUNDING)
    if not unsure:
        return claimed.astype(labels.dtype, copy=False)
    # a distance within rounding of its bound: numpy's own rounding decides, as it always did
    return _claim_grazing_limbs_numpy(ctx, labels, fits, claiming, valid=valid, k_sigma=k_sigma, rings=rings)


#: Relative margin about the limb test's bound within which the compiled pass leaves the answer
#: to numpy (:func:`claim_grazing_limbs`): thousands of times float64's rounding of the terms
#: of one distance (2.2e-16); outside it both roundings answer alike.
_LIMB_ROUNDING = 1e-12


def _claim_grazing_limbs_numpy(ctx: Context, labels: np.ndarray, fits: dict, claiming: list, *,
                               valid: np.ndarray, k_sigma: float, rings: int) -> np.ndarray:
    # claim_grazing_limbs in numpy (the compiled pass's meaning, and its answer where a test
    # lies within rounding of its bound): per claiming region and ring, masks within its
    # bounding box grown by the rings it may take
    labels = labels.copy()
    h, w = labels.shape
    # each region's work within its bounding box grown by the rings it may take (plus the ring
    # beside the last): the masks of a whole grid per region and ring cost ~0.2 ms an LMS200 scan
    boxes = kernels.label_boxes(np.ascontiguousarray(labels, dtype=np.int32), int(labels.max(initial=0)) + 1)
    reach = int(rings) + 1
    active = claiming
    for _ in range(int(rings)):
        grew = []
        for k in active:
            if k >= len(boxes) or boxes[k, 1] <= boxes[k, 0]:
                continue  # (a model without pixels)
            r0, r1 = max(boxes[k, 0] - reach, 0), min(boxes[k, 1] + reach, h)
            c0, c1 = max(boxes[k, 2] - reach, 0), min(boxes[k, 3] + reach, w)
            crop = labels[r0:r1, c0:c1]
            region = crop == k
            beside = np.zeros_like(region)
            beside[1:] |= region[:-1]
            beside[:-1] |= region[1:]
            beside[:, 1:] |= region[:, :-1]
            beside[:, :-1] |= region[:, 1:]
            rows, cols = np.nonzero(beside & (crop == 0) & valid[r0:r1, c0:c1])
            if rows.size == 0:
                continue
            idx = (rows + r0) * w + (cols + c0)
            points = rows_at(ctx.xyz, idx)
            rays = ctx.viewing_rays(idx)
            cosines = np.abs(np.sum(fits[k].normals(points) * rays, axis=1))
            ok = np.abs(fits[k].distances(points)) <= k_sigma * ctx.sigma[idx] * cosines
            if ok.any():
                labels.reshape(-1)[idx[ok]] = k
                grew.append(k)
        # a region that took nothing takes nothing later: it is the same and the free pixels fewer
        active = grew
        if not active:
            break
    return labels
