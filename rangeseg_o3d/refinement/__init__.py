"""The refinement: beyond the paper's Sec. 3.2, after the first fits.

One module per step, in run order; each step is a function from ``(labels, fits)`` to new
ones and is timed under ``refine.<step>`` in ``Result.timings``:

1. :mod:`.split`: a region no model explains is split into all the surfaces it holds, one
   after the other (least trimmed squares, largest connected piece); only what no surface
   takes is freed (the paper's "local checks that remove under-segmentation").
2. :mod:`.grow`: edge-band pixels go back to the neighbouring region whose surface explains
   them (the paper's "re-add points left out by the edge band").
3. :mod:`.recover`: compact blobs of unlabelled pixels (small objects that the edge band
   swallowed whole, far boxes whose faces are narrower than the band) are split into
   every surface they hold, which become regions and take back their rims. Running
   after ``grow``, it sees only what no neighbour explains.
4. :mod:`.facets`: a curved model whose residuals exceed the sensor's noise (a cylinder
   over the crease of two faces, a pipe that took its end cap) gives way to the planes, or
   failing them the surfaces of any kind, that explain its region (before the merge,
   which joins them to the rest of their faces).
5. :mod:`.merge`: regions of one kind whose union one model explains as well as the parts
   are merged (the paper's "merging of patches that belong to the same surface"); two
   planes on the halves of a column seen through a noisy sensor become its cylinder; then a
   strip of a sphere or cylinder that another kind took goes back to it; on a laser's grid,
   :mod:`.trimmed_pieces`: a piece beside a curved region that also holds the mixed returns
   of its limb gives it the part its model explains, and the returns are freed.
6. ``settle`` (:func:`.grow.settle_regions`): border pixels go to the neighbouring region
   whose surface explains them clearly better (the band one surface took from another
   while growing first).
7. :mod:`.dissolve`: small blobs at junctions are dissolved into the larger neighbours
   that explain them, and curved patches into a neighbouring plane that explains them
   within its own rms (a ripple of the camera's error, not a surface); then :mod:`.grid_lines`
   frees every region on one row or one column of the grid (no surface of its own).
8. :mod:`.polish`: spheres and cylinders are refitted once on their final pixels (planes
   are refitted from moments whenever they change, which costs nothing), and a plane whose
   final pixels the fitter no longer settles as one is decided anew on them; on a laser's
   single returns, where a region's kind changed, the borders settle again
   (:func:`_settle_turned_by_polish`).
9. :mod:`.along_rays` (a laser's single returns only): border pixels go to the
   neighbouring plane that explains their range clearly better, in range sigmas along
   their rays (a plane seen near grazing took them within three range sigmas of its
   distances); then a region whose larger touching regions explain its pixels within the
   noise goes to them (:func:`.dissolve.dissolve_fragments`: a crease strip or a column's
   flank that a model of its own fits at 20 mm of range noise). On a spinning lidar,
   :mod:`.grazing_rings` first recovers the faces seen so near grazing that every step
   between its rings is a range jump (a low box's top), from the ring arcs no region took.

:func:`recover_pixels` is step 3 again at full resolution, after a run on tile means.
:mod:`.context` holds what the steps share (points, noise, fitter, size floor).
"""

from __future__ import annotations

import numpy as np

from ..fitting.region_fitter import RegionFitter
from ..result import Regions
from ..scales import GRAZING_COSINE, with_derived_refinement
from ..sensor import Sensor
from .along_rays import settle_along_rays
from .bands import release_bands
from .context import Context
from .dissolve import absorb_ripples, dissolve_fragments, dissolve_small
from .facets import planes_for_curved
from .grazing_rings import recover_grazing_rings
from .grid_lines import release_grid_lines
from .grow import grow_regions, grows_any, settle_regions
from .merge import curved_pairs_apart, merge_into_curved, merge_regions, planes_into_curved, region_adjacency
from .mixed_returns import planes_under_mixed_returns, release_mixed_returns
from .polish import polish_models
from .recover import claim_grazing_limbs, recover_leftovers, recover_pixels
from .split import split_regions
from .trimmed_pieces import join_trimmed_pieces
from ..timing import StepTimer

