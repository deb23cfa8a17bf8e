"""Plane regions of a tile grid that hold several faces, split at full resolution.

On a depth camera far from a box, the tile means of two of its faces (one seen near
grazing, one near head-on) can fit one plane within the range noise: the noise moves each
mean along its ray, nearly within the grazing face's plane, and the tile grid sees no
crease. Its pixels do: over them that plane is beyond the noise of their distances (range
noise times the incidence cosine), and the narrow face's plane, which its few tile means
could not give, is fitted to its pixels (:func:`split_plane_faces`, :func:`faces_of_plane`).
A cylinder or sphere region bent over such a corner gives way to the two faces when the pattern of its
misfit across the crease is many times theirs (:func:`faces_of_curved`; three or four
faces when two planes leave a side's pixels off: :func:`_faces_of_leaves`), a region no model
fitted is cut into the faces its crease lines separate (:func:`faces_of_unfitted`), and a face
that only continues the plane of a region beside it joins that region (:func:`_continued_plane`).
A face seen near grazing takes back the pixels beside it its rays meet nearer, in range
noise, than their regions' planes (:func:`claim_along_rays`).
"""

from __future__ import annotations

import numpy as np
from scipy.special import fdtri, ndtr

from ._numeric import rows_at, unique_ints
from .fitting.plane import fit_plane
from .fitting.primitives import Cylinder, FitFailure, Plane, Sphere, front_along_rays
from .fitting.region_fitter import fresh_label, region_indices
from .fitting.robust import beyond_noise, curvature_resolved, distance_noise
from .kernels.linalg import CHI_SQUARE_SIGMAS
from .kernels.modelnoise import plane_distances_noise, plane_noise_sums
from .kernels.claims import block_offsets, box_claims
from .kernels.rays import crease_cut_squares
from .fullres import region_stats
from .ray_planes import pixel_moments, ray_fits, ray_moments, ray_plane, ray_terms, robust_ray_plane
from .refinement.context import TRIM_SIGMAS, touching

__all__ = ["BLOCK_SAMPLES", "BLOCK_SIGMAS", "CLAIM_REACH", "FACE_BLOCKS", "FINE_DIRECTIONS", "HIDDEN_SHARE", "SEARCH_STRIDE", "CUT_DIRECTIONS", "CUT_SHARE", "CUTS", "CYLINDER_TEST_PIXELS", "FACE_RETURNS", "FACE_TEST_PIXELS", "LINE_SEARCH_PIXELS", "PATTERN_BINS",
           "PATTERN_RATIO", "PLANES_COVER", "claim_along_rays", "crease_line", "faces_of_curved", "faces_of_faces", "faces_of_plane", "faces_of_unfitted", "hidden_faces", "join_pieces_along_rays", "misfit_patterns", "plane_beside", "share_near_curved",
           "split_plane_faces"]

#: Pixels of a plane region (an even subsample) on which :func:`split_plane_faces` first
#: asks whether its own plane is beyond the noise of their distances (the cheap gate before
#: the split's searches over every pixel).
FACE_TEST_PIXELS = 1024
#: Fewest independent returns each face must hold where a split's piece is split again
#: (:func:`faces_of_faces`): a plane over fewer is placed by the noise (a 288-px sliver
#: under a Kinect's noise, which errs together over 9 x 9 pixels, holds 3.6 of them).
FACE_RETURNS = 30
#: Directions on the sensor grid (over half a turn) of the straight lines tried as the
#: crease between two faces of a region (:func:`crease_line`) ...
CUT_DIRECTIONS = 32
#: ... equal-count cuts tried across each direction ...
CUTS = 129
#: ... and the least share of the region's pixels on either side of a cut.
CUT_SHARE = 0.1
#: Pixels of a region (an even subsample) over which :func:`crease_line` searches its line.
LINE_SEARCH_PIXELS = 16384
#: Share of a region's pixels the faces found must keep (the rest: bits under the size floor).
PLANES_COVER = 0.9
#: Equal-count bins across the crease line in which :func:`faces_of_curved` compares the
#: misfit patterns of a cylinder and of two planes ...
PATTERN_BINS = 16
#: ... and the ratio of the two patterns (their chi-squares over the bins) beyond which the
#: cylinder's misfit is not the noise's: the F distribution's quantile of PATTERN_BINS and
#: PATTERN_BINS degrees of freedom at the tail of CHI_SQUARE_SIGMAS normal deviations.
PATTERN_RATIO = float(fdtri(PATTERN_BINS, PATTERN_BINS, ndtr(CHI_SQUARE_SIGMAS)))
#: Blocks of BLOCK_SAMPLES x BLOCK_SAMPLES independent returns (matching windows) over which
#: :func:`hidden_faces` averages a plane region's residuals along the rays ...
BLOCK_SAMPLES = 4
#: ... the least mean of a block, in noise units of its independent returns, that marks it ...
BLOCK_SIGMAS = 3.0
#: ... and the least connected blocks of one sign a hidden face is looked for under.
FACE_BLOCKS = 4
#: The largest share of its region's pixels a hidden face may take (a larger one is no face
#: the region hides: the region's plane is off its surface).
HIDDEN_SHARE = 0.25
#: Directions of the crease line :func:`hidden_faces` tries again within one of CUT_DIRECTIONS'
#: steps either side of the best (a face cut off by the frame's edge meets the wall on a
#: line within a few degrees of the edge; steps of 5.6 degrees leave a 13-row strip's
#: triangle on both sides of the line).
FINE_DIRECTIONS = 23
#: :func:`hidden_faces`' line searches try every SEARCH_STRIDE-th of the CUT_DIRECTIONS first,
#: then those near the best (:func:`crease_line`'s ``stride``; the searches were most of its cost).
SEARCH_STRIDE = 2
#: Pixels of a cylinder or sphere region (an even subsample) on which :func:`faces_of_curved` first
#: looks for the two planes (the cheap gate before the search over every pixel).
CYLINDER_TEST_PIXELS = 4096
#: Pixels beyond a grazing plane region's box that :func:`claim_along_rays` looks at, at
#: least (its box is grown by its own height and width).
CLAIM_REACH = 8


def _beyond_distance_noise(points: np.ndarray, sigma: np.ndarray, independent: float) -> bool:
    # whether the least-squares plane of ``points`` (range noise ``sigma``) leaves an rms
    # beyond the noise of their distances to it, over ``independent`` returns
    plane = fit_plane(points)
    if not plane:
        return False
    # the noise's sum of squares in one compiled pass (numpy's rays, cosines and noise arrays
    # took half the gate's time; the sum's rounding differs)
    _, noise_squares, _, _ = plane_noise_sums(points, sigma, np.arange(points.shape[0]),
                                              np.asarray(plane.normal, dtype=np.float64), float(plane.d))
    return beyond_noise(plane.rms, float(np.sqrt(noise_squares / points.shape[0])), max(int(independent), 1))


