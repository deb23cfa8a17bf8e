"""What every refinement step needs (points, noise, the fitter, the size floor) and the
connected-piece helpers that split and recover share."""

from __future__ import annotations

import numpy as np

from .._numeric import rows_at

# The kernels package, not its names: importing it loads no compiler (each name loads on first
# use, PEP 562), and an attribute look-up costs a fraction of a from-import in each call (the
# piece helpers below run a few hundred times a frame)
from .. import kernels
from ..fitting.plane import fit_plane
from ..fitting.region_fitter import RegionFitter
from ..fitting.robust import (CHI_SQUARE_SIGMAS, ROUNDS, beyond_noise, distance_noise, distinct_masks, local_seeds,
                               trimmed_fit)
from ..kernels.linalg import noise_rms_bound

__all__ = ["Context", "returns_across", "touching", "without"]


def without(pool: np.ndarray, piece: np.ndarray) -> np.ndarray:
    """The pixels of ``pool`` not in ``piece``, both increasing, ``piece`` a subset of ``pool``
    (``pool[~np.isin(pool, piece)]`` by a binary search of the few, not a sort of all)."""
    keep = np.ones(pool.size, bool)
    keep[np.searchsorted(pool, piece)] = False
    return pool[keep]


def returns_across(idx: np.ndarray, width: int) -> float:
    """How many returns across the flat pixels ``idx`` of a grid ``width`` columns wide
    span: the smaller of the median counts of their pixels per row and per column (a line
    along a limb: 1)."""
    rows, cols = np.divmod(np.asarray(idx, dtype=np.int64), int(width))
    per_row, per_col = np.bincount(rows), np.bincount(cols)
    return float(min(np.median(per_row[per_row > 0]), np.median(per_col[per_col > 0])))


def touching(labels: np.ndarray, idx: np.ndarray, reach: int) -> set[int]:
    """The labels within ``reach`` pixels (rows and columns) of the flat pixels ``idx``
    (increasing), in one compiled pass over their rows' runs (:func:`rangeseg_o3d.kernels.labels_near`)."""
    return set(kernels.labels_near(np.ascontiguousarray(labels), np.ascontiguousarray(idx, dtype=np.int64),
                                   int(reach)).tolist())


#: Inliers whose largest 4-connected piece holds less than this share of them are not one
#: piece of a surface (the model is refitted to the piece, or searched for again).
_ONE_PIECE = 0.9
#: A trimmed search's answer holding less than this share of its pool may be a minority
#: surface the global proposals locked onto (a small face beside a ball): the local starts
#: are asked too, and an answer of theirs holding more of the pool wins.
DOMINANT_SHARE = 0.5
#: A pool whose distances to its plane carry less than this share of the range noise (its
#: median; seen more than 60 degrees from head-on) is searched again at that distance noise.
_GRAZING_NOISE = 0.5
#: A point within this many sigmas of its distance noise lies on the plane (refinement.context
#: and recover.py's trims of a plane's pixels).
TRIM_SIGMAS = 3.0
#: The least share of a curved answer's pixels the face found at the noise of its distances
#: must hold to replace it (:meth:`Context.dominant_search`): one of three faces at a corner.
FACE_SHARE = 1.0 / 3.0
#: Relative widening of the refinement steps' compiled screens and float pretests (facets,
#: recover, merge, polish, dissolve): each bound is widened by this much of itself (and of
#: its terms' magnitudes) on the safe side, far above the rounding by which a few float64
#: operations in another order differ from numpy's (~1e-15 relative), far below any noise,
#: so a screen says "nothing to do" only where the step's own numpy test surely finds nothing.
SCREEN_SLACK = 1e-9
#: The most pixels :meth:`Context._start_pieces` searches (its starts see every one): a bound
#: on its cost (one core of a 2.1 GHz Xeon: 7.3 ms on a pool of 5878 px; on a coarser grid,
#: 22 ms on a pool of 17196 px, :func:`lattice_stride`). It was 4000 at first:
#: then nodding_0.5deg seed 1034 scan 1, a column half sunk into a box face and the box's top
#: and two sides leaking into one 5878-px region, stayed unfitted (four surfaces missed).
_START_POOL_MAX = 16000
#: Local starts per pool (as :func:`rangeseg_o3d.fitting.robust.trimmed_fit`'s).
_LOCAL_STARTS = 8
# The noise bands (in the pool's sigmas) _start_pieces runs the local proposals at, in turn.
# At the range noise a column's proposal holds, within its three sigmas, a strip of the face
# beside it along their corner and of the floor below (20 mm noise: 6 cm either side), which
# lifts its cylinder over the noise; at half of it the strip is narrower than the column's
# own spread and the fitter takes the column (noise_20mm seed 1010 scan 6: a column of 630
# returns and the box face beside it left in no region).
_START_BANDS = (1.0, 0.5)
#: No pixels taken (:meth:`Context.pieces`).
_NO_PIXELS = np.zeros(0, np.int64)