__all__ = ["refine_regions", "recover_pixels", "bend_samples", "ripple_jump", "single_returns"]



def _turned_by_polish(fits: dict, before: dict) -> set:
    """The labels of ``fits`` whose kind differs from their model in ``before`` (the models
    before polish)."""
    return {k for k, m in fits.items() if m and before.get(k) and before[k].kind != m.kind}


def _merge_turned_by_polish(ctx: Context, labels: np.ndarray, fits: dict, before: dict, config,
                            wrap_columns: bool):
    """``(labels, fits)`` with the regions whose kind polish changed (a plane made curved, a
    curved model made a plane) merged with the regions of their new kind whose union one
    model explains (:func:`.merge.merge_regions`, ``only`` those), and the ones made curved
    given the touching planes that are pieces of their surface (:func:`.merge.merge_into_curved`,
    as the merge step asks it): merge_regions pairs one kind only, and a column whose two
    halves were planes, one of them made a cylinder by polish, stayed a cylinder and a plane
    (spinning_32x1024 study seed 1415 scan 2: a 0.175 m column at 3.3-3.8 m, 179 and 186 px).

    The merge ran on the kinds before polish, which decides some regions' kinds on their
    final pixels only. On a stereo camera's tile grid polish's bend test (:func:`bend_samples`)
    makes a pipe's planes cylinders: a pipe the segmentation faceted into two planes along its
    axis (its halves meeting at a crease the tile means show) ends as two cylinders of one
    pipe, side by side, that nothing joins (seed 23 scan 0: 19 845 and 15 228 px of one
    35 468-px pipe). On a spinning lidar a few dozen returns of a far ceiling that an occluder
    cuts off, recovered as a cylinder, become a plane in polish, apart from the ceiling's
    region, after the merge that pairs pieces apart (spinning_64x1024 study seed 1045 scan 3:
    33 px at 6.3 m beside 2008).

    A turned region joins a region it touches only when it shows no step off that region's
    plane either (:meth:`.merge._Unions.no_step`, which the merge asks of pieces apart
    alone): its kind was in doubt until polish, and a small piece a few of its own sigmas
    off a large plane leaves the union's rms within the parts'. On the real 3DTK
    3dtk_scan001 (sick_3dtk preset) a 39-tile piece of a face in front of a wall (its plane
    at full resolution 0.12 m before the wall's), recovered as a sphere and made a plane in
    polish, joined the wall's 3995 tiles (its mean 47 mm, six of its own 7.6 mm rms, off the
    wall's plane; the union 10.9 mm rms against the wall's 9.9 mm), and at full resolution
    171 of its 188 px left the wall's plane free. Held so everywhere, touching pieces cost
    the ABW images over-segmentation (a big face's one-level terraces of its 1.3 mm depth
    steps kept apart: 90.6 -> 88.5 % correct), so the merge before polish does not ask it."""
    turned = _turned_by_polish(fits, before)
    if not turned:
        return labels, fits
    adjacency = region_adjacency(labels, wrap_columns=wrap_columns)
    labels, fits, adjacency = merge_regions(ctx, labels, fits, adjacency, max_angle_deg=config.merge_angle_deg,
                                            tolerance=config.merge_tolerance, disjoint=config.merge_disjoint,
                                            rms_factor=config.merge_rms_factor, only=turned,
                                            steps_between_touching=True)
    curved = {k for k in turned if fits.get(k) and fits[k].kind != "plane"}
    if curved:
        labels, fits, _ = merge_into_curved(ctx, labels, fits, adjacency, rms_factor=config.merge_rms_factor,
                                            only=curved)
    return labels, fits