def _own_plane_beyond_noise(xyz: np.ndarray, noise: np.ndarray, idx: np.ndarray, window: float) -> bool:
    # split_plane_faces' gate: the least-squares plane of an even subsample of the pixels
    # ``idx`` beyond the noise of their distances, over at most their independent returns
    sample = idx[:: max(1, idx.size // FACE_TEST_PIXELS)]
    return _beyond_distance_noise(xyz[sample], noise[sample], min(sample.size, idx.size / window))


def faces_of_faces(ctx, surfaces: list, window: float, correlation_px: int, min_angle_deg: float) -> list:
    """``surfaces`` (``[(pixels, plane)]``, the faces a region was split into) with each
    piece of two faces' pixels whose plane is beyond the noise of its distances split again
    into the faces it holds (:func:`faces_of_plane`, each face at least FACE_RETURNS of the
    ``window`` pixels the noise errs together over), until none is: a cylinder's tile
    model over a far box's corner is cut along one crease line into two faces, and the
    third face (the box's top, seen near grazing) stays in the piece beside it (stereo study
    seed 1293 scan 3: a cylinder region of 6044 px over a box's front, side and top cut into
    5150 px, 508 of them the top's 553, and 838)."""
    out, todo = [], list(surfaces)
    # a piece under two faces' floor of pixels, or of FACE_RETURNS, is not searched (no split could stand)
    floor = 2 * max(ctx.min_size, FACE_RETURNS * window)
    while todo:
        piece, plane = todo.pop()
        faces = []
        if piece.size >= floor and _own_plane_beyond_noise(ctx.xyz, ctx.sigma, piece, window):
            faces = faces_of_plane(ctx, plane, piece, correlation_px=correlation_px, min_angle_deg=min_angle_deg)
        if faces and min(face.size for face, _ in faces) >= FACE_RETURNS * window:
            todo.extend(faces)
        else:
            out.append((piece, plane))
    return out


def split_plane_faces(cloud, labels: np.ndarray, fits: dict, stats, *, fitter, sigma: np.ndarray,
                      min_size: int, inlier_factor: float, min_angle_deg: float, correlation_px: int = 1,
                      wrap_columns: bool = False):
    """Each plane region of at least two faces' pixels (``2 min_size``) whose own plane is
    beyond the noise of its pixels' distances, each cylinder or sphere region of as many pixels
    whose misfit two or more planes explain (:func:`faces_of_curved`), and each region of as
    many pixels no model fitted whose crease lines cut it into planes (:func:`faces_of_unfitted`),
    is split into the planes of the faces it holds (:func:`faces_of_plane`, at least
    ``min_angle_deg`` apart; a curved region's pieces that hold two faces are split again,
    :func:`faces_of_faces`); a face that continues the plane of a region it touches (of a
    region split into three faces or more: that the region touched) joins that region
    (:func:`_continued_plane`), of the others the largest keeps the label. Returns ``(labels, fits, stats)``, the statistics of
    the regions changed measured again; the inputs when no region is split.

    The gate looks at an even subsample of ``FACE_TEST_PIXELS`` pixels, counted as at most
    the region's independent returns (a sensor whose noise errs together over
    ``correlation_px`` x ``correlation_px`` pixels has that many times fewer than pixels):
    a face seen head-on keeps the range noise in its distances, a grazing one its cosine's
    share, and the plane of either fits at that noise.
    """
    from .refinement.context import Context

    counts = stats.counts
    candidates = [k for k, m in fits.items()
                  if isinstance(m, (Plane, Cylinder, Sphere)) and 0 < k < counts.size and counts[k] >= 2 * min_size]
    # the regions no model fitted (their statistics count no pixel: their sizes come below)
    unfitted = [k for k, m in fits.items() if isinstance(m, FitFailure) and k > 0]
    if not candidates and not unfitted:
        return labels, fits, stats
    xyz, noise = cloud.xyz.reshape(-1, 3), sigma.ravel()
    window = float(max(int(correlation_px), 1)) ** 2
    suspects = {}
    for k, idx in region_indices(labels, only=candidates + unfitted).items():
        if isinstance(fits[k], FitFailure) and idx.size < 2 * min_size:  # (its size is known only here)
            continue
        # a curved region's own test starts on a subsample (faces_of_curved); a region no
        # model fitted is asked whole (faces_of_unfitted)
        if isinstance(fits[k], (Cylinder, Sphere, FitFailure)) or _own_plane_beyond_noise(xyz, noise, idx, window):
            suspects[k] = idx
    hidden = window > 1.0 and any(isinstance(fits[k], Plane) for k in candidates)
    if not suspects and not hidden:
        return labels, fits, stats
    ctx = Context(cloud, fitter, sigma, min_size, wrap_columns=wrap_columns, correlation_px=max(int(correlation_px), 1))
    out, fits, split = None, dict(fits), []
    next_label = fresh_label(labels, fits)
    walls, made = {}, set()  # the ray-space sums of the planes pieces were offered to; the faces found
    for k, idx in suspects.items():
        faces = (faces_of_curved if isinstance(fits[k], (Cylinder, Sphere))
                 else faces_of_unfitted if isinstance(fits[k], FitFailure) else faces_of_plane)
        surfaces = faces(ctx, fits[k], idx, correlation_px=correlation_px, min_angle_deg=min_angle_deg)
        if not surfaces:
            continue
        if faces is faces_of_curved:
            surfaces = faces_of_faces(ctx, surfaces, window, correlation_px, min_angle_deg)
        if out is None:
            out = np.array(labels, dtype=np.int32, order="C")
        # three faces or more: a face may continue a plane the region touched that none of
        # its pieces does (a pipe before a box's face cuts the face in two: study seed 7 scan 3)
        beside = touching(out, idx, 1) - {0, k} if len(surfaces) > 2 else set()
        flat = out.reshape(-1)
        flat[idx] = 0
        split.append(k)
        made.add(k)
        kept = []
        for piece, surface in sorted(surfaces, key=lambda s: -s[0].size):
            # the rest of a neighbour's plane, or of a plane beyond what stands before the
            # piece (a far wall's strip a pipe cuts off from the wall's region), as below
            wall = (_continued_plane(ctx, out, fits, piece, surface, walls, skip=made, beside=beside)
                    or _plane_explaining(ctx, out, fits, piece, window, skip=made))
            if wall:  # the rest of a neighbour's plane the tile region had taken
                flat[piece] = wall
                split.append(wall)
                walls.pop(wall, None)  # its pixels changed
            else:
                kept.append((piece, surface))
        for i, (piece, surface) in enumerate(kept):
            label = k if i == 0 else next_label
            next_label += i > 0
            flat[piece] = label
            fits[label] = surface
            split.append(label)
            made.add(label)
    if hidden:
        # the plane regions no split touched: faces their pixels hide, which their mean
        # residuals along the rays show (hidden_faces)
        current = labels if out is None else out
        found = hidden_faces(ctx, current, fits, [k for k in candidates if k not in made and isinstance(fits[k], Plane)],
                             correlation_px=correlation_px, min_angle_deg=min_angle_deg)
        for k, pieces in found.items():
            for piece, surface in pieces:
                if out is None:
                    out = np.array(labels, dtype=np.int32, order="C")
                flat = out.reshape(-1)
                wall = (_continued_plane(ctx, out, fits, piece, surface, walls, skip={k})
                        or _plane_explaining(ctx, out, fits, piece, window, skip={k}))
                if wall:  # a face of another region the region had taken: back to it
                    flat[piece] = wall
                    walls.pop(wall, None)
                    split.extend((k, wall))
                    continue
                flat[piece] = next_label
                fits[next_label] = surface
                split.extend((k, next_label))
                made.add(next_label)
                next_label += 1
            walls.pop(k, None)
    if out is None:
        return labels, fits, stats
    stats = region_stats(cloud.xyz, out, fits, sigma, inlier_factor, known=stats, stale=split)
    return out, fits, stats


def hidden_faces(ctx, labels: np.ndarray, fits: dict, candidates, *, correlation_px: int,
                 min_angle_deg: float = 0.0) -> dict:
    """``{label: [(pixels, plane)]}``: the faces each plane region of ``candidates`` (labels
    of ``labels`` with a :class:`Plane` in ``fits``) holds beside the face its plane is, on a
    sensor whose range noise errs together over ``correlation_px`` x ``correlation_px`` pixels.

    A far box's face seen near grazing beside the face seen head-on lies within 1-2 range
    sigmas of the head-on face's plane along its rays pixel by pixel, and a few thousand of
    its pixels are a percent of a wall's region: no gate on the whole region, and no
    crease line with a tenth of the region on either side (:func:`faces_of_plane`), finds
    it. Its mean offset along the rays does: 245 independent returns 1.16 sigmas off are
    18 sigmas off together. So the residuals along the rays of each region's plane, one
    pixel a matching window (an independent return), are averaged over blocks of
    BLOCK_SAMPLES x BLOCK_SAMPLES of them; blocks at least BLOCK_SIGMAS off (in the noise
    of their mean), FACE_BLOCKS or more of one sign at most a block apart, mark a piece. Over the region's
    pixels in the piece's box grown by its own height and width, the crease line
    (:func:`crease_line`, its best direction searched again over FINE_DIRECTIONS) must give two faces
    (:func:`_faces_of_sides`, at least ``min_angle_deg`` apart, PLANES_COVER of the pixels)
    that each fit their planes within the range noise over their independent returns
    (:func:`_within_noise_along_rays`) and beat one plane by the F-test of
    :func:`~rangeseg_o3d.fitting.robust.curvature_resolved` over those returns. The piece
    of the marked side is the hidden face, if it takes at most HIDDEN_SHARE of its region; boxes of one region are taken in turn, a later
    one without the pixels an earlier face took, and a face within ``min_angle_deg`` of an
    earlier one's plane joins it.
    """
    from scipy import ndimage

    c = max(int(correlation_px), 1)
    planes = [k for k in candidates if 0 < k and isinstance(fits.get(k), Plane)]
    if not planes:
        return {}
    height, width = labels.shape
    # labels past the largest candidate's have no slot (the frame's maximum need not be
    # scanned: a candidate without pixels sums nothing and marks no block)
    top = max(planes) + 1
    # the planes' slots: the sums kept for them only (a slot per label, hundreds of them, took
    # more than the pass to zero and to scan)
    slots = np.full(top, -1, dtype=np.int64)
    slots[planes] = np.arange(len(planes))
    normals = np.array([np.asarray(fits[k].normal, dtype=np.float64) for k in planes]).reshape(-1, 3)
    offsets = np.array([float(fits[k].d) for k in planes], dtype=np.float64)
    # one pixel a matching window (the independent returns), in blocks, in one compiled pass
    # (numpy's gathers and sums took 13 ms a scan)
    b = BLOCK_SAMPLES
    sums, counts = block_offsets(ctx.xyz, ctx.sigma, np.ascontiguousarray(labels), slots, normals, offsets, c, b)
    z = sums / np.sqrt(np.maximum(counts, 1))
    full = counts >= b * b // 2
    found, region_sizes = {}, {}
    for p, k in enumerate(planes):
        def region_size(k=k):  # counted once, and only for a piece past the pre-test
            if k not in region_sizes:
                region_sizes[k] = int(np.count_nonzero(labels == k))
            return region_sizes[k]

        for sign in (1.0, -1.0):
            marked = full[p] & (sign * z[p] >= BLOCK_SIGMAS)
            if np.count_nonzero(marked) < FACE_BLOCKS:
                continue
            # blocks a block apart are one piece (a face's strip narrowing to a few rows,
            # or the noise, leaves gaps; pieces of one face would over-segment it)
            pieces, n = ndimage.label(_dilated(marked))
            pieces[~marked] = 0
            sizes = np.bincount(pieces.ravel(), minlength=n + 1)
            for j in np.flatnonzero(sizes[1:] >= FACE_BLOCKS) + 1:
                face = _hidden_face(ctx, labels, k, pieces == j, b * c, (height, width), correlation_px,
                                    min_angle_deg, taken=found.get(k, []), region_size=region_size)
                # a face hidden in a region is a small part of it: one of half of it or more means
                # the region's plane is no wall's (a pipe, or a tile model off its surface), which
                # the region's own split judges (a pure 7700-px region halved: fresh seed 1004 scan 3)
                if face is not None and face[0].size <= HIDDEN_SHARE * region_size():
                    found[k] = _join_coplanar(ctx, found.get(k, []), face, min_angle_deg)
    return found


def _dilated(mask: np.ndarray) -> np.ndarray:
    """``mask`` (2-D, boolean) dilated by one cell in each of the 8 directions: scipy's
    ``binary_dilation`` with a 3 x 3 structure, by slices (on a block grid of a few thousand
    cells scipy's call costs ten times the work)."""
    out = mask.copy()
    height, width = mask.shape
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                out[max(dr, 0):height + min(dr, 0), max(dc, 0):width + min(dc, 0)] |= \
                    mask[max(-dr, 0):height + min(-dr, 0), max(-dc, 0):width + min(-dc, 0)]
    return out


def _join_coplanar(ctx, faces: list, face: tuple, min_angle_deg: float) -> list:
    """``faces`` with ``face`` ``(pixels, plane)`` added: joined to the first of them whose
    plane is within ``min_angle_deg`` of its own (two pieces of one face, which the noise
    marked apart), the union's plane fitted along the rays again."""
    piece, plane = face
    for i, (other, other_plane) in enumerate(faces):
        if np.degrees(np.arccos(min(1.0, abs(float(np.asarray(plane.normal) @ np.asarray(other_plane.normal)))))) \
                < min_angle_deg:
            union = np.union1d(other, piece)
            _, a = ray_fits(pixel_moments(ctx.xyz, ctx.sigma, union))
            joined = ray_plane(a[0], ctx.xyz[union])
            if joined:
                return faces[:i] + [(union, joined)] + faces[i + 1:]
    return faces + [face]


def _hidden_face(ctx, labels: np.ndarray, k: int, blocks: np.ndarray, side: int, shape: tuple,
                 correlation_px: int, min_angle_deg: float, taken=(), region_size=None):
    """The face ``(pixels, plane)`` of region ``k`` under the marked ``blocks`` (a grid of
    ``side`` x ``side`` pixel blocks) when the crease line over its window gives it
    (:func:`hidden_faces`), None when not; the pixels of the faces in ``taken`` are left out.
    With ``region_size`` (a function: the region's pixels), None too when the region's pixels under the
    marked blocks (one a matching window, ``correlation_px`` x ``correlation_px`` each) are
    more than HIDDEN_SHARE of them."""
    height, width = shape
    rows, cols = np.nonzero(blocks)
    r0, r1 = rows.min() * side, min((rows.max() + 1) * side, height)
    c0, c1 = cols.min() * side, min((cols.max() + 1) * side, width)
    h, w = r1 - r0, c1 - c0
    r0, r1, c0, c1 = max(0, r0 - h), min(height, r1 + h), max(0, c0 - w), min(width, c1 + w)
    c = max(int(correlation_px), 1)
    window = float(c * c)

    def pixels(step):  # the region's pixels in the window, every ``step``-th row and column
        rr, cc = np.nonzero(labels[r0:r1:step, c0:c1:step] == k)
        idx = (rr * step + r0) * width + (cc * step + c0)
        for piece, _ in taken:
            idx = idx[~np.isin(idx, piece, assume_unique=True)]
        return idx

    # first, on one pixel a matching window (independent returns), the marked blocks' pixels
    # and the rest as the two sides: two planes that do not pass the F-test there, or meet
    # within min_angle_deg, are one face with the noise's blotches (the line's search over
    # every pixel cost ten times as much)
    sample = pixels(c)
    if sample.size * window < 2 * ctx.min_size:
        return None
    pr, pc = np.divmod(sample, width)
    under = blocks[np.minimum(pr // side, blocks.shape[0] - 1), np.minimum(pc // side, blocks.shape[1] - 1)]
    marked_count = int(np.count_nonzero(under))
    if marked_count < 3 or sample.size - marked_count < 3:
        return None  # a side of fewer than three samples has no plane (the marked blocks' pixels taken already)
    one = pixel_moments(ctx.xyz, ctx.sigma, sample)
    marked = pixel_moments(ctx.xyz, ctx.sigma, sample[under])
    (one_chi2,), _ = ray_fits(one)
    (marked_chi2,), (marked_a,) = ray_fits(marked)
    (rest_chi2,), (rest_a,) = ray_fits(tuple(x - y for x, y in zip(one, marked)))
    cosine = abs(float(marked_a @ rest_a)) / max(float(np.linalg.norm(marked_a) * np.linalg.norm(rest_a)), 1e-300)
    if (np.degrees(np.arccos(min(1.0, cosine))) < min_angle_deg
            or not curvature_resolved(float(one_chi2), float(marked_chi2 + rest_chi2), sample.size, 4)):
        return None
    # the face is the side with the larger share of its pixels under the marked blocks, and
    # a face takes at most HIDDEN_SHARE of its region (hidden_faces): marked blocks holding
    # more of the region than that are the region's plane off its surface, no face it hides
    # (the line's search costs ten times this test)
    if region_size is not None and np.count_nonzero(under) * window > HIDDEN_SHARE * region_size():
        return None
    idx = pixels(1)
    if idx.size < 2 * ctx.min_size:
        return None
    (one_chi2,), _ = ray_fits(pixel_moments(ctx.xyz, ctx.sigma, idx))
    # the line's search on the independent returns' share of the pixels, drawn through them all
    chi2, sides = crease_line(ctx, idx, fine=FINE_DIRECTIONS, search_pixels=max(int(idx.size / window), 1),
                              stride=SEARCH_STRIDE)
    # the cheap tests first (the F-test on the line's chi-square, then each side's noise),
    # the faces' pieces and planes last: all must pass, and most lines fail one of the first
    if len(sides) != 2:
        return None
    if not curvature_resolved(float(one_chi2) / window, chi2 / window, max(int(idx.size / window), 1), 4):
        return None
    # each side's sums once, for both tests
    moments = [pixel_moments(ctx.xyz, ctx.sigma, side) for side in sides]
    if not all(_within_noise_along_rays(ctx, side, window, m) for side, m in zip(sides, moments)):
        return None
    surfaces = _faces_of_sides(ctx, idx, sides, min_angle_deg, moments)
    if len(surfaces) < 2 or sum(piece.size for piece, _ in surfaces) < PLANES_COVER * idx.size:
        return None
    # the face: the piece with the larger share of its pixels under the marked blocks
    def marked_share(piece):
        pr, pc = np.divmod(piece, width)
        return float(np.mean(blocks[np.minimum(pr // side, blocks.shape[0] - 1),
                                    np.minimum(pc // side, blocks.shape[1] - 1)]))
    return max(surfaces, key=lambda s: marked_share(s[0]))


def _plane_explaining(ctx, labels: np.ndarray, fits: dict, piece: np.ndarray, window: float, *, skip=()) -> int:
    """The label of the plane region (of ``fits``, not in ``skip``, with pixels in ``labels``)
    whose plane explains the flat pixels ``piece`` along their rays closest, within their range
    noise (the mean square of their residuals in noise units within the chi-square bound of
    their independent returns, ``window`` pixels each); 0 when none does. A face a pipe
    before it cuts in two leaves the piece beyond the pipe under the wall beside it: its own
    face's region touches it not, and a region of its own would over-segment the face."""
    from .kernels.linalg import noise_rms_bound

    rays, inverse, weight = ray_terms(ctx.xyz[piece], ctx.sigma[piece])
    bound = noise_rms_bound.py_func(1.0, max(piece.size / window, 1.0), CHI_SQUARE_SIGMAS)
    best, label = bound * bound, 0
    for other, model in fits.items():
        if other <= 0 or other in skip or not isinstance(model, Plane):
            continue
        mean_square = float(np.mean(weight * (inverse - rays @ (np.asarray(model.normal) / model.d)) ** 2))
        if mean_square <= best and np.any(labels == other):
            best, label = mean_square, other
    return label


def _continued_plane(ctx, labels: np.ndarray, fits: dict, piece: np.ndarray, surface, walls: dict, *,
                     skip=(), beside=()) -> int:
    """The label of a plane region touching ``piece`` (flat pixels, increasing; a face
    :func:`faces_of_plane` found, its plane ``surface``) whose plane it continues, 0 when
    none does; ``walls`` caches the regions' ray-space sums
    (:func:`~rangeseg_o3d.ray_planes.ray_moments`), the labels in ``skip`` are not offered, those
    in ``beside`` are offered too (the regions the piece's whole region touched).

    A tile region over a far wall's edge and what stands before it splits into the wall's
    strip and the rest; the strip, a piece of its own, would over-segment the wall. It
    continues a neighbour's plane when the plane fitted along the rays to both (the
    neighbour's pixels and the piece's within TRIM_SIGMAS noise sigmas of its own
    plane: a strip at an occluding edge carries the other surface's mixed pixels) moves the
    piece's pixels by less than their range noise: its chi-square grows by less than one
    per pixel over the two planes apart. A statistical test would not do: a strip of a
    wall along the rows of a stereo camera's correlated streaks is off the wall's plane by
    a significant fraction of its noise (seed 23 scan 3 of the sensor matrix: 0.04 per
    pixel), where a face at an angle is off by hundreds."""
    rays, inverse, weight = ray_terms(ctx.xyz[piece], ctx.sigma[piece])
    a = surface.normal / surface.d
    inliers = weight * (inverse - rays @ a) ** 2 <= TRIM_SIGMAS * TRIM_SIGMAS
    if not inliers.any():
        return 0
    own = ray_moments(rays[inliers], inverse[inliers], weight[inliers])
    own_chi2 = float(ray_fits(own)[0][0])
    best, label = float(np.count_nonzero(inliers)), 0
    for other in sorted((touching(labels, piece, 1) | set(beside)) - {0} - set(skip)):
        if not isinstance(fits.get(other), Plane):
            continue
        if other not in walls:
            walls[other] = pixel_moments(ctx.xyz, ctx.sigma, np.flatnonzero(labels.reshape(-1) == other))
        wall = walls[other]
        union = float(ray_fits(tuple(x + y for x, y in zip(wall, own)))[0][0])
        growth = union - float(ray_fits(wall)[0][0]) - own_chi2
        if growth < best:
            best, label = growth, other
    return label


def crease_line(ctx, idx: np.ndarray, *, with_order: bool = False, fine: int = 0,
                search_pixels: int = LINE_SEARCH_PIXELS, stride: int = 1) -> tuple:
    """``(chi2, sides)``: of the straight lines on the sensor grid (CUT_DIRECTIONS directions
    x CUTS equal-count cuts, each side at least CUT_SHARE of the pixels and ``ctx.min_size``),
    the one that cuts the flat pixels ``idx`` (increasing) into the two faces whose planes
    fitted along the rays (:func:`~rangeseg_o3d.ray_planes.ray_terms`) leave the least
    chi-square, that chi-square and ``sides``, the two flat pixel sets (increasing); ``(inf, [])`` when none is. A
    box's crease seen by a camera is a straight line on its grid; each cut's two planes
    come from running sums along the direction (one sort, no refits). Orthogonal least
    squares would not do: a narrow face seen head-on, its pixels spread along the rays by a
    range noise near its width, has a least-squares plane tilted towards the rays, and the
    crease it puts is a third of a face off. ``with_order`` adds the positions in ``idx``
    ordered across the line (None with no line).

    With ``fine``, the best direction is searched again over ``fine`` directions within one
    of CUT_DIRECTIONS' steps either side. A region of more than ``search_pixels`` pixels is
    searched on an even subsample of them; the line found is drawn through every pixel, and the chi-square is that of every
    pixel's two planes (a floor of 400 000 pixels took seconds searched pixel by pixel).

    With ``stride`` > 1, the search over the CUT_DIRECTIONS tries every ``stride``-th
    direction first and then those within ``stride`` of the best of them: the chi-square
    falls smoothly towards the crease's direction, so the line found is the one of the
    search over every direction unless two valleys lie within ``stride`` steps. The
    ``fine`` directions are all searched."""
    n = idx.size
    side = max(ctx.min_size, int(np.ceil(CUT_SHARE * n)))
    if n < 2 * side:
        return (np.inf, [], None) if with_order else (np.inf, [])
    step = -(-n // max(int(search_pixels), 1))
    search = idx[::step]
    rows, cols = np.divmod(search, ctx.width)
    rays, inverse, weight = ray_terms(ctx.xyz[search], ctx.sigma[search])
    m = search.size
    search_side = max(-(-ctx.min_size // step), int(np.ceil(CUT_SHARE * m)))
    if m < 2 * search_side:
        return (np.inf, [], None) if with_order else (np.inf, [])
    sizes = np.unique(np.linspace(search_side, m - search_side, CUTS).astype(np.int64))
    angles = np.arange(CUT_DIRECTIONS) * (np.pi / CUT_DIRECTIONS)
    # compiled, every direction in one call: the pixels ordered across it (numpy's stable
    # argsort's positions, in linear time), each cut's two sides' sums in one running pass
    # and their 3 x 3 systems solved in place (numpy's pairwise sums and LAPACK's solves
    # took three times as long; the chi-squares differ in the last bits)
    total, orders = _direction_search(rows, cols, rays, inverse, weight, sizes,
                                      np.array([np.cos(angle) for angle in angles]),
                                      np.array([np.sin(angle) for angle in angles]), stride, True)
    total = total.ravel()
    if not np.isfinite(total).any():
        return (np.inf, [], None) if with_order else (np.inf, [])
    best = int(np.argmin(total))
    if fine > 0:  # again, over ``fine`` directions within a step either side of the best
        around = angles[best // sizes.size] + np.linspace(-1.0, 1.0, fine) * (np.pi / CUT_DIRECTIONS)
        # every fine direction: the chi-square over a step's fine directions is no smooth
        # valley (a few pixels cross the line from one to the next; strided, study seed 11
        # scan 2 took another line)
        finer, fine_orders = _direction_search(rows, cols, rays, inverse, weight, sizes, np.cos(around),
                                               np.sin(around), 1, False)
        finer = finer.ravel()
        if float(np.min(finer)) < float(total[best]):
            total, orders, angles = finer, fine_orders, around
            best = int(np.argmin(total))
    chi2 = float(total[best])
    direction, cut = divmod(best, sizes.size)
    order, size, angle = orders[direction], int(sizes[cut]), float(angles[direction])
    if step > 1:
        chi2, order, size = _line_through_every_pixel(ctx, idx, angle, search, order, size, side)
    sides = [np.sort(idx[order[:size]]), np.sort(idx[order[size:]])]
    return (chi2, sides, order) if with_order else (chi2, sides)


def _direction_search(rows, cols, rays, inverse, weight, sizes, cosines: np.ndarray, sines: np.ndarray,
                      stride: int, around: bool) -> tuple:
    """``(total, orders)`` of :func:`~rangeseg_o3d.kernels.rays.crease_cut_squares` over the
    directions ``(cosines, sines)``: with ``stride`` > 1 only every ``stride``-th direction and then
    those within ``stride`` of the best of them (the others' rows: inf chi-squares, their
    orders unset); ``around``: the directions close on themselves (the last one's neighbour
    is the first, half a turn on)."""
    count = cosines.size
    if stride <= 1 or count <= 2 * stride:
        return crease_cut_squares(rows, cols, rays, inverse, weight, sizes, cosines, sines)
    total = np.full((count, sizes.size), np.inf)
    orders = np.zeros((count, rows.size), dtype=np.int64)
    first = np.arange(0, count, stride)
    total[first], orders[first] = crease_cut_squares(rows, cols, rays, inverse, weight, sizes,
                                                     cosines[first], sines[first])
    if not np.isfinite(total).any():
        return total, orders
    best = int(np.argmin(total)) // sizes.size
    near = best + np.arange(-stride + 1, stride)
    near = np.unique(near % count if around else near[(near >= 0) & (near < count)])
    near = near[~np.isin(near, first)]
    if near.size:
        total[near], orders[near] = crease_cut_squares(rows, cols, rays, inverse, weight, sizes,
                                                       cosines[near], sines[near])
    return total, orders


def _line_through_every_pixel(ctx, idx: np.ndarray, angle: float, search: np.ndarray, order: np.ndarray,
                              size: int, side: int) -> tuple:
    """``(chi2, order, size)`` of the line at ``angle`` that cuts the subsample ``search``
    after its ``size`` first pixels in ``order``, drawn through every pixel of ``idx``:
    the cut between the same two positions across the line, each side at least ``side``
    pixels, and the chi-square of the two sides' planes along the rays."""
    def across(flat):
        rows, cols = np.divmod(flat, ctx.width)
        return cols * np.cos(angle) + rows * np.sin(angle)

    ends = across(search[order[[size - 1, size]]])
    position = across(idx)
    full_order = np.argsort(position, kind="stable")
    ordered = position[full_order]
    full_size = int(np.clip(np.searchsorted(ordered, 0.5 * (ends[0] + ends[1]), side="left"),
                            side, idx.size - side))
    chi2 = 0.0
    for part in (full_order[:full_size], full_order[full_size:]):
        squares, _ = ray_fits(pixel_moments(ctx.xyz, ctx.sigma, idx[part]))
        chi2 += float(squares[0])
    return chi2, full_order, full_size


def _faces_of_sides(ctx, idx: np.ndarray, sides: list, min_angle_deg: float = 0.0, moments=None) -> list:
    """The largest connected piece of each of the two ``sides`` of the flat pixels ``idx``
    (at least ``ctx.min_size``), with its side's plane fitted along the rays
    (:func:`~rangeseg_o3d.ray_planes.ray_terms`), ``[(pixels, plane)]``; the other pieces are left free (bits of the
    surfaces beside the region, which a piece of their own would over-segment). The line
    decides each pixel, not the pixel's own distances: near the crease a pixel of the face
    seen head-on is as near the other face's plane as the range noise leaves it (a
    pixel-by-pixel choice moved a fifth of such a face across).
    Empty when the two planes meet within ``min_angle_deg``: pieces of one surface (a
    floor's systematic bend over 400 000 pixels passes any F-test), which the merge joins.
    ``moments``: the sides' :func:`~rangeseg_o3d.ray_planes.pixel_moments`, when made already."""
    if len(sides) != 2:
        return []
    normals, out = [], []
    for i, side in enumerate(sides):
        _, a = ray_fits(pixel_moments(ctx.xyz, ctx.sigma, side) if moments is None else moments[i])
        normals.append(a[0] / max(float(np.linalg.norm(a[0])), 1e-300))
        piece = np.sort(ctx.largest_piece(side))
        plane = ray_plane(a[0], ctx.xyz[piece]) if piece.size >= ctx.min_size else None
        if plane:
            out.append((piece, plane))
    if np.degrees(np.arccos(min(1.0, abs(float(normals[0] @ normals[1]))))) < min_angle_deg:
        return []  # one surface's two pieces: the merge would join them again
    return out


def _off_model(distances: np.ndarray, noise: np.ndarray, independent: float) -> bool:
    """Whether points at ``distances`` from a model lie off it beyond the noise of their
    distances to it (``noise``, :func:`~rangeseg_o3d.fitting.robust.distance_noise`), their
    rms over the chi-square bound of ``independent`` returns."""
    return beyond_noise(float(np.sqrt(np.mean(distances * distances))), float(np.sqrt(np.mean(noise * noise))),
                        max(int(independent), 1))


def _within_noise_along_rays(ctx, idx: np.ndarray, window: float, moments=None) -> bool:
    """Whether the plane fitted along the rays to the flat pixels ``idx`` leaves them within
    their range noise: the mean square of their residuals in noise units within the chi-square
    bound of their independent returns (``window`` pixels each). ``moments``: their
    :func:`~rangeseg_o3d.ray_planes.pixel_moments`, when made already."""
    from .kernels.linalg import noise_rms_bound

    squares, _ = ray_fits(pixel_moments(ctx.xyz, ctx.sigma, idx) if moments is None else moments)
    bound = noise_rms_bound.py_func(1.0, max(idx.size / window, 1.0), CHI_SQUARE_SIGMAS)
    return float(squares[0]) / idx.size <= bound * bound


def faces_of_plane(ctx, model, idx: np.ndarray, *, correlation_px: int = 1, min_angle_deg: float = 0.0) -> list:
    """The planes of the faces the plane region ``idx`` (flat pixels, increasing) of
    ``model`` holds, ``[(pixels, plane)]``; empty when it holds one face.

    The region must be beyond the noise of its distances to ``model`` with a connected
    piece of its pixels beyond it (``facets._holds_another``, the model's own outliers not
    counted: a plane over two faces spreads its misfit over both). Its pixels are cut along
    the straight line whose sides' planes fit them closest (:func:`crease_line`; a trimmed
    search, even at the noise of a grazing face's distances, takes the diagonal plane
    through both faces, which holds most pixels), each side's largest connected piece
    keeping its plane (:func:`_faces_of_sides`; the planes at least ``min_angle_deg``
    apart). The pieces must take PLANES_COVER of the pixels, and the two planes lower the
    chi-square of one plane along the rays by more than their four extra parameters would (the F-test of
    :func:`rangeseg_o3d.fitting.robust.curvature_resolved`), counted in independent returns:
    a sensor whose noise errs together over ``correlation_px`` x ``correlation_px`` pixels
    (a stereo camera's matching window) has that many times fewer.

    On such a sensor a far box's faces can hide pixel by pixel: at 5-6 m its range noise is a
    tenth of a metre, and no connected piece of the region's floor of pixels stands 4 sigmas
    off a plane bent over both faces a few sigmas deep. Over their independent returns they
    do not hide. So there, a region with no such piece is split all the same when its model is
    beyond the noise of its distances over its independent returns (a ninth of its pixels over
    a 3-pixel window) and each side of the crease line fits its plane along the rays within
    the range noise, over its own independent returns (:func:`_within_noise_along_rays`): two
    faces, not one face with a few pixels of other surfaces, whose line cuts off a piece of
    the face with them.
    """
    from .refinement.facets import _holds_another

    # the distances and their noise once, for both gates (each computed the noise over
    # every pixel); a plane's in one compiled pass (numpy's gathers cost ~1 ms a region)
    if isinstance(model, Plane):
        distances, noise = plane_distances_noise(ctx.xyz, ctx.sigma, np.ascontiguousarray(idx, dtype=np.int64),
                                                 np.asarray(model.normal, dtype=np.float64), float(model.d))
    else:
        points = ctx.xyz[idx]
        distances, noise = model.distances(points), distance_noise(model, points, ctx.sigma[idx])
    rms = float(np.sqrt(np.mean(distances * distances)))
    # pixel by pixel; else, on a matched window, over the independent returns (see above)
    held = _holds_another(ctx, model, idx, distances, rms, count_outliers=False, noise=noise)
    window = float(max(int(correlation_px), 1)) ** 2
    if not held and (window == 1.0 or not _off_model(distances, noise, idx.size / window)):
        return []
    chi2, sides = crease_line(ctx, idx)
    surfaces = _faces_of_sides(ctx, idx, sides, min_angle_deg)
    if len(surfaces) < 2 or sum(piece.size for piece, _ in surfaces) < PLANES_COVER * idx.size:
        return []
    if not held and not all(_within_noise_along_rays(ctx, side, window) for side in sides):
        return []
    # one plane along the rays against the two, in independent returns: the chi-squares and
    # counts over the matching window's pixels (the F-test of curvature_resolved, a second
    # plane and the crease line: four parameters more)
    one, _ = ray_fits(pixel_moments(ctx.xyz, ctx.sigma, idx))
    share = 1.0 / float(max(int(correlation_px), 1)) ** 2
    if not curvature_resolved(share * float(one[0]), share * chi2, max(int(share * idx.size), 1), 4):
        return []
    return surfaces


def faces_of_unfitted(ctx, model, idx: np.ndarray, *, correlation_px: int = 1, min_angle_deg: float = 0.0) -> list:
    """The planes of the faces the region ``idx`` (flat pixels, increasing) that no model
    fitted (``model`` a :class:`~rangeseg_o3d.fitting.primitives.FitFailure`) holds,
    ``[(pixels, plane)]``; empty when it holds no faces a crease line separates.

    A region whose plane along the rays fits it within its range noise over its independent
    returns (:func:`_within_noise_along_rays`) is one face. A region a cylinder fits (on an
    even subsample of CYLINDER_TEST_PIXELS pixels) is judged
    as that cylinder's region (:func:`faces_of_curved`): a far pipe the fitter refused cut
    into facets would fit them within the noise (four facets at 2.5 m, two at 4 m, in the
    tests), and the misfit patterns keep it whole.

    On a stereo camera two or three faces of a far box, or a box's face and the wall behind
    it, can come out of the tile grid as one region no single model explains (study seed 29
    scans 1 and 3 of the stereo row: 11 808 px over two faces, 3090 px over three), and the
    region is left unlabelled. Its pixels are cut along their crease line (:func:`crease_line`)
    when the two sides' planes along the rays beat one plane by the F-test over the region's
    independent returns (``correlation_px`` squared pixels each), and each side beyond its
    range noise is cut once more the same way (:func:`_cut_again`); each leaf's largest
    connected piece keeps its plane along the rays, pieces continuing one another's plane
    joined (:func:`_join_continued`). Taken when two or more pieces of ``ctx.min_size`` remain
    and the leaves' planes hold PLANES_COVER of the region's pixels within TRIM_SIGMAS of
    their range noise (:func:`_leaf_faces`)."""
    from .fitting.cylinder import fit_cylinder

    if not isinstance(model, FitFailure):
        return []
    window = float(max(int(correlation_px), 1)) ** 2
    if _within_noise_along_rays(ctx, idx, window):
        return []  # one face (a cylinder fitted over it would lose to two planes' patterns)
    cylinder = fit_cylinder(ctx.xyz[idx[:: max(1, idx.size // CYLINDER_TEST_PIXELS)]])
    if isinstance(cylinder, Cylinder):
        return faces_of_curved(ctx, cylinder, idx, correlation_px=correlation_px, min_angle_deg=min_angle_deg)
    sides = _cut_again(ctx, idx, window, min_angle_deg)
    if len(sides) < 2:
        return []
    leaves = [leaf for side in sides for leaf in _cut_again(ctx, side, window, min_angle_deg)]
    surfaces, near, _ = _leaf_faces(ctx, leaves)
    if len(surfaces) < 2 or near < PLANES_COVER * idx.size:
        return []
    return surfaces


def _leaf_faces(ctx, leaves: list) -> tuple:
    """``(surfaces, near, squares)`` of the pixel sets ``leaves``: each one's plane fitted
    along the rays with its largest connected piece, ``[(pixels, plane)]`` (pieces under
    ``ctx.min_size`` left out; pieces continuing one another's plane joined:
    :func:`_join_continued`), the count of the leaves' pixels within TRIM_SIGMAS of their
    range noise of their leaf's plane along the rays, and those pixels' summed squares in
    noise units."""
    near, within, surfaces = 0, 0.0, []
    for leaf in leaves:
        rays, inverse, weight = ray_terms(ctx.xyz[leaf], ctx.sigma[leaf])
        _, a = ray_fits(ray_moments(rays, inverse, weight))
        z = (inverse - rays @ a[0]) ** 2 * weight
        kept = z <= TRIM_SIGMAS * TRIM_SIGMAS
        near += int(np.count_nonzero(kept))
        within += float(np.sum(z[kept]))
        piece = np.sort(ctx.largest_piece(leaf))
        plane = ray_plane(a[0], ctx.xyz[piece]) if piece.size >= ctx.min_size else None
        if plane:
            surfaces.append((piece, plane))
    return _join_continued(ctx, surfaces), near, within


def _join_continued(ctx, surfaces: list) -> list:
    """``surfaces`` (``[(pixels, plane)]``) with the pieces that continue one another's plane
    joined, the closest pair first: the plane fitted along the rays to both raises their
    chi-square by less than one per pixel of the smaller (:func:`_continued_plane`'s rule).
    A crease line through the middle of three faces leaves the middle one's halves on its two
    sides, each cut off again as a leaf of its own."""
    moments = [pixel_moments(ctx.xyz, ctx.sigma, piece) for piece, _ in surfaces]
    squares = [float(ray_fits(m)[0][0]) for m in moments]
    while len(surfaces) > 1:
        best, pair = 0.0, None
        for i in range(len(surfaces)):
            for j in range(i + 1, len(surfaces)):
                union = tuple(x + y for x, y in zip(moments[i], moments[j]))
                fitted = ray_fits(union)
                growth = float(fitted[0][0]) - squares[i] - squares[j]
                budget = min(surfaces[i][0].size, surfaces[j][0].size)
                if growth < budget and (pair is None or growth / budget < best):
                    best, pair = growth / budget, (i, j, union, fitted)
        if pair is None:
            break
        i, j, union, (chi2, a) = pair
        pixels = np.union1d(surfaces[i][0], surfaces[j][0])
        plane = ray_plane(a[0], ctx.xyz[pixels])
        if not plane:
            break
        surfaces = [s for k, s in enumerate(surfaces) if k not in (i, j)] + [(pixels, plane)]
        moments = [m for k, m in enumerate(moments) if k not in (i, j)] + [union]
        squares = [q for k, q in enumerate(squares) if k not in (i, j)] + [float(chi2[0])]
    return surfaces


def _curved_residuals(model, points: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Per point, its range minus the range at which its ray meets the cylinder or sphere
    ``model`` (the nearer crossing; where the ray passes by, its closest approach:
    :func:`~rangeseg_o3d.fitting.primitives.front_along_rays`), in units of the range noise
    ``sigma``: the model's residuals along the rays, in the units of the planes'
    (:func:`~rangeseg_o3d.ray_planes.ray_terms`)."""
    _, ranges, front, _ = front_along_rays(model, points)
    return (ranges - front) / np.maximum(sigma, 1e-12)


def share_near_curved(ctx, model, idx: np.ndarray) -> float:
    """The share of the flat pixels ``idx`` whose residuals along the rays to the cylinder or
    sphere ``model`` lie within TRIM_SIGMAS of their range noise: the curved model's share of
    :func:`misfit_patterns`' inliers, without its crease-line search (a cheap first test)."""
    residuals = _curved_residuals(model, ctx.xyz[idx], ctx.sigma[idx])
    return float(np.count_nonzero(np.abs(residuals) <= TRIM_SIGMAS)) / max(idx.size, 1)


def misfit_patterns(ctx, model, idx: np.ndarray, correlation_px: int) -> tuple:
    """``(curved, planes, inliers, squares, sides)`` of the flat pixels ``idx`` (increasing) under
    the cylinder or sphere ``model`` (a curved region's, or the model of two plane regions:
    :mod:`rangeseg_o3d.curved_pairs`):
    the chi-squares over PATTERN_BINS equal-count bins across the best crease line
    (:func:`crease_line`) of the mean residuals along the rays of the curved ``model`` and
    of the two sides' planes (each bin's mean in units of its noise over its independent
    returns, residuals clipped at 10 sigmas: a few mixed pixels do not make a pattern), each
    model's share of pixels within TRIM_SIGMAS and their mean squared residual, and the two
    sides; None when no line is."""
    chi2, sides, order = crease_line(ctx, idx, with_order=True)
    if order is None:
        return None
    points, noise = ctx.xyz[idx], ctx.sigma[idx]
    rays, inverse, weight = ray_terms(points, noise)
    planes = np.empty(idx.size)
    size = sides[0].size
    for part in (order[:size], order[size:]):
        _, a = ray_fits(ray_moments(rays[part], inverse[part], weight[part]))
        planes[part] = (inverse[part] - rays[part] @ a[0]) * np.sqrt(weight[part])
    curved = _curved_residuals(model, points, noise)
    share = 1.0 / float(max(int(correlation_px), 1)) ** 2
    out = []
    for z in (curved, planes):
        bins = np.array_split(np.clip(z, -10.0, 10.0)[order], PATTERN_BINS)
        out.append(share * float(sum(b.size * float(np.mean(b)) ** 2 for b in bins)))
    near = [np.abs(z) <= TRIM_SIGMAS for z in (curved, planes)]
    inliers = tuple(float(np.mean(m)) for m in near)
    squares = tuple(float(np.mean(z[m] ** 2)) if m.any() else np.inf for z, m in zip((curved, planes), near))
    return out[0], out[1], inliers, squares, sides


def _two_planes_win(patterns, cover: float = PLANES_COVER) -> bool:
    # the cylinder's misfit pattern beyond the planes' by PATTERN_RATIO, the planes holding
    # ``cover`` (PLANES_COVER) of the pixels within TRIM_SIGMAS (two faces, not the bits of
    # several surfaces a region over a far clutter holds, which the later splits sort out) and
    # at least the cylinder's share, closer on them
    if patterns is None:
        return False
    curved, planes, inliers, squares, _ = patterns
    return (curved > PATTERN_RATIO * planes and inliers[1] >= max(inliers[0], cover)
            and squares[1] <= squares[0])


def faces_of_curved(ctx, model, idx: np.ndarray, *, correlation_px: int = 1, min_angle_deg: float = 0.0) -> list:
    """The planes of two faces of a box the cylinder region ``idx`` (flat pixels, increasing)
    of ``model`` holds, ``[(pixels, plane)]``; empty when it is the curved surface. A sphere region
    is asked the same (its residuals along the rays: :func:`_curved_residuals`): at 5-6 m the
    tile means of a box's three faces fit a sphere within their noise (kinect_real_640x480
    seed 1105 scan 0: 4873 px, r 0.45 m; stereo_1280x720 seed 1104 scan 2: 2667 px, r 0.33 m).
    A sphere region that one plane along the rays explains within its range noise
    (:func:`_within_noise_along_rays`) is one face, and left whole: two planes across any line
    beat a sphere's misfit pattern on a single face as well (kinect_real seed 1106 scan 1).

    Far away, a box's corner and a pipe are alike to a stereo camera's tile means (a
    cylinder bends over the crease within the range noise), and a right pipe may fit its
    cylinder no better than two planes (the pipe's model comes from the tile means, and the
    noise errs together over streaks longer than its matching window): the chi-square of
    either model does not tell them apart. The patterns of their misfits do. Across the
    best crease line (:func:`crease_line`), a cylinder over two faces misses the crease
    and the far edges the same way along whole bands, and two planes over a pipe its arc;
    the wrong model's pattern is many times the right one's, and both carry the same noise.
    The two planes are taken when the cylinder's pattern exceeds theirs by PATTERN_RATIO (an
    F-test of the two patterns), they hold PLANES_COVER of the pixels within TRIM_SIGMAS and
    at least the cylinder's share, and fit those closer (a pipe with the edge of its cap: the planes leave the
    cap's pixels far off), first on an even subsample of CYLINDER_TEST_PIXELS pixels, then on
    every pixel. The sides' largest pieces must take PLANES_COVER of the region with planes
    at least ``min_angle_deg`` apart (:func:`_faces_of_sides`).
    """
    if not isinstance(model, (Cylinder, Sphere)):
        return []
    if isinstance(model, Sphere) and _within_noise_along_rays(ctx, idx, float(max(int(correlation_px), 1)) ** 2):
        return []  # one face (above)
    sample = idx[:: max(1, idx.size // CYLINDER_TEST_PIXELS)]
    # the gate without the cover: a side of the line may hold two faces (_faces_of_leaves)
    patterns = misfit_patterns(ctx, model, sample, correlation_px)
    if not _two_planes_win(patterns, cover=0.0):
        return []
    if sample.size < idx.size:
        patterns = misfit_patterns(ctx, model, idx, correlation_px)
    if not _two_planes_win(patterns):
        if _two_planes_win(patterns, cover=0.0):
            return _faces_of_leaves(ctx, idx, patterns, correlation_px, min_angle_deg)
        return []
    surfaces = _faces_of_sides(ctx, idx, patterns[-1], min_angle_deg)
    if len(surfaces) < 2 or sum(piece.size for piece, _ in surfaces) < PLANES_COVER * idx.size:
        return []
    return surfaces


def _faces_of_leaves(ctx, idx: np.ndarray, patterns: tuple, correlation_px: int, min_angle_deg: float) -> list:
    """The planes of three or four faces the cylinder region ``idx`` holds, ``[(pixels,
    plane)]``, when the two planes across its crease line (``patterns``: :func:`misfit_patterns`)
    beat the cylinder's misfit pattern but hold less than PLANES_COVER of its pixels within
    TRIM_SIGMAS: a side of the line holds two faces. Each side beyond its range noise along
    the rays over its independent returns (:func:`_within_noise_along_rays`) is cut again by
    its own crease line when the two planes beat its one by the F-test over those returns and
    meet at least ``min_angle_deg`` apart; each leaf's largest connected piece keeps its plane
    along the rays (the other pieces are left free, as :func:`_faces_of_sides` leaves them),
    and pieces that continue one another's plane are joined (:func:`_join_continued`).
    Taken when three or more leaves are cut, two or more pieces of ``ctx.min_size`` remain,
    and the leaves' planes hold PLANES_COVER of the region's pixels within TRIM_SIGMAS, at
    least the cylinder's share, closer on them than the cylinder; empty otherwise. (The pieces need not take
    PLANES_COVER of the region: a face cut by the region's border into bits under the size
    floor, 181 of seed 7 scan 1's 1551 px, would refuse a split its planes explain.)

    A far box's corner beside a pipe's end cap (a grazing face, a head-on face and the cap)
    comes out of the tile grid as one cylinder region whose misfit pattern is a hundred
    times the two planes' (study seed 7 scans 1 and 3 of the stereo row), yet the two
    planes hold 75-90 % of it: one plane spans two faces."""
    _, _, inliers, squares, sides = patterns
    window = float(max(int(correlation_px), 1)) ** 2
    leaves = []
    for side in sides:
        leaves.extend(_cut_again(ctx, side, window, min_angle_deg))
    if len(leaves) < 3:
        return []
    surfaces, near, within = _leaf_faces(ctx, leaves)
    share = near / idx.size
    if len(surfaces) < 2 or share < max(PLANES_COVER, inliers[0]) or within / max(near, 1) > squares[0]:
        return []
    return surfaces


def _cut_again(ctx, side: np.ndarray, window: float, min_angle_deg: float) -> list:
    """``[side]``, or its two sides along its own crease line (:func:`crease_line`) when it
    is beyond its range noise along the rays over its independent returns (``window`` pixels
    each) and the two sides' planes beat its one by the F-test over those returns, at least
    ``min_angle_deg`` apart (:func:`_faces_of_leaves`)."""
    if _within_noise_along_rays(ctx, side, window):
        return [side]
    chi2, halves = crease_line(ctx, side)
    if len(halves) != 2:
        return [side]
    (one,), _ = ray_fits(pixel_moments(ctx.xyz, ctx.sigma, side))
    if not curvature_resolved(float(one) / window, chi2 / window, max(int(side.size / window), 1), 4):
        return [side]
    normals = []
    for half in halves:
        _, a = ray_fits(pixel_moments(ctx.xyz, ctx.sigma, half))
        normals.append(a[0] / max(float(np.linalg.norm(a[0])), 1e-300))
    if np.degrees(np.arccos(min(1.0, abs(float(normals[0] @ normals[1]))))) < min_angle_deg:
        return [side]
    return list(halves)


def claim_along_rays(cloud, labels: np.ndarray, fits: dict, stats, *, sigma: np.ndarray, min_size: int,
                     inlier_factor: float, correlation_px: int = 1):
    """Each plane region of at least ``min_size`` pixels seen near grazing (median incidence
    cosine under ``scales.GRAZING_COSINE``) takes the pixels beside it, free or of another
    plane region, that its plane fitted along the rays to its pixels
    (:func:`~rangeseg_o3d.ray_planes.ray_terms`, robustly:
    :func:`~rangeseg_o3d.ray_planes.robust_ray_plane`) meets within TRIM_SIGMAS of their range
    noise and nearer, in those units, than their own region's plane, connected to it through
    such pixels. A region whose plane along the rays is not seen near grazing, or which has
    none (:func:`~rangeseg_o3d.ray_planes.robust_ray_plane` found none; a band of a head-on wall
    under a tile model bent towards the rays) joins the plane region beside it that
    explains it along the rays (:func:`plane_beside`; ``correlation_px``: the side of the
    sensor's matching window, over which its range noise errs together); its pixels that
    region's plane leaves beyond TRIM_SIGMAS become free.
    Returns ``(labels, fits, stats)``: a region that claimed reported with the plane it
    claimed by (``fits`` a changed copy, without the regions that joined another), the
    regions changed measured again; the inputs when none is.

    A stereo camera's range noise spans a far box's top seen near grazing: its pixels beside
    the front face are within the noise of both planes, and a claim in distances over the
    range noise favours whichever plane is seen head-on (the grazing plane's distances are
    the range errors times its small cosine; its pixels' are not less noisy for that).
    Along the rays both planes are judged by one noise, the range's: a pixel goes to the
    face its ray meets nearer its range."""
    from scipy import ndimage

    from .scales import GRAZING_COSINE

    counts = stats.counts
    xyz, noise = cloud.xyz.reshape(-1, 3), sigma.ravel()
    planes = {k: m for k, m in fits.items() if isinstance(m, Plane) and 0 < k < counts.size and m.d != 0}
    grazing = []
    for k, idx in region_indices(labels, only=[k for k in planes if counts[k] >= min_size]).items():
        sample = idx[:: max(1, idx.size // FACE_TEST_PIXELS)]
        points = xyz[sample]
        cosine = np.abs(points @ planes[k].normal) / np.maximum(np.linalg.norm(points, axis=1), 1e-12)
        if float(np.median(cosine)) < GRAZING_COSINE:
            grazing.append((k, idx))
    if not grazing:
        return labels, fits, stats
    h, w = labels.shape
    out = np.array(labels, dtype=np.int32, order="C")
    # each plane region's plane along the rays, a = n / d (a row of NaN: no plane region)
    inverse_planes = np.full((counts.size, 3), np.nan)
    for j, m in planes.items():
        inverse_planes[j] = m.normal / m.d
    changed, along, joined = set(), {}, set()
    for k, idx in grazing:
        own = out.reshape(-1)[idx] == k
        idx = idx[own]
        if idx.size < min_size:
            continue
        rays, inverse, weight = ray_terms(xyz[idx], noise[idx])
        rows, cols = np.divmod(idx, w)
        # robust (its rim holds its neighbours' pixels), from its pixels alone: a tile model
        # of a thin grazing face may pass near the camera, no pixel within its noise
        found = robust_ray_plane(rays, inverse, weight, rows, cols)
        a = None if found is None else found[0]
        # the plane along the rays must be seen near grazing too: a region of a head-on wall
        # whose tile model was bent towards the rays refits to the wall's plane, and its
        # claims would only cut the wall in two; such a band of a wall whose own region's
        # plane explains it along the rays goes back to that region
        normal = None if a is None else a / max(float(np.linalg.norm(a)), 1e-300)
        if normal is None or float(np.median(np.abs(rays @ normal))) >= GRAZING_COSINE:
            wall, kept = plane_beside(out, k, idx, rays, inverse, weight, planes, correlation_px)
            if wall:
                flat = out.reshape(-1)
                flat[idx] = 0
                flat[idx[kept]] = wall
                changed |= {k, wall}
                joined.add(k)
            continue
        # the face may go on beyond the region along its length (the rest of a box's top
        # left free): its box grown by its own extent, at least CLAIM_REACH pixels
        down = max(CLAIM_REACH, int(np.ptp(rows)) + 1)
        across = max(CLAIM_REACH, int(np.ptp(cols)) + 1)
        r0, r1 = max(int(rows.min()) - down, 0), min(int(rows.max()) + down + 1, h)
        c0, c1 = max(int(cols.min()) - across, 0), min(int(cols.max()) + across + 1, w)
        box = out[r0:r1, c0:c1]
        # compiled, one pass over the box: each pixel's distance along its ray to both planes
        # (numpy's form, a mask and a gather a neighbouring region, cost 4-5 ms a stereo scan)
        eligible = box_claims(cloud.xyz[r0:r1, c0:c1], sigma[r0:r1, c0:c1], cloud.valid[r0:r1, c0:c1], box, k,
                              np.asarray(a, dtype=np.float64), inverse_planes, float(TRIM_SIGMAS))
        region = box == k
        grown = ndimage.binary_propagation(region, mask=region | eligible)
        taken = grown & ~region
        if taken.any():
            changed |= set(unique_ints(box[taken]).tolist()) | {k}
            box[taken] = k
            along[k] = a
    if not changed:
        return labels, fits, stats
    changed.discard(0)
    # a region that claimed is reported with the plane it claimed by, not its tile model
    # (which may pass near the camera): the result's model and its stats are that plane's
    fits = {k: m for k, m in fits.items() if k not in joined}
    flat = out.reshape(-1)
    for k, a in along.items():
        plane = ray_plane(a, rows_at(xyz, np.flatnonzero(flat == k)))  # a gather: a third of a mask's time
        if plane is not None:
            fits[k] = plane
    stats = region_stats(cloud.xyz, out, fits, sigma, inlier_factor, known=stats, stale=changed)
    return out, fits, stats


def plane_beside(labels: np.ndarray, k: int, idx: np.ndarray, rays: np.ndarray, inverse: np.ndarray,
                 weight: np.ndarray, planes: dict, correlation_px: int) -> tuple:
    """``(label, kept)``: of the plane regions (``planes``: label -> Plane) touching region
    ``k`` of ``labels`` (its flat pixels ``idx``, their
    :func:`~rangeseg_o3d.ray_planes.ray_terms`), the one whose plane keeps
    ``strips.EXPLAINED_SHARE`` of them within TRIM_SIGMAS of their range noise along the rays
    with the least mean square of those, that mean square within the chi-square bound of their
    independent returns (``correlation_px`` squared pixels each), and the mask of the pixels it
    keeps; ``(0, None)`` when none does (``k`` 0: any region touching ``idx`` is asked).

    A thin band of a far head-on wall beside what stands before it can come out of the tile
    grid as a region of its own whose model lies along its rays (its pixels spread along
    them by a range noise larger than the band is wide): its pixels fit the wall's plane
    along the rays within their noise, and are that wall."""
    from .kernels.linalg import noise_rms_bound

    share = 1.0 / float(max(int(correlation_px), 1)) ** 2
    best, label, mask = np.inf, 0, None
    for other, kept, mean_square in planes_keeping(labels, k, idx, rays, inverse, weight, planes):
        n = int(np.count_nonzero(kept))
        if mean_square <= noise_rms_bound.py_func(1.0, share * n, CHI_SQUARE_SIGMAS) ** 2 and mean_square < best:
            best, label, mask = mean_square, other, kept
    return label, mask


def planes_keeping(labels: np.ndarray, k: int, idx: np.ndarray, rays: np.ndarray, inverse: np.ndarray,
                   weight: np.ndarray, planes: dict):
    """Yields ``(label, kept, mean_square)`` for each plane region (``planes``: label -> Plane)
    touching region ``k`` of ``labels`` (its flat pixels ``idx``, their
    :func:`~rangeseg_o3d.ray_planes.ray_terms`) whose plane keeps ``strips.EXPLAINED_SHARE`` of
    them within TRIM_SIGMAS of their range noise along the rays: the mask of those and the
    mean of their squares in units of that noise (:func:`plane_beside`'s candidates)."""
    from .strips import EXPLAINED_SHARE

    for other in sorted(touching(labels, idx, 1) - {0, k}):
        if other not in planes:
            continue
        squares = weight * (inverse - rays @ (planes[other].normal / planes[other].d)) ** 2
        kept = squares <= TRIM_SIGMAS * TRIM_SIGMAS
        if np.count_nonzero(kept) < EXPLAINED_SHARE * idx.size:
            continue
        yield other, kept, float(np.mean(squares[kept]))


def join_pieces_along_rays(cloud, labels: np.ndarray, fits: dict, stats, *, sigma: np.ndarray,
                           inlier_factor: float, correlation_px: int = 1):
    """Each plane region joins the larger plane region beside it whose plane explains it along
    the rays (:func:`plane_beside`: :data:`strips.EXPLAINED_SHARE` of its pixels within
    TRIM_SIGMAS of their range noise, their mean square within the chi-square bound of their
    independent returns, ``correlation_px`` squared pixels each); its pixels that plane leaves
    beyond TRIM_SIGMAS become free. Regions are asked from the smallest up, on the labels as
    the joins before left them. Returns ``(labels, fits, stats)``, the regions that joined
    gone from ``fits`` and the regions changed measured again; the inputs when none joins.

    A stereo camera's tile means beside a curved or near object (a pipe, a ball) average it
    with the wall behind, and the wall's pixels there come out as a plane region of their own
    whose model is turned from the wall's by the mean's error: no angle test joins it, while
    along the rays, the noise's own direction, the wall's plane explains its pixels. Such a
    piece of a far head-on wall, a few hundred to a few thousand pixels, makes the wall count
    as over-segmented. A face of its own, even parallel to the wall a few range sigmas in
    front, leaves a mean square beyond the bound over its independent returns and stays."""
    counts = stats.counts
    xyz, noise = cloud.xyz.reshape(-1, 3), sigma.ravel()
    planes = {k: m for k, m in fits.items() if isinstance(m, Plane) and 0 < k < counts.size and m.d != 0}
    if len(planes) < 2:
        return labels, fits, stats
    share = 1.0 / float(max(int(correlation_px), 1)) ** 2
    out = np.array(labels, dtype=np.int32, order="C")
    flat = out.reshape(-1)
    indices = region_indices(out, only=list(planes))
    size = {k: idx.size for k, idx in indices.items()}
    changed, joined = set(), set()
    for k in sorted(indices, key=lambda j: (size[j], j)):
        if k in joined:
            continue
        # its pixels are still its own: a join relabels only the joining region's pixels, and
        # a region that joined is not asked again (the mask of them cost a gather of every
        # plane region's pixels, ~1.5 ms a stereo scan, and never removed one)
        idx = indices[k]
        larger = {j: m for j, m in planes.items() if j not in joined and j != k and size.get(j, 0) > idx.size}
        if not larger:
            continue
        beside = touching(out, idx, 1)  # once: inside the filter it was searched again for every larger region
        larger = {j: m for j, m in larger.items() if j in beside}
        if not larger:
            continue
        # first on an even subsample (its fewer returns get a looser bound): most regions beside
        # a larger plane are other surfaces, and the gate spares their every pixel's terms
        sample = idx[:: max(1, idx.size // FACE_TEST_PIXELS)]
        if sample.size < idx.size and not _explained_along_rays(xyz[sample], noise[sample], larger, share):
            continue
        rays, inverse, weight = ray_terms(xyz[idx], noise[idx])
        wall, kept = plane_beside(out, k, idx, rays, inverse, weight, larger, correlation_px)
        if not wall:
            continue
        flat[idx] = 0
        flat[idx[kept]] = wall
        size[wall] += int(np.count_nonzero(kept))
        changed |= {k, wall}
        joined.add(k)
    if not joined:
        return labels, fits, stats
    fits = {k: m for k, m in fits.items() if k not in joined}
    stats = region_stats(cloud.xyz, out, fits, sigma, inlier_factor, known=stats, stale=changed)
    return out, fits, stats


def _explained_along_rays(points: np.ndarray, sigma: np.ndarray, planes: dict, share: float) -> bool:
    """Whether one of ``planes`` (label -> Plane) keeps :data:`strips.EXPLAINED_SHARE` of
    ``points`` within TRIM_SIGMAS of their range noise ``sigma`` along the rays with a mean
    square within the chi-square bound of ``share`` independent returns a kept point
    (:func:`plane_beside`'s test, without the search for touching regions)."""
    from .kernels.linalg import noise_rms_bound
    from .strips import EXPLAINED_SHARE

    rays, inverse, weight = ray_terms(points, sigma)
    for plane in planes.values():
        squares = weight * (inverse - rays @ (plane.normal / plane.d)) ** 2
        kept = squares <= TRIM_SIGMAS * TRIM_SIGMAS
        n = int(np.count_nonzero(kept))
        if n >= EXPLAINED_SHARE * points.shape[0] and float(np.mean(squares[kept])) <= noise_rms_bound.py_func(
                1.0, share * n, CHI_SQUARE_SIGMAS) ** 2:
            return True
    return False