def lattice_stride(size: int) -> int:
    """The grid step of :meth:`Context._start_pieces`' starts on a pool of ``size`` pixels:
    1 up to ``_START_POOL_MAX``, else the least step whose coarser grid (every step-th row
    and column) holds about that many of them."""
    return 1 if size <= _START_POOL_MAX else int(np.ceil(np.sqrt(size / _START_POOL_MAX)))


class _Starts:
    """The pixels of a pool the local starts run on: all of them (``stride`` 1), or those on
    every ``stride``-th row and column, numbered on that coarser grid for their connectivity;
    with ``wrap_columns`` (a 360-degree grid) its first and last columns are neighbours, as
    the pool's own grid's are."""

    def __init__(self, pool: np.ndarray, width: int, stride: int, wrap_columns: bool = False):
        self.stride = stride
        if stride == 1:
            self.pool, self.positions = pool, None
            return
        rows, cols = np.divmod(pool, width)
        #: where the starts' pixels are in the pool
        self.positions = np.flatnonzero((rows % stride == 0) & (cols % stride == 0))
        self.pool = pool[self.positions]
        self._coarse_width = -(-width // stride)
        self._wrap = bool(wrap_columns) and self._coarse_width > 2
        # the pool increases, and so do these (row-major on both grids)
        self._coarse = (rows[self.positions] // stride) * self._coarse_width + cols[self.positions] // stride

    def largest_piece(self, near: np.ndarray) -> np.ndarray:
        """The pool's pixels (flat, on its own grid) of the largest 4-connected piece, on the
        coarser grid, of the starts' pixels ``near`` (a mask over them)."""
        coarse = np.ascontiguousarray(self._coarse[near], dtype=np.int64)
        piece = _largest_piece(coarse, self._coarse_width, self._wrap)
        return self.pool[near][np.searchsorted(coarse, piece)]


class Context:
    """What every refinement step needs: points, noise, the fitter, the size floor."""

    def __init__(self, cloud, fitter: RegionFitter, sigma: np.ndarray, min_size: int, *,
                 wrap_columns: bool = False, grazing_search: bool = False, correlation_px: int = 1,
                 band_faces_only: bool = False, face_floor: int | None = None):
        if not (isinstance(correlation_px, (int, np.integer)) and correlation_px >= 1):
            raise ValueError(f"Context: correlation_px must be an integer >= 1; got {correlation_px!r}")
        if face_floor is not None and not (isinstance(face_floor, (int, np.integer)) and face_floor >= 1):
            raise ValueError(f"Context: face_floor must be an integer >= 1 or None; got {face_floor!r}")
        self.xyz = cloud.xyz.reshape(-1, 3)
        self.sigma = sigma.ravel()
        self.width = cloud.shape[1]
        self.fitter = fitter
        self.min_size = min_size
        #: a 360-degree grid: the first and last columns are neighbours
        self.wrap_columns = bool(wrap_columns) and self.width > 2
        #: search a pool seen near grazing again at the noise of its distances
        #: (:meth:`dominant_piece`); the pixels of a frame a tile grid lost only: on the tile
        #: grid the search took a column's flank, its tile means within that noise of a
        #: plane, as a plane piece beside the column (stereo seed 0 scan 0)
        self.grazing_search = bool(grazing_search)
        #: the pixels' range noise errs together over ``correlation_px`` pixels square (a
        #: stereo camera's matching window, the sensor's ``noise.correlation_px``; 1 on a tile
        #: grid, whose means are left as independent): :meth:`plane_along_rays` counts its
        #: chi-square's degrees of freedom over the independent returns
        self.correlation_px = int(correlation_px)
        #: the one-sigma face band (:meth:`dominant_search` with ``face_band``) asked for
        #: faces only: its last resort, the local starts' pieces (a curved model or a plane),
        #: is not tried, and after the band found a face of a pool's region a curved answer
        #: must lie within the noise of its distances (``after_band``). The pixels of a frame
        #: the tile grid lost: there the search after the band made a curved region of pixels
        #: strewn along the rays (pcl_office1: a cylinder of r 0.37 m found on 1085 px from 3.5
        #: to 5.6 m, 22.7 mm rms where the noise of its distances is 1.8 mm; 1177 px in the end),
        #: and the starts new cylinders on the 3DTK scans (116-278 px, r 0.47-0.69 m; no truth)
        self.band_faces_only = bool(band_faces_only)
        #: the fewest pixels of a face found at the noise of its distances in place of a curved
        #: answer beyond that noise (:meth:`_face_at_distance_noise`); ``min_size`` when not given
        self.face_floor = min_size if face_floor is None else int(face_floor)
        self._cloud = cloud
        self._row_origins = False  # not looked up yet (most steps never ask)

    @property
    def row_origins(self):
        """``(H, 3)`` each row's ray origin where the sensor's rays do not start at the
        origin (a nodding laser's mirror off its tilt axis), else None (:meth:`viewing_rays`)."""
        if self._row_origins is False:
            self._row_origins = _row_origins(self._cloud)
        return self._row_origins

    def viewing_rays(self, idx: np.ndarray) -> np.ndarray:
        """``(N, 3)`` unit rays of the flat pixels ``idx``, from where the sensor's rays start
        to each pixel's point: a nodding laser's mirror sits off its tilt axis (0.1 m on the
        LMS200), and a floor seen near grazing meets its rays 2-3 degrees less obliquely than
        the rays from the origin say (the LMS200 suite's floors: median incidence cosine
        0.19-0.22 where those give 0.16-0.19): what its range noise leaves its distances is
        a fifth more."""
        origins = self.ray_origins(idx)
        points = rows_at(self.xyz, idx) if origins is None else rows_at(self.xyz, idx) - origins
        return points / np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-12)

    def ray_origins(self, idx: np.ndarray):
        """``(N, 3)`` where the rays of the flat pixels ``idx`` start, or None where every
        ray starts at the origin (:attr:`row_origins`)."""
        return None if self.row_origins is None else rows_at(self.row_origins, np.asarray(idx) // self.width)

    def piece_ids(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(ids, sizes)`` of the 4-connected pieces of the flat pixels ``idx`` (increasing),
        as :func:`rangeseg_o3d.kernels.piece_ids` numbers them; on a 360-degree grid the
        pieces that meet across the seam are one (the first one's number; others' sizes 0)."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        ids, sizes = kernels.piece_ids(idx, self.width)
        if self.wrap_columns and idx.size:
            ids, sizes = _join_across_seam(idx, ids, sizes, self.width)
        return ids, sizes

    def largest_piece(self, idx: np.ndarray) -> np.ndarray:
        """The largest 4-connected piece of the flat pixels ``idx`` (inliers can be
        scattered over the grid; on a 360-degree grid across the seam too)."""
        return _largest_piece(np.ascontiguousarray(idx, dtype=np.int64), self.width, self.wrap_columns)

    def pieces(self, idx: np.ndarray, taken: np.ndarray | None = None) -> list[np.ndarray]:
        """The 4-connected pieces of the flat pixels ``idx`` (increasing) with at least
        ``min_size`` pixels, smallest first; with ``taken`` (increasing, among ``idx``),
        those of ``without(idx, taken)``."""
        if not self.wrap_columns:
            # one compiled call (the difference, the pieces, their order), not a handful of
            # small-array calls: a split asks it after each of its dozens of searches a frame
            if idx.size < self.min_size:
                return []
            pixels, bounds = kernels.pool_pieces(np.ascontiguousarray(idx, dtype=np.int64),
                                                 _NO_PIXELS if taken is None
                                                 else np.ascontiguousarray(taken, dtype=np.int64),
                                                 self.width, self.min_size)
            ends = bounds.tolist()
            return [pixels[a:b] for a, b in zip(ends[:-1], ends[1:])]
        if taken is not None:
            idx = without(idx, taken)
        if idx.size < self.min_size:
            return []
        ids, sizes = self.piece_ids(idx)
        # the pixels of each piece in idx's order: a counting sort of their piece numbers
        order, starts = kernels.group_by_label(ids, sizes.shape[0])
        # (a pool can hold thousands of pieces under the floor: they are skipped in numpy)
        big = np.flatnonzero(sizes >= self.min_size)
        pieces = [idx[order[a:b]] for a, b in zip(starts[big].tolist(), starts[big + 1].tolist())]
        return sorted(pieces, key=len)

    def dominant_piece(self, pool: np.ndarray, *, face_band: bool = False):
        """The largest connected piece of the dominant surface of the flat pixels ``pool``
        and its model, or ``(None, None)`` when no model explains ``min_size`` of them.
        With ``face_band``, a pool neither search explains gets one more try
        (:meth:`_face_in_noise`); :meth:`dominant_search` also tells whether that try found it.
        """
        piece, model, _ = self.dominant_search(pool, face_band=face_band)
        return piece, model

    def dominant_search(self, pool: np.ndarray, *, face_band: bool = False, after_band: bool = False):
        """``(piece, model, by_face_band)``: :meth:`dominant_piece`'s answer and whether the
        one-sigma face band found it (the face then holds a strip of its neighbour along
        the corner: :func:`rangeseg_o3d.refinement.split.split_regions` gives it back).
        ``after_band``: the band found a face of the region ``pool`` belongs to; with
        :attr:`band_faces_only` a curved answer beyond the noise of its distances
        (:meth:`curved_beyond_distance_noise`) then gives way to the band's face, or to none;
        otherwise, with :attr:`band_faces_only`, such an answer gives way to the face a
        search at that noise finds (:meth:`_face_at_distance_noise`) when the face holds at
        least :data:`FACE_SHARE` of it, and stands when not.

        When the trimmed fit's answer is no surface (nothing, or a model beyond the noise
        whose inliers are not one connected piece: the plane tangent to two columns
        standing on a floor takes a strip of each), the search starts again from local
        starts (:func:`rangeseg_o3d.fitting.robust.trimmed_fit` with ``starts``), whose
        answer at the noise replaces it; when what is left of the answer (the lost one, or the
        start's that replaced it) is no surface (its largest piece under the size floor, or a
        plane the fitter refuses on that piece), the pool is searched on as one without an
        answer (:meth:`_after_no_answer`: with ``face_band`` the one-sigma band, then the
        starts' pieces). A column against a box's face, their planes tangent, and the floor at
        their feet (nodding_0.5deg study seed 1461 scan 2, 5218 px) gave a plane over the face
        and a strip of the column, 7.9 mm rms under 5 mm of noise, which the fitter refused on
        its piece: the region was left unfitted, though the band holds the face and a start
        the column. When the answer holds less than :data:`DOMINANT_SHARE` of the pool, the
        local starts are searched too and their answer replaces it when it holds more of the
        pool: the global proposals can lock onto a small surface beside a ball when their
        quadric band straddles both (noise_2mm study seed 1424 scan 7: a ball of r 0.35 m at
        3 m, 106 returns in a blob with strips of the surfaces beside it, became three planes
        of about 20 returns that the release of grid lines then freed; a start on the ball
        finds it whole)."""
        if pool.size < self.min_size:
            return None, None, False
        noise = self.sigma[pool]
        sigma = float(np.partition(noise, noise.size // 2)[noise.size // 2])
        # the fitter's own compiled search when it has one (the same answer)
        found = (self.fitter.trimmed(self.xyz, pool, sigma=sigma, min_points=self.min_size)
                 if hasattr(self.fitter, "trimmed") else None)
        model, inliers = found if found is not None else trimmed_fit(
            self.xyz, self.fitter.fit, pool=pool, sigma=sigma, min_points=self.min_size)
        piece = None if model is None else self.largest_piece(pool[inliers])
        # (the inliers' count once: a bool array's sum goes through numpy's reduction each time)
        count = 0 if model is None else int(np.count_nonzero(inliers))
        lost = model is None or (piece.size < _ONE_PIECE * count and beyond_noise(model.rms, sigma, count))
        if lost or count < DOMINANT_SHARE * pool.size:
            found = (self.fitter.trimmed(self.xyz, pool, sigma=sigma, min_points=self.min_size, starts=True)
                     if hasattr(self.fitter, "trimmed") else None)
            local, near = found if found is not None else trimmed_fit(
                self.xyz, self.fitter.fit, pool=pool, sigma=sigma, min_points=self.min_size, starts=True)
            near_count = 0 if local is None else int(np.count_nonzero(near))
            # (a minority answer gives way only to a start's answer holding more of the pool)
            if local is not None and (lost or near_count > count):
                model, inliers, count = local, near, near_count
                piece = self.largest_piece(pool[inliers])
        if self.grazing_search and (model is None or piece.size < self.min_size
                                    or self.seen_along_rays(model, piece)):
            grazing = self.grazing_piece(pool, sigma, model)
            if grazing is not None:
                return (*grazing, False)
        if model is None:
            return self._after_no_answer(pool, sigma, face_band)
        # (after a lost answer, one that leaves no surface is no answer: see the docstring)
        if piece.size < self.min_size:
            return self._after_no_answer(pool, sigma, face_band) if lost else (None, None, False)
        if piece.size < _ONE_PIECE * count:  # a piece was cut off: fit the piece itself
            refit = self.fitter.refit(self.fitter.points(self.xyz, piece), model)
            if not refit and model.kind != "plane":
                return self._plane_after_curved(pool, sigma, face_band)
            if not refit and lost:
                return self._after_no_answer(pool, sigma, face_band)
            model = refit
        if after_band and self.band_faces_only and self.curved_beyond_distance_noise(model, piece):
            piece, model = self._face_in_noise(pool, sigma)
            return (piece, model, True) if piece is not None else (None, None, False)
        if self.band_faces_only and model and model.kind != "plane" and piece.size >= 3:
            # (the noise once, for the test and for the band of the face search)
            noise = distance_noise(model, rows_at(self.xyz, piece), self.sigma[piece])
            if self._beyond_distance_noise(model, piece, noise):
                face, plane = self._face_at_distance_noise(pool, float(np.median(noise)))
                # the curved answer's pixels mostly faces (a corner of two or three): a face of
                # less is a sliver beside a surface the model may well be (pcl_frame_laptop: a
                # cylinder of r 0.18 m on 795 px gave way to a plane of 85, and the rest to
                # another plane: 726 px fewer in the cylinder, 4 ms more to the frame)
                if face is not None and face.size >= FACE_SHARE * piece.size:
                    return face, plane, False
        return (piece, model, False) if model else (None, None, False)

    def seen_along_rays(self, model, piece: np.ndarray) -> bool:
        """:meth:`plane_along_rays` of a plane seen more than 60 degrees from head-on at the
        centre of its flat pixels ``piece`` (``_GRAZING_NOISE``); False for other planes and
        models without computing the noise (a plane facing the sensor keeps most of the
        range noise in its distances)."""
        if model.kind != "plane":
            return False
        centre = self.xyz[piece[:: max(1, piece.size // 64)]].mean(axis=0)
        cosine = abs(float(np.dot(model.normal, centre))) / max(float(np.linalg.norm(centre)), 1e-12)
        return cosine < _GRAZING_NOISE and self.plane_along_rays(model, piece)

    def grazing_piece(self, pool: np.ndarray, sigma: float, model):
        """``(piece, model)`` of the search of ``pool`` at the noise of its distances, or None.

        Faces seen near grazing (a box top far away) move their points along the rays by
        the range noise, off their plane by only its incidence cosine. A search whose band
        is three range-noise sigmas wide then takes two parallel faces a few centimetres
        apart, or a strip of each, as one plane: beyond the noise of its distances, or
        nothing the fitter accepts. When the pool's plane (``model`` when a plane, else its
        least-squares plane) leaves its distances less than ``_GRAZING_NOISE`` of the range
        noise, the pool is searched again with that distance noise as the band's sigma.
        """
        sample = pool[:: max(1, pool.size // 600)]  # the median of a few hundred is enough
        points = rows_at(self.xyz, sample)
        plane = (model if model is not None and model.kind == "plane"
                 else fit_plane(points[np.isfinite(points).all(axis=1)]))
        if not plane:  # a FitFailure: too few points, or all on a line
            return None
        narrow = float(np.median(distance_noise(plane, points, self.sigma[sample])))
        if not 0.0 < narrow < _GRAZING_NOISE * sigma:
            return None
        found = (self.fitter.trimmed(self.xyz, pool, sigma=narrow, min_points=self.min_size)
                 if hasattr(self.fitter, "trimmed") else None)
        model, inliers = found if found is not None else trimmed_fit(
            self.xyz, self.fitter.fit, pool=pool, sigma=narrow, min_points=self.min_size)
        if model is None or model.kind != "plane":  # a face is sought: a curved answer stays the first search's
            return None
        piece = self.largest_piece(pool[inliers])
        if piece.size < self.min_size:
            return None
        # each pixel held to the noise of its own distance (a strip of the next face across
        # a crease lies within the band's median noise and tilts the plane)
        piece, model = self.within_distance_noise(piece, model)
        return None if piece is None else (piece, model)

    def _after_no_answer(self, pool: np.ndarray, sigma: float, face_band: bool):
        # ``(piece, model, by_face_band)`` of :meth:`dominant_search` when neither trimmed search
        # answered with a surface: with ``face_band`` the one-sigma face band's, else (unless
        # faces only) the first local start's piece fitted at the noise (:meth:`_start_pieces`)
        if not face_band:
            return None, None, False
        piece, model = self._face_in_noise(pool, sigma)
        if piece is not None:
            return piece, model, True
        if self.band_faces_only:
            return None, None, False
        return (*self._start_pieces(pool, sigma), False)

    def _plane_after_curved(self, pool: np.ndarray, sigma: float, face_band: bool):
        # ``(piece, model, by_face_band)`` when a curved model took pieces apart and fits none
        # of them alone: the dominant plane (:meth:`_face_plane`), else, with ``face_band``, the
        # one-sigma face band's (:meth:`_face_in_noise`), as when no model was found. A pipe and
        # its end cap in one pool (spinning_64x1024 study seed 1181 scan 3: 244 + 232 px under
        # 15 mm of noise): the three-sigma band's plane lies along the pipe and takes a strip of
        # the cap, which the fitter refuses, while a band of one sigma holds the cap alone
        piece, model = self._face_plane(pool, sigma)
        if piece is not None or not face_band:
            return piece, model, False
        piece, model = self._face_in_noise(pool, sigma)
        return (piece, model, True) if piece is not None else (None, None, False)

    def _face_plane(self, pool: np.ndarray, sigma: float):
        # The largest connected piece of the dominant plane of ``pool`` (a planes-only trimmed
        # search) and the fitter's refit of the plane to it, or (None, None). Asked when a
        # curved model within the noise took pieces apart and fits none of them alone: on a
        # noisy sensor a wide cylinder bends over a box corner and the wall beside it (each
        # face's plane takes a band of its neighbours' pixels and so ranks below it)
        from ..fitting.classify import trimmed_plane

        plane, inliers = trimmed_plane(self.xyz, pool, sigma=sigma, min_points=self.min_size)
        if plane is None:
            return None, None
        piece = self.largest_piece(pool[inliers])
        if piece.size < self.min_size:
            return None, None
        model = self.fitter.refit(self.fitter.points(self.xyz, piece), plane)
        return (piece, model) if model else (None, None)

    def _start_pieces(self, pool: np.ndarray, sigma: float):
        """``(piece, model)`` of the first local start of ``pool`` whose proposal, cut to its
        largest 4-connected piece, the fitter accepts at the noise, grown to the largest
        connected piece of the pool within ``TRIM_SIGMAS`` of it and refitted; or (None, None).

        The last try of :meth:`dominant_search` at sensor resolution, when the trimmed
        searches and the one-sigma face band found nothing. The local starts' quadric
        (:func:`rangeseg_o3d.kernels.local_proposals`) spreads over its seed's surface, but
        its band also holds the few returns of other surfaces it crosses farther off (the
        floor below a column, a column beside it, 0.3-2 m from the surface): a handful of
        them lift a column's cylinder to twice the range noise and the fitter refuses it,
        while the surface's own returns fit at the noise. Those returns lie apart from the
        proposal's connected piece on the grid. Here the starts run on all of the pool's
        pixels (the search's subsample of a large pool is no grid), at most
        ``_START_POOL_MAX`` of them; a larger pool's starts run on a coarser grid of its pixels
        (every ``stride``-th row and column, :func:`lattice_stride`), each proposal cut to its
        largest piece on that grid, and only a surface grown on the pool's own grid and
        refitted at the noise is an answer. (noise_10mm seed 1032 scan 2: two columns of 568
        and 827 returns and a strip of floor, one region the segmenter could not fit, were
        freed whole; nodding_0.25deg seed 1036 scan 0: a box's top and sides and the floor
        beside it, 17196 px, were left in no region before the coarser grid.)"""
        if pool.size < 2 * self.min_size:
            return None, None  # (no room for two surfaces)
        stride = lattice_stride(pool.size)
        starts = _Starts(pool, self.width, stride, self.wrap_columns)
        if starts.pool.size < 2 * self.min_size:
            return None, None
        points = np.ascontiguousarray(rows_at(self.xyz, pool), dtype=np.float64)
        start_points = points if stride == 1 else np.ascontiguousarray(points[starts.positions])
        for band in _START_BANDS:
            found = self._start_piece(pool, points, starts, start_points, sigma, band * sigma)
            if found[0] is not None:
                return found
        return None, None

    def _start_piece(self, pool: np.ndarray, points: np.ndarray, starts: "_Starts", start_points: np.ndarray,
                     sigma: float, band: float):
        # _start_pieces with the local proposals' concentration run at the noise ``band``
        # (the fitter's answer still held to ``sigma``); ``start_points`` those of ``starts``
        on_grid = starts.stride == 1
        size = starts.pool.size
        proposals = kernels.local_proposals(start_points, float(band), int(ROUNDS), local_seeds(size, size),
                                            max(size // _LOCAL_STARTS, 6))
        for near in distinct_masks(proposals):
            piece = self.largest_piece(pool[near]) if on_grid else starts.largest_piece(near)
            if piece.size < self.min_size:
                continue
            model = self.fitter.fit(self.fitter.points(self.xyz, piece))
            if not model or beyond_noise(model.rms, sigma, piece.size):
                continue
            # the whole surface: the pool's returns near the model, in one connected piece
            grown = self.largest_piece(pool[np.abs(model.distances(points)) <= TRIM_SIGMAS * max(sigma, model.rms)])
            if grown.size > piece.size:
                refit = self.fitter.refit(self.fitter.points(self.xyz, grown), model)
                if refit and not beyond_noise(refit.rms, sigma, grown.size):
                    return grown, refit
            if on_grid:  # (a piece of the coarser grid is no region)
                return piece, model
        return None, None

    def _face_in_noise(self, pool: np.ndarray, sigma: float):
        # The dominant plane of ``pool`` found with a one-sigma band (:meth:`_face_at_band` at
        # sigma / 3), or (None, None). Two narrow faces meeting at a corner, a few noise sigmas
        # wide each: the best three-point plane by the search's three-sigma band is the diagonal
        # one through the corner, which takes most of both and which the fitter refuses; a band
        # of one sigma holds most of one face and only a strip of the other along the corner.
        return self._face_at_band(pool, sigma / 3.0, self.min_size)

    def _face_at_distance_noise(self, pool: np.ndarray, band: float):
        # ``(face, plane)`` of :meth:`_face_at_band` with ``band`` the median noise of a
        # cylinder's or sphere's distances to its piece of the pool (range noise x incidence
        # cosine), down to ``face_floor`` pixels; or (None, None). A far box's top and side
        # seen near grazing, a few pixels across each, lie within the range noise of a sphere
        # or cylinder bent over their edge (kinect study seed 1228 scan 5: a sphere of r 0.29 m
        # on 323 + 296 px at 4.1 m, 30 mm rms where the range noise is 25 mm), but each face's
        # plane fits it at 3-4 mm, the noise of its distances; a band of range noise holds both
        # faces whole, one of that noise one face
        return self._face_at_band(pool, band, self.face_floor, from_inliers=True)

    def _face_at_band(self, pool: np.ndarray, band: float, floor: int, *, from_inliers: bool = False):
        # ``(face, plane)``: the dominant plane of ``pool`` by a planes-only trimmed search of
        # noise ``band``, cut to its largest piece within the noise of its distances (of the
        # pool, or with ``from_inliers`` of the largest piece of the search's inliers) and
        # refitted (within_distance_noise), at least ``floor`` pixels; or (None, None)
        from ..fitting.classify import trimmed_plane

        plane, inliers = trimmed_plane(self.xyz, pool, sigma=band, min_points=floor)
        if plane is None:
            return None, None
        if from_inliers:
            pool = self.largest_piece(pool[inliers])
        piece, model = self.within_distance_noise(pool, plane, floor=floor)
        if piece is None or not model or model.kind != "plane":
            return None, None
        return piece, model

    def within_distance_noise(self, pool: np.ndarray, model, floor: int | None = None, *, refit: bool = True):
        # the largest connected piece of ``pool`` within TRIM_SIGMAS distance noises of the
        # plane ``model`` (range noise x incidence cosine), refitted, when it keeps the size
        # floor (``floor``, else min_size) and its refit plane explains it within that noise;
        # else (None, None). ``refit`` False: ``model`` kept (a plane fitted along the rays,
        # which the fitter's refit by distances would turn off a stereo camera's face)
        near = self._near_plane(pool, model) if model.kind == "plane" else None
        if near is None:  # (the test as numpy words it; the compiled pass could not tell)
            points = rows_at(self.xyz, pool)
            near = np.abs(model.distances(points)) <= TRIM_SIGMAS * distance_noise(model, points, self.sigma[pool])
        piece = self.largest_piece(pool[near])
        if piece.size < (self.min_size if floor is None else floor):
            return None, None
        if refit:
            model = self.fitter.refit(self.fitter.points(self.xyz, piece), model)
        if not model or self.plane_along_rays(model, piece):
            return None, None
        return piece, model

    def plane_along_rays(self, model, idx: np.ndarray) -> bool:
        """Whether ``model`` is a plane whose distances to the flat pixels ``idx`` are
        beyond the noise of those distances (the range noise times the incidence cosine,
        :func:`rangeseg_o3d.fitting.robust.distance_noise`; chi-square bound over the
        independent returns: :meth:`compact_piece_returns`).

        A band a few rows thick of any surface lies within the range noise of the plane
        through the viewing rays of its middle row: seen along its rays, that plane's
        distances carry almost none of the range noise, so the band's spread across the
        rays is what its rms measures. A true face, grazing or not, moves its points
        along the rays only, by the noise its incidence cosine leaves.
        """
        if not model or model.kind != "plane" or idx.size < 3:
            return False
        beyond = self._plane_beyond_noise(model, idx)
        if beyond is not None:
            return beyond
        return self._beyond_distance_noise(model, idx)

    def curved_beyond_distance_noise(self, model, idx: np.ndarray) -> bool:
        """Whether the cylinder or sphere ``model``'s distances to the flat pixels ``idx`` are
        beyond their noise (range noise moved along each pixel's ray,
        :func:`rangeseg_o3d.fitting.robust.distance_noise`; chi-square bound over the
        independent returns: :meth:`compact_piece_returns`), as :meth:`plane_along_rays` asks
        of a plane. Pixels strewn along their rays over metres lie within a cylinder's range
        noise when its axis runs along those rays, but its surface then takes their range
        noise at grazing incidence: almost none of it is left in its distances."""
        if not model or model.kind == "plane" or idx.size < 3:
            return False
        return self._beyond_distance_noise(model, idx)

    def _beyond_distance_noise(self, model, idx: np.ndarray, noise: np.ndarray | None = None) -> bool:
        # the rms of ``model``'s distances to the flat pixels ``idx`` beyond the rms of their
        # noise (robust.distance_noise; ``noise`` when the caller has it), by the chi-square
        # bound over their independent returns
        points = rows_at(self.xyz, idx)
        if noise is None:
            noise = distance_noise(model, points, self.sigma[idx])
        rms = float(np.sqrt(np.mean(model.distances(points) ** 2)))
        return beyond_noise(rms, float(np.sqrt(np.mean(noise * noise))), self.compact_piece_returns(idx.size))

    def compact_piece_returns(self, n: int) -> float:
        """The independent returns among the ``n`` pixels of a compact piece: ``n /
        correlation_px**2`` (as :func:`rangeseg_o3d.plane_faces.split_plane_faces` counts
        them), at least 1; :meth:`rangeseg_o3d.sensor.NoiseModel.independent_returns` counts
        them exactly for a given shape (a strip's are more), at a cost per call.

        A face under a camera whose returns err together over a window (kinect_real_640x480:
        9 px, and 1/8-px disparity steps) scatters its distances more than the noise of a
        return says over as many pixels: kinect_real seed 1069 scan 3, a face's blob plane of
        1988 px (1936 of them the face's) at 4.1 m fit them at 23.4 mm against 20.9 mm of
        distance noise (1.12 times, where the bound over every pixel allows 1.06), and was
        freed as a band seen along the rays."""
        return max(float(n) / (self.correlation_px * self.correlation_px), 1.0)

    def _plane_beyond_noise(self, plane, idx: np.ndarray):
        # plane_along_rays' answer from one compiled pass over the pixels (kernels.plane_noise_sums),
        # or None where the two rms lie within _ROUNDING of each other, so that numpy's
        # rounding could answer the other way (the rays from the origin, as distance_noise's)
        n = int(idx.size)
        squares, noise_squares, scale, sigma_max = kernels.plane_noise_sums(
            self._flat_xyz, self._flat_sigma, np.ascontiguousarray(idx, dtype=np.int64),
            np.ascontiguousarray(plane.normal, dtype=np.float64), float(plane.d))
        rms = float(np.sqrt(squares / n))
        bound = noise_rms_bound.py_func(float(np.sqrt(noise_squares / n)), self.compact_piece_returns(n),
                                        CHI_SQUARE_SIGMAS)
        # each distance is off numpy's by a few roundings of its terms (``scale``), each noise
        # by a few of ``sigma_max`` (the bound: under 2.3 noises); the sums by n roundings
        slack = _ROUNDING * (scale + 4.0 * sigma_max) + _RELATIVE * (rms + bound)
        if rms - bound > slack:
            return True
        if bound - rms > slack:
            return False
        return None  # (a NaN too)

    def _near_plane(self, idx: np.ndarray, plane):
        # whether each of the flat pixels idx lies within TRIM_SIGMAS noises of its distance of
        # the plane (kernels.plane_noise_near), or None where one pixel is within _ROUNDING of
        # that bound (numpy's rounding could tell it otherwise)
        near, unsure = kernels.plane_noise_near(
            self._flat_xyz, self._flat_sigma, np.ascontiguousarray(idx, dtype=np.int64),
            np.ascontiguousarray(plane.normal, dtype=np.float64), float(plane.d), TRIM_SIGMAS, _RELATIVE, _ROUNDING)
        return None if unsure else near

    @property
    def _flat_xyz(self) -> np.ndarray:
        return np.ascontiguousarray(self.xyz, dtype=np.float64)

    @property
    def _flat_sigma(self) -> np.ndarray:
        return np.ascontiguousarray(self.sigma, dtype=np.float64)


#: Margins about a bound within which the compiled passes of one plane's noise tests leave the
#: answer to numpy (:meth:`Context._plane_beyond_noise`, :meth:`Context._near_plane`): many times
#: the rounding of a few operations on the terms of a distance (float64's epsilon is 2.2e-16)
#: and of sums over up to a million pixels. Outside them both roundings answer alike.
_ROUNDING = 64 * np.finfo(np.float64).eps
_RELATIVE = 1e-9


def _row_origins(cloud):
    # (H, 3) ray origins of a nodding geometry with its mirror off the tilt axis and the
    # cloud's own grid; None where rays start at the origin (or the geometry is not known)
    from ..geometry import NoddingGeometry, nodding_ray_origins

    geometry = getattr(cloud, "geometry", None)
    if (not isinstance(geometry, NoddingGeometry) or geometry.shape != tuple(cloud.shape)
            or not np.any(geometry.mount_offset)):
        return None
    return nodding_ray_origins(geometry)


def _largest_piece(idx: np.ndarray, width: int, wrap_columns: bool) -> np.ndarray:
    # the largest 4-connected piece of the flat pixels ``idx`` (int64, increasing) of a grid
    # ``width`` columns wide, in increasing order; with ``wrap_columns`` the pieces meeting
    # across the seam are one (Context.largest_piece on the pool's grid, _Starts on the coarser)
    if not wrap_columns:
        return kernels.largest_piece(idx, width)
    ids, sizes = _join_across_seam(idx, *kernels.piece_ids(idx, width), width)
    return idx[ids == np.argmax(sizes)] if sizes.size else idx.copy()


def _join_across_seam(idx: np.ndarray, ids: np.ndarray, sizes: np.ndarray, width: int):
    # pieces with a pixel in the last column beside one of another piece in the first
    # column of the same row are one: each takes the smallest number of its group (the
    # first in raster order), whose size becomes the group's, the others' 0
    first = np.flatnonzero(idx % width == 0)
    last = np.flatnonzero(idx % width == width - 1)
    if not (first.size and last.size):
        return ids, sizes
    at = np.searchsorted(idx, idx[last] - (width - 1))
    at = np.minimum(at, idx.size - 1)
    meet = idx[at] == idx[last] - (width - 1)
    pairs = np.unique(np.stack([ids[at[meet]], ids[last[meet]]], axis=1), axis=0)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    if not pairs.size:
        return ids, sizes
    root = np.arange(sizes.size)
    for a, b in pairs.tolist():  # a few seam crossings: a plain union-find
        while root[a] != a:
            a = root[a]
        while root[b] != b:
            b = root[b]
        root[max(a, b)] = min(a, b)
    for p in range(root.size):
        root[p] = root[root[p]]
    joined = np.bincount(root, weights=sizes, minlength=sizes.size).astype(sizes.dtype)
    return root[ids].astype(ids.dtype), joined