def _settle_turned_by_polish(ctx: Context, labels: np.ndarray, fits: dict, before: dict, **settle):
    """``(labels, fits)`` with the borders settled again (:func:`.grow.settle_regions`, its
    keywords ``settle``) when polish changed a region's kind (``before``: the models before
    polish); the inputs when it changed none.

    The settle step gave border pixels to the neighbour whose model explained them clearly
    better by the kinds of then: a pipe the segmentation left a plane, over the rim of its
    end cap, kept the rim against the cap's plane (a plane near both along the crease), and
    polish then made it the cylinder it is (spinning_64x1024 study seed 1389 scan 0: a cap of
    133 px, 31 of them in the pipe's region, 77 % in its own). With the cylinder the rim lies
    nearer the cap's plane, and the settle gives it back (128 of 133)."""
    if not _turned_by_polish(fits, before):
        return labels, fits
    return settle_regions(ctx, labels, fits, **settle)


def _absorb_ripples(ctx: Context, labels: np.ndarray, fits: dict, k_sigma: float, min_cosine: float,
                    jump: tuple[float, float] | None):
    # curved patches a neighbouring plane explains within its rms and meets without a range
    # jump (dissolve.absorb_ripples); the planes that took them refitted from moments
    labels, fits, changed = absorb_ripples(ctx.xyz, labels, fits, ctx.sigma, {}, k_sigma=k_sigma,
                                           min_cosine=min_cosine, jump=jump)
    hosts = [k for k in changed if k in fits]
    for k, refit in ctx.fitter.refit_regions(ctx.xyz, labels, fits, hosts, from_points=False).items():
        if refit and refit.kind == fits[k].kind:
            fits[k] = refit
    return labels, fits


def bend_samples(sensor: Sensor, tile: int) -> float:
    """The independent samples each point of a grid of ``tile`` x ``tile`` means carries for
    polish's bend test (the quadric's F-test counts them), 0 for no bend test.

    Where the sensor states that its returns err together (``noise.correlation_px > 1``, a
    stereo camera's matching window) the test counts what that correlation leaves
    (:meth:`rangeseg_o3d.sensor.NoiseModel.independent_share`): on the stereo row's 6-px
    tile grid (0.73 samples each) 15 cm pipes at 4.6 and 6.5 m are cylinders, which
    stayed planes without the test (seeds 23 and 71); a 10 cm one at 3.6 m still does. Elsewhere only a laser's single
    returns (a range noise that does not grow with range, no tile) are counted, one sample
    each: a camera's returns err together over a window its preset does not state (a
    structured-light pattern's ripple: planes of the real frames came out as 1-59 cm
    cylinders), the ABW camera's noise is its depth steps, which neighbours share, and on
    the laser rows' tile grids the test cost correct surfaces (noise_20mm seed 0 97.6 ->
    96.3 %, spinning_32x1024 seed 0 93.5 -> 90.3 %, a false fitting on its seed 11)."""
    if sensor.noise.correlation_px > 1:
        return sensor.noise.independent_share(tile)
    return 1.0 if single_returns(sensor, tile) else 0.0


def single_returns(sensor: Sensor, tile: int) -> bool:
    """Whether the points of a grid of ``tile`` x ``tile`` means are a laser's single
    returns: no tile, and a sensor whose model states a laser's returns along its rays
    (:attr:`rangeseg_o3d.sensor.Sensor.laser_returns`: a range noise constant over range and
    uncorrelated, no depth steps, no lateral noise). :func:`bend_samples` counts one sample
    each; polish asks their planes whether the range noise along the rays (from the mirror
    of a nodding laser, :meth:`rangeseg_o3d.refinement.context.Context.viewing_rays`)
    explains them.

    Read from the sensor model and the tile, not from the geometry. A camera is out by what
    its model states, whatever its tile: the ABW structured-light camera by its depth steps
    and its lateral noise (its derived tile is 2 at 0.75-1.15 m, :mod:`rangeseg_o3d.scales`;
    the tile alone kept it out before, and without ``depth_step`` it would have counted)."""
    return tile == 1 and sensor.laser_returns


def ripple_jump(sensor: Sensor, tile: int, jump_ratio: float, jump_min: float) -> tuple[float, float] | None:
    """The range-jump test ``(jump_ratio, jump_min)`` that :func:`.dissolve.absorb_ripples`
    asks of a ripple's contact with its plane on a grid of ``tile`` x ``tile`` means, None
    on a laser's single returns (:func:`single_returns`): a camera's ripples meet their plane
    without a jump, while a spinning lidar's rings on a floor seen near grazing step by more
    than the test between them (region growing on spinning_32x1024 study seed 1411 scan 3
    kept curved patches of the floor apart from it and lost a ball)."""
    return None if single_returns(sensor, tile) else (jump_ratio, jump_min)


def grow_recovered_curves(ctx: Context, labels: np.ndarray, fits: dict, before, **growth):
    """``(labels, fits)`` with the cylinders and spheres the recovery found (labels of ``fits``
    not in ``before``, the labels before it) grown into the free pixels their models explain,
    ring after ring until none joins (:func:`grow_regions`, its acceptance test: within
    ``k_sigma`` noise sigmas, never across a jump edge); ``growth`` holds grow_regions' grids
    and thresholds but ``iterations``.

    The growth step ran before these regions existed, and the recovery's blobs are the free
    pixels' parts with a 3 x 3 core: a column two or three grid columns wide whose curvature the
    residual marked as edge band all along is recovered from its part three columns wide, and
    the part two columns wide, which has no core, stayed free (noise_2mm seed 17 scan 1: a
    0.137 m column at 4.6 m, 109 of its 152 px recovered as a cylinder, its upper 43 px free). A
    plane recovered there takes such strips already (``recover.claim_thin_strips``); a curved
    surface took none. Asked on a laser's single returns (:func:`single_returns`): on the
    region-growing preset's real 640 x 480 frames (tile 1, a camera) it grew a 41-px plane of
    pcl_office1 into a 3.3 cm cylinder of 306 px at 14 mm rms."""
    recovered = [k for k, m in fits.items() if m and m.kind != "plane" and k not in before]
    # (where none of them takes a free pixel, growth adds nothing and refits nothing: half
    # of the LMS200 suite's scans recover a cylinder, none grew)
    if not recovered or not grows_any(labels=labels, models={k: fits[k] for k in recovered}, **growth):
        return labels, fits
    # (the kernel stops at the first ring that adds no pixel; no region is farther across the grid)
    return grow_regions(ctx, labels, fits, iterations=int(max(labels.shape)), only=recovered, **growth)


def refine_regions(cloud, regions: Regions, *, fitter: RegionFitter, config, sensor: Sensor,
                   ranges: np.ndarray, sigma: np.ndarray, jumps: np.ndarray | None,
                   timings: dict) -> Regions:
    """Run the refinement steps; returns new Regions (``regions`` is not changed).

    Parameters
    ----------
    cloud : OrganizedCloud
    regions : the regions after segmentation and their first fits.
    fitter : the pipeline's region fitter.
    config : RefineConfig; the scale-dependent values it leaves out (None: ``min_region_size``,
        the jump test, ``merge_tolerance``) are derived from ``sensor`` for ``cloud``
        (:func:`rangeseg_o3d.scales.scales_for_cloud`; the Pipeline passes them resolved).
    sensor : the run's sensor.
    ranges : (H, W) ranges, NaN where invalid (for the no-jump test of growth).
    sigma : (H, W) range noise per pixel (``sensor.noise`` at ``ranges``).
    jumps : (H, W) jump-edge mask from the segmenter, if it made one.
    timings : dict receiving ``refine.<step>`` durations.
    """
    timer = StepTimer(timings, "refine.")
    config = with_derived_refinement(config, sensor, cloud)
    # Region sizes and jump ratios are in sensor pixels; a grid step spans cloud.tile.
    tile = cloud.tile
    min_size = max(-(-int(config.min_region_size) // (tile * tile)), 10)
    growth = dict(xyz=cloud.xyz, ranges=ranges, sigma=sigma, k_sigma=config.k_sigma,
                  jump_ratio=config.jump_ratio * tile, jump_min=config.jump_min)
    ctx = Context(cloud, fitter, sigma, min_size, wrap_columns=sensor.wrap_columns)
    labels, fits = regions.labels, regions.models

    failed = [k for k, m in fits.items() if not m]
    if failed:
        # On tile means a plane found there is held to the noise of its own distances, at
        # least half a depth step (a quantised camera's planes scatter by that much whatever
        # their incidence): a tile's mean lies on its face but for the noise along its ray. A
        # laser's single return seen near grazing spreads across the face (noise_20mm seed 0,
        # nodding_0.25deg seed 71 lost faces to the hold).
        held = 0.5 * sensor.depth_step if tile > 1 else None
        # At sensor resolution a pool neither trimmed search explains is searched once more
        # with a one-sigma face band (Context.dominant_piece's face_band), as the recovery's
        # blobs are: at 20 mm noise a region the segmenter could not fit holds two to five box
        # faces of a few hundred returns, a few noise sigmas wide each, whose best three-point
        # plane by the three-sigma band is a diagonal one the fitter refuses (noise_20mm seed
        # 89 scan 5: four faces left unfitted). On tile means a face's mean is exact but for
        # its noise along the ray (held above).
        labels, fits = split_regions(ctx, labels, fits, failed, held=held, face_band=tile == 1)
    timer.lap("split")
    labels, fits = grow_regions(ctx, labels, fits, iterations=config.grow_iterations, **growth)
    timer.lap("grow")
    if config.recover_leftovers:
        before = set(fits)
        labels, fits = recover_leftovers(ctx, labels, fits, valid=cloud.valid,
                                         jumps=jumps if jumps is not None else np.zeros(cloud.shape, bool),
                                         claim_strips=config.merge_disjoint,  # a strip is a piece apart
                                         thin_strips=tile == 1, **growth,  # (tile grid: see fullres)
                                         # (a laser's column strips, where it was measured)
                                         strips_apart=single_returns(sensor, tile))
        if single_returns(sensor, tile):  # (a laser's grid, where it was measured; see its docstring)
            labels, fits = grow_recovered_curves(ctx, labels, fits, before, **growth)
    timer.lap("recover")
    before = fits
    # (the cut of a cylinder beyond the noise into two faces: a laser's grazing box tops, where
    # it was measured; on a camera's tile grid it turned a real frame's planes over, unverified)
    labels, fits = planes_for_curved(ctx, labels, fits, faces_beyond_noise=single_returns(sensor, tile))
    # the surfaces split off a curved region (a pipe's end cap) take back the band growth gave it
    split_off = fits.keys() - before.keys()
    if split_off:
        labels, fits = grow_regions(ctx, labels, fits, iterations=config.grow_iterations, only=split_off, **growth)
    timer.lap("facets")
    adjacency = set()
    if config.merge:
        adjacency = region_adjacency(labels, wrap_columns=sensor.wrap_columns)
        labels, fits, adjacency = merge_regions(
            ctx, labels, fits, adjacency, max_angle_deg=config.merge_angle_deg,
            tolerance=config.merge_tolerance, disjoint=config.merge_disjoint,
            rms_factor=config.merge_rms_factor)
        before_curving = fits
        labels, fits, adjacency = planes_into_curved(ctx, labels, fits, adjacency,
                                                     max_angle_deg=config.merge_angle_deg)
        # a column whose two planes became its cylinder there may touch another piece of it
        # (or, with merge_disjoint, match one apart from it), curved already, which the merge
        # above could not pair with a plane
        joined = {k for k, m in fits.items() if m and m.kind != "plane" and before_curving[k].kind == "plane"}
        if joined:
            labels, fits, adjacency = merge_regions(
                ctx, labels, fits, adjacency, max_angle_deg=config.merge_angle_deg,
                tolerance=config.merge_tolerance, disjoint=config.merge_disjoint,
                rms_factor=config.merge_rms_factor, only=joined)
        # with merge_disjoint, a piece of a column or pipe seen apart from the rest of it (a
        # pipe crossing in front: noise_20mm study seed 1182 scan 3, a column's 33 px above
        # the pipe a plane, 114 below it the cylinder) is offered to the curved regions apart too
        labels, fits, adjacency = merge_into_curved(ctx, labels, fits, adjacency,
                                                    rms_factor=config.merge_rms_factor,
                                                    apart=curved_pairs_apart(fits, adjacency)
                                                    if config.merge_disjoint else frozenset(),
                                                    apart_sigmas=config.k_sigma)
        if single_returns(sensor, tile):  # (a laser's mixed returns at a column's limb)
            labels, fits, adjacency = join_trimmed_pieces(ctx, labels, fits, adjacency,
                                                          rms_factor=config.merge_rms_factor,
                                                          apart=curved_pairs_apart(fits, adjacency, any_kind=True)
                                                          if config.merge_disjoint else frozenset(),
                                                          apart_sigmas=config.k_sigma)
    timer.lap("merge")
    labels, fits = settle_regions(ctx, labels, fits, iterations=config.grow_iterations,
                                  wrap_columns=sensor.wrap_columns, **growth)
    timer.lap("settle")
    if config.merge:  # the merge's adjacency tells the small regions' neighbours
        labels, fits = dissolve_small(ctx, labels, fits, adjacency, k_sigma=config.k_sigma)
    labels, fits = release_grid_lines(labels, fits)  # the steps before may leave one; none after makes one
    # on tile means a ripple is judged by the noise of its distances to the plane (range
    # noise x incidence cosine): a tile's mean lies on its face but for the noise along its
    # ray, while a laser's single return near grazing spreads across the face (3DTK scans
    # and the laser rows keep the range noise)
    labels, fits = _absorb_ripples(ctx, labels, fits, config.k_sigma, GRAZING_COSINE if tile > 1 else 1.0,
                                   ripple_jump(sensor, tile, growth["jump_ratio"], growth["jump_min"]))
    timer.lap("dissolve")
    if single_returns(sensor, tile):  # a row of another face keeps a laser's pipe a plane
        labels, fits = release_bands(ctx, labels, fits, k_sigma=config.k_sigma,
                                     resolve_bends=bend_samples(sensor, tile))
    before_polish = fits
    fits = polish_models(ctx, labels, fits, resolve_bends=bend_samples(sensor, tile),
                         along_rays=single_returns(sensor, tile))
    if config.merge:
        labels, fits = _merge_turned_by_polish(ctx, labels, fits, before_polish, config, sensor.wrap_columns)
    if single_returns(sensor, tile):  # (a laser's grid, where it was measured; see its docstring)
        labels, fits = _settle_turned_by_polish(ctx, labels, fits, before_polish, iterations=config.grow_iterations,
                                               wrap_columns=sensor.wrap_columns, **growth)
    timer.lap("polish")
    if single_returns(sensor, tile):  # a laser's returns err along their rays only
        labels, fits = settle_along_rays(ctx, labels, fits, ranges=ranges, iterations=config.grow_iterations,
                                         k_sigma=config.k_sigma, jump_ratio=growth["jump_ratio"],
                                         jump_min=config.jump_min)
        if sensor.wrap_columns:  # a spinning lidar's rings (a nodding laser's rows are fans through it)
            labels, fits = recover_grazing_rings(ctx, labels, fits, ranges=ranges, jump_ratio=growth["jump_ratio"],
                                                 jump_min=config.jump_min)
        # a column's limbs seen near grazing are range jumps growth never crossed
        labels = claim_grazing_limbs(ctx, labels, fits, valid=cloud.valid, k_sigma=config.k_sigma)
        # a piece of a surface that a model of its own fits within the noise (a crease strip,
        # a column's flank) goes to the surface whose model explains it within the noise too
        # (timed with the rays' steps)
        labels, fits = dissolve_fragments(ctx, labels, fits, k_sigma=config.k_sigma,
                                          wrap_columns=sensor.wrap_columns, jumps=jumps)
        if sensor.beam_width_deg > 0:  # a line of returns the beam mixed between two surfaces
            labels, fits = release_mixed_returns(ctx, labels, fits, ranges=ranges, k_sigma=config.k_sigma,
                                                 wrap_columns=sensor.wrap_columns)
            labels, fits = planes_under_mixed_returns(ctx, labels, fits, ranges=ranges,
                                                      wrap_columns=sensor.wrap_columns)
    timer.lap("rays")
    return Regions(labels, fits)
