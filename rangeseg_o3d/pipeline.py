"""Pipeline: OrganizedCloud -> segment -> fit -> refine -> full resolution (tiled presets) -> Result."""

from __future__ import annotations

import inspect
import logging
import time
from typing import NamedTuple

import numpy as np

from . import registry
from .cloud import OrganizedCloud
from .config import PipelineConfig, load_config
from .crease_planes import planes_for_creases
from .fitting.primitives import Cylinder, Plane, Sphere, with_statistics
from .fitting.region_fitter import RegionFitter
from .free_faces import faces_from_free
from .fullres import (ExpandedStages, PixelStats, drop_small_regions, drop_unresolvable_curves, grow_into_free,
                      label_pixels, recover_freed_pixels, merge_touching_planes, planes_for_unresolved,
                      recover_thin_surfaces, recovered_region_floor, settle_curved_into_planes,
                      refit_planes_to_pixels, region_stats, settle_caps, settle_creases, settle_plane_borders,
                      smallest_region, stats_after_moves, free_untold_regions)
from .off_model import recover_off_model
from .bent_planes import cylinders_for_bent_planes
from .curved_pairs import curved_from_plane_pairs
from .detached import give_detached_pieces, specks_apart
from .occluded_planes import join_across_occluders
from .plane_faces import claim_along_rays, join_pieces_along_rays, split_plane_faces
from .ray_claims import claim_outliers_along_rays
from .strips import recover_strips
from .edge_planes import edge_planes_to_curved
from .end_caps import split_end_caps
from .memory import keep_freed_memory, large_frame
from .refinement import refine_regions, ripple_jump
from .timing import StepTimer
from .patches import PatchSource
from .result import INLIER_SIGMAS, Feature, Regions, Result, Segmentation, Unfitted
from .scales import Scales, pixelwise_noise_spans_the_grid, scales_for_cloud
from .sensor import Sensor
from .sensor_checks import check_plausible, noise_excess

__all__ = ["Pipeline", "warm_up"]


log = logging.getLogger(__name__)

# Settings a preset may leave to the sensor (None): rangeseg_o3d.scales derives them per scan.
_DERIVED_SEGMENTER = ("jump_ratio", "jump_min", "min_region_size")
_DERIVED_REFINE = ("min_region_size", "jump_ratio", "jump_min", "merge_tolerance")


class _Settings(NamedTuple):
    """One run's scale-dependent settings: the preset's, with what it leaves to the sensor derived."""

    tile: int
    segmenter_args: dict
    refine: object  # RefineConfig


def _takes_sensor(run) -> bool:
    # Segmenters declare a ``sensor`` keyword to receive the Sensor; older plugins do not.
    try:
        return "sensor" in inspect.signature(run).parameters
    except (TypeError, ValueError):
        return False


class Pipeline:
    """Segment organized clouds and fit planes, cylinders and spheres to the regions.

    Parameters
    ----------
    config : PipelineConfig, preset name, YAML path, dict, or None (the lms200 preset).
    keep_memory : on the first frame of at least 128 KiB of float64 per whole-frame array
        (:func:`rangeseg_o3d.memory.large_frame`; a VGA frame, not an LMS200 scan), fix glibc's
        malloc thresholds so that the memory a run frees stays in the process for the next
        run (:func:`rangeseg_o3d.memory.keep_freed_memory`: process-wide, a no-op off glibc
        or when the environment sets glibc's malloc). Otherwise glibc starts handing each
        frame's large temporaries back to the system after a few frames, and every later
        frame page-faults them again (4-5 ms of a VGA frame).

    Examples
    --------
    >>> import rangeseg_o3d as rs
    >>> from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    >>> from rangeseg_o3d.synthetic.suite import default_scene
    >>> result = rs.Pipeline("lms200").run(simulate_lms200(default_scene()).cloud)
    >>> result.labels.shape, sorted({f.kind for f in result.features})
    ((70, 131), ['cylinder', 'plane', 'sphere'])
    """

    def __init__(self, config=None, *, keep_memory: bool = True):
        self.config: PipelineConfig = load_config(config)
        self.keep_memory = keep_memory
        # The sensor, resolved once; every stage receives it (or what follows from it).
        self.sensor: Sensor = self.config.sensor.resolve()
        self.segmenter = registry.get("segmenter", self.config.segmenter.name)
        self._segmenter_args = dict(self.config.segmenter.params)
        if _takes_sensor(self.segmenter.run):
            self._segmenter_args["sensor"] = self.sensor
        self.fitter = RegionFitter(registry.get("fitter", self.config.fitter.name),
                                   self.config.fitter.params, self.config.max_fit_points,
                                   sensor=self.sensor)
        self._derived_segmenter = [k for k in _DERIVED_SEGMENTER
                                   if k in self._segmenter_args and self._segmenter_args[k] is None]
        self._derived_refine = [k for k in _DERIVED_REFINE if getattr(self.config.refine, k) is None]
        # the settings of every run when no derived value depends on the cloud (set by the first run)
        self._fixed_settings: _Settings | None = None

    def scales(self, cloud: OrganizedCloud) -> Scales | None:
        """The scales derived for ``cloud`` (:func:`rangeseg_o3d.scales.scales_for_cloud`),
        or None when the preset sets every scale-dependent value itself."""
        if self.config.tile is not None and not (self._derived_segmenter or self._derived_refine):
            return None
        return scales_for_cloud(self.sensor, cloud, tile=self.config.tile)

    def _with_scales(self, scales: Scales | None) -> _Settings:
        # the run's tile, segmenter keywords and refinement with the derived values filled in
        if scales is None:
            return _Settings(self.config.tile, self._segmenter_args, self.config.refine)
        args = {**self._segmenter_args, **{k: getattr(scales, k) for k in self._derived_segmenter}}
        refine = self.config.refine.model_copy(
            update={k: getattr(scales, k) for k in self._derived_refine})
        return _Settings(scales.tile, args, refine)

    def _settings(self, cloud: OrganizedCloud) -> _Settings:
        """The run's settings for ``cloud``; computed once when they cannot depend on it."""
        if self._fixed_settings is not None:
            return self._fixed_settings
        settings = self._with_scales(self.scales(cloud))
        if self._scales_ignore_cloud():
            self._fixed_settings = settings
        return settings

    def _scales_ignore_cloud(self) -> bool:
        # The derived values read the cloud through its median range (only for the noise
        # there: a constant without the noise's range term), its measured spacing (when the
        # sensor gives none) and its shape (only for a tile the preset leaves to the sensor).
        sensor = self.sensor
        return (self.config.tile is not None and sensor.noise.sigma_quadratic == 0.0
                and sensor.row_spacing_deg is not None and sensor.column_spacing_deg is not None)

    def _fitter_for(self, work: OrganizedCloud, excess: float | None = None) -> RegionFitter:
        """The fitter for ``work``'s points. On a tile grid they are means of ``tile x tile``
        returns, and the thresholds follow the noise of those means
        (:meth:`rangeseg_o3d.sensor.Sensor.of_means`): under the single returns' noise, the
        tile means of a cylinder or of two faces meeting at a shallow crease pass for a
        plane. Means that scatter more than the model says (real cameras' returns err
        together) widen them by the measured excess ``excess``
        (:func:`rangeseg_o3d.sensor_checks.noise_excess` of ``work``, measured when None)."""
        if work.tile <= 1:
            return self.fitter
        if excess is None:
            excess = noise_excess(work, self.sensor)
        means = self.sensor.of_means(work.tile * work.tile, excess=excess)
        return RegionFitter(self.fitter.plugin, self.config.fitter.params, self.config.max_fit_points,
                            sensor=means)

    def __repr__(self) -> str:
        return (f"Pipeline({self.config.name!r}, segmenter={self.segmenter.name!r}, "
                f"fitter={self.fitter.plugin.name!r})")

    def run(self, cloud: OrganizedCloud, *, recording=None, scan_index: int = 0,
            light_log: bool = False) -> Result:
        """Segment ``cloud`` and fit every region.

        Parameters
        ----------
        cloud : OrganizedCloud
        recording : optional ``rerun.RecordingStream``; every stage is logged to it.
        scan_index : position of this scan on the recording's ``scan`` timeline.
        light_log : log no intermediate images (residual, closed, edges) to ``recording``.

        Raises
        ------
        TypeError
            ``cloud`` is not an OrganizedCloud.
        ValueError
            The cloud has no valid point, its ranges do not fit the sensor's working
            ranges (a unit mistake: see :func:`rangeseg_o3d.sensor_checks.check_plausible`,
            which also warns when no window looks planar), or the segmenter returned
            malformed labels.
        """
        self._check(cloud)
        if self.keep_memory and large_frame(cloud.shape):
            keep_freed_memory()  # once per process: a no-op from the second call on
        clock = StepTimer({})
        settings = self._settings(cloud)
        work = cloud.tile_means(settings.tile) if settings.tile > 1 else cloud
        segmentation = self._segment(work, settings)
        clock.timings.update(segmentation.timings)
        clock.lap("segment")
        labels = segmentation.labels
        excess = noise_excess(work, self.sensor) if work.tile > 1 else 1.0
        fitter = self._fitter_for(work, excess)
        regions = Regions(labels, fitter.fit_regions(work.xyz.reshape(-1, 3), labels))
        clock.lap("fit")
        regions, sigma = self._refine(work, regions, segmentation.jumps, clock.timings,
                                      settings.refine, fitter)
        clock.lap("refine")
        stages, stats = segmentation.stages, None
        if work is not cloud:
            labels, fits, sigma, stats = self._full_resolution(cloud, regions.labels, regions.models, settings,
                                                               excess, timings=clock.timings, tile_means=work)
            regions = Regions(labels, fits)
            stages = ExpandedStages(stages, settings.tile, cloud.shape)
            clock.lap("full_resolution")
        result = self._assemble(regions, sigma, cloud.xyz, clock, stages, stats=stats)
        if recording is not None:
            from .viz.rerun_log import log_scan

            log_scan(recording, cloud, result, scan_index=scan_index, light=light_log)
        return result

    def _check(self, cloud) -> None:
        # what run refuses before any work: see its Raises
        if not isinstance(cloud, OrganizedCloud):
            raise TypeError(f"cloud must be an OrganizedCloud; got {type(cloud).__name__}")
        if cloud.n_valid == 0:
            raise ValueError(
                f"cloud has no valid point (all {cloud.shape[0]}x{cloud.shape[1]} are NaN)")
        check_plausible(cloud, self.sensor, name=f"preset {self.config.name!r}")

    def _segment(self, work: OrganizedCloud, settings: _Settings) -> Segmentation:
        """The segmenter's answer on ``work``, its labels checked and zero on invalid pixels."""
        if work.n_valid == 0:
            raise ValueError(f"no {settings.tile}x{settings.tile} tile of the cloud has "
                             "at least half of its pixels valid; use a smaller tile")
        seg = self.segmenter.run(work, **settings.segmenter_args)
        labels = np.asarray(seg.labels)
        if labels.shape != work.shape or not np.issubdtype(labels.dtype, np.integer):
            raise ValueError(
                f"segmenter {self.segmenter.name!r} returned labels of shape {labels.shape} and "
                f"dtype {labels.dtype}; expected integer labels of shape {work.shape}"
            )
        jumps = getattr(seg, "jumps", None)  # plugins written before the field have none
        if jumps is not None and np.shape(jumps) != work.shape:
            raise ValueError(f"segmenter {self.segmenter.name!r} returned jumps of shape "
                             f"{np.shape(jumps)}; expected {work.shape}")
        return Segmentation(np.where(work.valid, labels, 0).astype(np.int32), seg.stages, seg.timings,
                            jumps=None if jumps is None else np.asarray(jumps, dtype=bool))

    def _refine(self, work: OrganizedCloud, regions: Regions, jumps, timings: dict, refine,
                fitter: RegionFitter):
        """The refined regions (``regions`` when refinement is off) and the noise per pixel of ``work``."""
        if work.samples is None:  # one compiled pass, the same values
            from .kernels import ranges_and_noise

            noise = self.sensor.noise
            ranges, sigma = ranges_and_noise(_read_only(work.range_image(), np.float64),
                                             _read_only(work.valid, np.bool_), float(noise.sigma0),
                                             float(noise.sigma_quadratic))
        else:
            ranges = np.where(work.valid, work.range_image(), np.nan)
            sigma = self.sensor.noise.sigma(ranges, work.samples)
        if refine.enabled:
            regions = refine_regions(work, regions, fitter=fitter, config=refine,
                                     sensor=self.sensor, ranges=ranges, sigma=sigma, jumps=jumps,
                                     timings=timings)
        return regions, sigma

    def _full_resolution(self, cloud: OrganizedCloud, tile_labels: np.ndarray, fits: dict,
                         settings: _Settings, excess: float = 1.0, timings: dict | None = None,
                         tile_means: OrganizedCloud | None = None):
        """Label every pixel by the models of its tile's region and the 8 around it.

        Returns full-resolution ``(labels, fits, sigma, stats)``, ``stats`` the
        :class:`rangeseg_o3d.fullres.PixelStats` of the labels. The models stay those
        fitted to the tile means (each averages all the region's pixels; refitting the
        pixels moves a plane's normal by far less than its error), except a curved one
        whose curvature its pixels do not resolve, which becomes their plane unless its kind
        refitted to them resolves it (:func:`rangeseg_o3d.fullres.planes_for_unresolved`); :meth:`_assemble` reports the
        rms of the pixels' distances. ``timings`` (optional) receives each step's seconds
        under ``full.<step>`` (the steps that ran), as the refinement's go under ``refine.<step>``.
        ``tile_means`` (the cloud ``tile_labels`` label) places the regions for the crease rule
        of :func:`rangeseg_o3d.fullres.label_pixels`, taken where the range noise grows with the range.
        """
        from .kernels import ranges_and_noise

        lap = StepTimer(timings, "full.").lap

        # NaN-masked ranges and the noise there in one compiled pass (numpy took four
        # whole-frame temporaries: the where, the square, the product, the sum)
        noise = self.sensor.noise
        ranges, sigma = ranges_and_noise(_read_only(cloud.range_image(), np.float64),
                                         _read_only(cloud.valid, np.bool_), float(noise.sigma0),
                                         float(noise.sigma_quadratic))
        lap("noise")
        refine = settings.refine
        min_size = smallest_region(refine, self.sensor, cloud)  # the fewest pixels of a region here
        # how much more a tile's mean errs than one of independent returns (correlated
        # returns, the tile means' measured excess scatter)
        spread = excess * float(noise.mean_scale(settings.tile * settings.tile)) * settings.tile
        # where the noise grows with the range, a far crease's band lies within the noise of
        # both faces' planes: there the rays choose the face (``tile_means`` places the regions).
        # Not where that noise errs together over a matching window (a stereo camera's): there
        # split_plane_faces cuts the regions the band reaches into the faces they hold, and a
        # plane region that took a pipe's band from across a crease gave the pipe's piece a
        # plane of its own that no merge rule joins to the pipe's cylinder (seed 89 scan 1 of
        # the stereo matrix: 525 of 5557 px, the union's cylinder beyond the noise)
        by_rays = (refine.enabled and float(noise.sigma_quadratic) > 0 and not noise.matched_window
                   and tile_means is not None)
        # where the range noise exceeds the grid's footprint and errs pixel by pixel (a Kinect's),
        # a pipe's plane turns towards the rays: a curved model is judged by the noise of its distances
        by_means = refine.enabled and pixelwise_noise_spans_the_grid(self.sensor, cloud)
        labels, stats, blocks = label_pixels(cloud, tile_labels, fits, tile=settings.tile, sigma=sigma,
                                             k_sigma=refine.k_sigma, inlier_factor=INLIER_SIGMAS, with_blocks=True,
                                             creases_from=tile_means if by_rays else None,
                                             min_angle_deg=refine.merge_angle_deg)
        lap("label_pixels")
        if refine.enabled:
            # (tile regions no model was fitted to: their pixels go to the recovery below)
            labels, fits, stats = free_untold_regions(tile_labels, labels, fits, stats)
        if refine.enabled and specks_apart(noise):
            # specks where a curved model's continuation crosses another surface go to that surface's region
            labels, stats = give_detached_pieces(cloud, labels, fits, stats, sigma=sigma, ranges=ranges,
                                                 k_sigma=refine.k_sigma, jump_ratio=refine.jump_ratio,
                                                 jump_min=refine.jump_min,
                                                 max_size=min_size,
                                                 inlier_factor=INLIER_SIGMAS, wrap_columns=self.sensor.wrap_columns)
            lap("detached")
        recovered_from = int(labels.max(initial=0)) + 1  # the regions found from here on are fitted to pixels
        if refine.enabled and refine.recover_leftovers:
            tile_fits = fits
            labels, fits, stats = recover_thin_surfaces(
                cloud, labels, fits, stats, fitter=self.fitter, config=refine, sensor=self.sensor,
                ranges=ranges, sigma=sigma, inlier_factor=INLIER_SIGMAS, strips=refine.close_gaps)
            lap("recover")
            # pixels a model took one by one that lie beside it as a group: a surface of their own?
            labels, fits, stats = recover_off_model(
                cloud, labels, fits, stats, blocks=blocks, tile_fits=tile_fits, tile=settings.tile, spread=spread,
                fitter=self.fitter, config=refine, sensor=self.sensor, ranges=ranges, sigma=sigma,
                inlier_factor=INLIER_SIGMAS)
            lap("off_model")
            if not refine.close_gaps:  # (with close_gaps the strips came with the blobs, as ever)
                # the strips too thin for a blob, once the blobs' surfaces have grown and merged
                labels, fits, stats = recover_strips(
                    cloud, labels, fits, stats, fitter=self.fitter, config=refine, sensor=self.sensor,
                    ranges=ranges, sigma=sigma, inlier_factor=INLIER_SIGMAS)
                lap("strips")
            # a pipe's end cap the pipe's tile model took, given back to the cap's plane found since
            labels, fits, stats = settle_curved_into_planes(
                cloud, labels, fits, stats, sigma=sigma, ranges=ranges, config=refine, sensor=self.sensor,
                recovered_from=recovered_from, inlier_factor=INLIER_SIGMAS)
            lap("settle_curved")
            if by_means or noise.matched_window:
                # a pipe the frame's edge cuts: the plane strips recovered at the edge beside its
                # cylinder region join it when its model (or its refit with them) explains them;
                # so do the pieces of a ball or pipe recovered as curved regions of their own,
                # on a stereo camera too
                labels, fits, stats = edge_planes_to_curved(
                    cloud, labels, fits, stats, sigma=sigma, fitter=self.fitter,
                    inlier_factor=INLIER_SIGMAS, tile_labels=tile_labels, tile=settings.tile,
                    near_sigmas=refine.k_sigma, curved_pieces=True)
                lap("edge_planes")
        if refine.enabled and noise.matched_window:
            # plane and cylinder regions whose tile means hid a crease (far boxes): the faces
            # their pixels hold. Only where the range noise grows with the range (a depth camera's), so that
            # far away it spreads a tile's mean along its ray by a box face's width; a sensor of
            # constant noise and depth steps (the ABW camera: 163 of 192 surfaces against 173)
            # leaves its planes off the noise model by more than any far crease. And only where
            # that noise errs together over a matching window (a stereo camera's): a Kinect-type
            # camera's tile regions split no far box on any studied scan, and the searches cost
            # its real frames 25-286 ms each in one --frames run
            labels, fits, stats = split_plane_faces(
                cloud, labels, fits, stats, fitter=self.fitter, sigma=sigma,
                min_size=min_size, inlier_factor=INLIER_SIGMAS,
                min_angle_deg=refine.merge_angle_deg, correlation_px=noise.correlation_px,
                wrap_columns=self.sensor.wrap_columns)
            lap("plane_faces")
        if refine.enabled:  # ripples the pixels show, measured by their planes' pixel rms
            jump = ripple_jump(self.sensor, 1, refine.jump_ratio, refine.jump_min)  # (full resolution: tile 1)
            labels, fits, stats, freed = _absorb_pixel_ripples(cloud, labels, fits, stats, sigma, refine.k_sigma, jump)
            if refine.recover_leftovers and freed.size:
                # what a ripple's host did not explain is surfaces of its own, not nothing
                labels, fits, stats = recover_freed_pixels(
                    cloud, labels, fits, stats, freed, fitter=self.fitter, config=refine, sensor=self.sensor,
                    ranges=ranges, sigma=sigma, inlier_factor=INLIER_SIGMAS)
            lap("ripples")
            # a cylinder bent over a crease gives way to its two faces before the regions grow
            labels, fits, stats = planes_for_creases(cloud, labels, fits, stats, sigma=sigma,
                                                     k_sigma=refine.k_sigma, inlier_factor=INLIER_SIGMAS,
                                                     min_size=min_size,
                                                     tile_labels=tile_labels, tile=settings.tile,
                                                     fitter=self.fitter, depth_step=self.sensor.depth_step)
            lap("creases")
            if refine.close_gaps:
                labels, fits, stats = _close_gaps(cloud, labels, fits, stats, sigma, ranges, refine, tile_labels,
                                                  rings=refine.grow_iterations * settings.tile,
                                                  wrap_columns=self.sensor.wrap_columns)
                lap("close_gaps")
            settled = fits
            fits, stats = planes_for_unresolved(cloud, labels, fits, stats, sigma=sigma,
                                                inlier_factor=INLIER_SIGMAS, tile_labels=tile_labels,
                                                tile=settings.tile, by_distance_noise=by_means,
                                                fitter=self.fitter, samples=noise.independent_share(1))
            lap("unresolved")
            turned = _kind_changed(settled, fits) if by_means or noise.matched_window else set()
            if turned:
                # a region given the other curved kind: the curved pieces beside it that the join
                # above refused for their kind are offered to it again
                labels, fits, stats = edge_planes_to_curved(
                    cloud, labels, fits, stats, sigma=sigma, fitter=self.fitter,
                    inlier_factor=INLIER_SIGMAS, tile_labels=tile_labels, tile=settings.tile,
                    near_sigmas=refine.k_sigma, curved_pieces=True, hosts=turned)
                lap("edge_planes_again")
            if by_means or noise.matched_window:
                # a far pipe's end cap within the range noise of its cylinder, on too few tile
                # means for the tile grid's cap split: split off where it closes the pipe
                # (a cap is a region found at full resolution: held to the recovered regions' floor)
                cap_floor = recovered_region_floor(refine, min_size, noise.correlation_px)
                labels, fits, stats = split_end_caps(cloud, labels, fits, stats, sigma=sigma, fitter=self.fitter,
                                                     min_size=cap_floor, inlier_factor=INLIER_SIGMAS,
                                                     wrap_columns=self.sensor.wrap_columns)
                lap("end_caps")
            if noise.matched_window:
                # (as split_plane_faces) a stereo camera's grazing faces take the pixels beside
                # them their rays meet nearer, in range noise, than their own regions' planes,
                # and a band of a wall under a model bent along its rays goes back to the wall
                labels, fits, stats = claim_along_rays(cloud, labels, fits, stats, sigma=sigma,
                                                       min_size=min_size,
                                                       inlier_factor=INLIER_SIGMAS,
                                                       correlation_px=noise.correlation_px)
                lap("claim_along_rays")
                # pixels a region took within the noise of their distances to its plane that lie
                # beyond the range noise along their rays (a floor seen near grazing under a far
                # face) go to the plane beside them that explains them along the rays
                labels, stats = claim_outliers_along_rays(cloud, labels, fits, stats, sigma=sigma,
                                                          inlier_factor=INLIER_SIGMAS,
                                                          correlation_px=noise.correlation_px)
                lap("claim_outliers")
            # a curved model within a few depth steps is the quantisation's, not a surface
            labels, fits = drop_unresolvable_curves(labels, fits, depth_step=self.sensor.depth_step)
            labels, fits = drop_small_regions(labels, fits, stats, min_size=min_size,
                                              recovered_from=recovered_from,
                                              recovered_min_size=recovered_region_floor(refine, min_size,
                                                                                 self.sensor.noise.correlation_px))
            lap("drop")
            if float(noise.sigma_quadratic) > 0:  # (by_rays, or a matching window's noise)
                # where the noise grows with the range, as close_gaps does on the abw preset:
                # regions grow into the free pixels beside them that their models explain
                # (a face recovered from the blobs reaches no farther than its rim and claims), then
                # a plane's border pixels that a touching plane explains clearly better go to it, as
                # deep as the tile grid settles: a face whose band along its crease the neighbour's
                # tile model took within the noise at labelling takes it back. Kinect study seed 1190
                # scan 3: a box top at 3.5 m recovered from the blobs kept 575 of its 722 px, 141 in
                # the plane beside it; 621 after the settling. Seed 1181 scan 5: a box top at 5 m seen
                # at 82 degrees, 272 of its 405 px; 319 after the settling, 328 with the growth.
                # Where it errs together over a matching window (stereo, kinect_real) too, before
                # the steps below grow faces from free pieces and settle creases by their rays: a
                # face whose tile model left a band of free pixels kept it (kinect_real
                # study seed 1464 scan 4, a face at 3.4 m seen 63 degrees from head-on: 1979 of its
                # 2513 px, 381 free; 2354 now)
                labels, stats, _ = _grow_free(cloud, labels, fits, stats, sigma, ranges, refine)
                labels, stats = _settle_planes(cloud, labels, fits, stats, sigma, ranges, refine,
                                               rings=refine.grow_iterations * settings.tile,
                                               wrap_columns=self.sensor.wrap_columns)
                lap("settle_planes")
            if noise.matched_window:
                # (as split_plane_faces) a stereo camera's faces seen near grazing that kept no
                # region, grown from the free pieces they left; after the drop, as each is held
                # to the independent returns of its own shape, not to the recovered-region floor
                labels, fits, stats = faces_from_free(cloud, labels, fits, stats, sigma=sigma, noise=noise,
                                                      inlier_factor=INLIER_SIGMAS)
                lap("free_faces")
                # pieces of a far wall the tile means left as plane regions of their own under
                # models turned from the wall's join it where its plane explains them along the
                # rays; then the pixels beside a crease between two planes go to the face their
                # rays meet there (settle_creases, as close_gaps ends on the abw preset): within
                # the range noise of both planes the nearer model is the noise's choice
                labels, fits, stats = join_pieces_along_rays(cloud, labels, fits, stats, sigma=sigma,
                                                             inlier_factor=INLIER_SIGMAS,
                                                             correlation_px=noise.correlation_px)
                lap("join_pieces")
                # pieces of one face a pipe or a box before it cuts apart, joined across it
                # where their joint plane explains both along the rays (occluded_planes)
                labels, fits, stats = join_across_occluders(cloud, labels, fits, stats, sigma=sigma,
                                                            inlier_factor=INLIER_SIGMAS,
                                                            correlation_px=noise.correlation_px)
                lap("occluders")
                labels, stats = settle_creases(cloud, labels, fits, stats, sigma=sigma, k_sigma=refine.k_sigma,
                                               min_angle_deg=refine.merge_angle_deg, inlier_factor=INLIER_SIGMAS,
                                               along_rays=True)
                lap("settle")
                # the same at a pipe's end cap: within the noise of both models the rim's pixels
                # go to the surface their rays enter (a cap seen at 50-60 degrees kept 74-78 %)
                labels, stats = settle_caps(cloud, labels, fits, stats, sigma=sigma, k_sigma=refine.k_sigma,
                                            inlier_factor=INLIER_SIGMAS)
                lap("caps")
                # a pipe the tile grid left a plane region: its plane in xyz turns to the rays and
                # hides the bend, which its inverse ranges show (bent_planes); where the depth
                # also comes in steps, the bend is judged over blocks of the correlation window
                fits, stats = cylinders_for_bent_planes(cloud, labels, fits, stats, sigma=sigma,
                                                        share=noise.independent_share(1),
                                                        inlier_factor=INLIER_SIGMAS,
                                                        max_radius=float(self.fitter.params["max_radius"]),
                                                        window=noise.correlation_px,
                                                        stepped=noise.step_quadratic > 0.0,
                                                        min_arc_deg=float(self.fitter.params["min_arc_deg"]))
                lap("bent_planes")
                # a pipe or ball left as two plane strips, each flat within the noise: the
                # model of both, where it leaves no crease's pattern between them (curved_pairs)
                labels, fits, stats = curved_from_plane_pairs(
                    cloud, labels, fits, stats, sigma=sigma, fitter=self.fitter, min_size=min_size,
                    inlier_factor=INLIER_SIGMAS, correlation_px=noise.correlation_px,
                    wrap_columns=self.sensor.wrap_columns, share=noise.independent_share(1),
                    stepped=noise.step_quadratic > 0.0)
                lap("curved_pairs")
        return labels, fits, sigma, stats

    @staticmethod
    def _assemble(regions: Regions, sigma, xyz, clock: StepTimer, stages,
                  stats: PixelStats | None = None) -> Result:
        # Regions with a fit (or a reported failure) numbered 1..n, in label order. With
        # ``stats`` (measured at full resolution on tile models) the rms is the pixels'.
        pixel_rms = stats is not None
        if stats is None:
            # Inliers over the whole region (fits may have used a subsample): pixels within
            # INLIER_SIGMAS sensor noise sigmas of the surface.
            stats = region_stats(xyz, regions.labels, regions.models, sigma, INLIER_SIGMAS)
        regions, sizes, kept = _renumber(regions)
        stats = PixelStats(*(np.concatenate([[0], values[kept]]).astype(values.dtype)
                             for values in (stats.inliers, stats.squares, stats.counts)))
        features, unfitted = _features(regions, sizes, stats, sigma, xyz, pixel_rms=pixel_rms)
        clock.timings["total"] = clock.elapsed()
        if not isinstance(stages, ExpandedStages):
            stages = dict(stages)
        return Result(labels=regions.labels, features=features, unfitted=unfitted,
                      timings=clock.timings, stages=stages)


def _kind_changed(before: dict, after: dict) -> set:
    """The cylinder regions of ``before`` that are spheres in ``after``, and the spheres that are
    cylinders."""
    return {k for k, model in after.items() if model and before.get(k) and before[k].kind != model.kind
            and model.kind != "plane" and before[k].kind != "plane"}


def _absorb_pixel_ripples(cloud: OrganizedCloud, labels: np.ndarray, fits: dict, stats: PixelStats,
                          sigma: np.ndarray, k_sigma: float, jump: tuple[float, float] | None):
    """:func:`rangeseg_o3d.refinement.dissolve.absorb_ripples` at full resolution, each
    plane's scatter the rms of its pixels about it, the range noise scaled by the incidence
    cosine (at least ``scales.GRAZING_COSINE``; a depth camera's pixel moves along its ray),
    ``jump`` the grid's range-jump test ``(jump_ratio, jump_min)`` or None;
    ``(labels, fits, stats, freed)`` after it, ``freed`` the flat indices (increasing) of the
    pixels it left in no region."""
    from .refinement.dissolve import absorb_ripples
    from .scales import GRAZING_COSINE

    scatter = {k: rms for k in fits if k > 0 and (rms := stats.rms(k)) is not None}
    before = labels
    labels, fits, changed = absorb_ripples(cloud.xyz.reshape(-1, 3), labels, fits, sigma.ravel(),
                                           scatter, k_sigma=k_sigma, sizes=stats.counts, min_cosine=GRAZING_COSINE,
                                           jump=jump)
    if changed:
        # a ripple's pixels went to a plane whose model stays, or became free: the statistics
        # follow them (not a pass over the plane's pixels)
        moved = np.flatnonzero(labels.ravel() != before.ravel())
        stats = stats_after_moves(cloud.xyz, sigma, before, labels, fits, stats, moved, set(),
                                  inlier_factor=INLIER_SIGMAS)
        return labels, fits, stats, moved[labels.ravel()[moved] == 0]
    return labels, fits, stats, np.zeros(0, np.int64)


def _close_gaps(cloud: OrganizedCloud, labels: np.ndarray, fits: dict, stats: PixelStats,
                sigma: np.ndarray, ranges: np.ndarray, refine, tile_labels: np.ndarray, *, rings: int,
                wrap_columns: bool = False):
    """Regions grow into the free pixels their models explain
    (:func:`rangeseg_o3d.fullres.grow_into_free`), then pieces of one plane that meet merge
    (:func:`rangeseg_o3d.fullres.merge_touching_planes`), a plane's border pixels that a
    touching plane explains clearly better go to it, up to ``rings`` pixels deep
    (:func:`rangeseg_o3d.fullres.settle_plane_borders`; ``wrap_columns``: a 360-degree grid's
    first and last columns are neighbours), and the pixels beside a crease go to
    the face their rays meet (:func:`rangeseg_o3d.fullres.settle_creases`), and every pair of
    planes that touches then is asked the merge again (pieces the settling made neighbours, or
    whose pixels it moved); ``(labels, fits, stats)``. A plane whose
    tile model its pixels' own plane beats by ``merge_rms_factor`` grows with that one
    (:func:`rangeseg_o3d.fullres.refit_planes_to_pixels`).

    Pieces meet where the growth made them 4-neighbours, or where their tiles lie within
    three tiles of each other: a pixel takes the region of its tile or of one of the 8
    around it (:func:`rangeseg_o3d.fullres.label_pixels`), so the pixels of two such
    regions can be neighbours (a pass over the tile grid, not the frame), or where their
    pixels already are neighbours (a pass over the frame's label runs: the regions recovered
    at full resolution have no tiles)."""
    from .kernels import adjacency_matrix

    fits, stats = refit_planes_to_pixels(cloud, labels, fits, stats, sigma=sigma,
                                         rms_factor=refine.merge_rms_factor, inlier_factor=INLIER_SIGMAS)
    labels, stats, touch = _grow_free(cloud, labels, fits, stats, sigma, ranges, refine)
    if refine.merge:
        near = adjacency_matrix(np.ascontiguousarray(tile_labels, dtype=np.int32), touch.shape[0], 3)
        # regions found at full resolution (recovered from the blobs) have no tiles, and two
        # such pieces of one face that already met before the growth are in neither ``touch``
        # nor the tile grid's ``near``: the pixels' own adjacency (a U-shaped box top cut in
        # two by a recovered arm, tabletop_abw seed 1010 scan 2: 6185 and 3904 px, 0.54 deg
        # apart, the union's rms their own)
        near |= adjacency_matrix(labels, touch.shape[0], 1)
        labels, fits, stats = merge_touching_planes(cloud, labels, fits, stats, touch, sigma=sigma,
                                                    max_angle_deg=refine.merge_angle_deg,
                                                    rms_factor=refine.merge_rms_factor,
                                                    inlier_factor=INLIER_SIGMAS, near=near)
    # a plane's band that a neighbour's tile model took and the neighbour's own plane leaves
    # beyond its noise: back to the plane that explains it, as deep as the tile grid settles
    labels, stats = _settle_planes(cloud, labels, fits, stats, sigma, ranges, refine, rings=rings,
                                   wrap_columns=wrap_columns)
    # the pixels beside a crease: the planes' rays decide where the noise cannot
    labels, stats = settle_creases(cloud, labels, fits, stats, sigma=sigma, k_sigma=refine.k_sigma,
                                   min_angle_deg=refine.merge_angle_deg, inlier_factor=INLIER_SIGMAS)
    if refine.merge:
        # pieces of one face that the settling made neighbours (a band of another region's or
        # free pixels lay between them at the merge above), or whose pixels it settled (a pair
        # that met before the settling and was refused then is asked again: held-out seeds
        # 1901 scan 5 and 1931 scan 2 of tabletop_abw, two faces each)
        labels = np.ascontiguousarray(labels, dtype=np.int32)
        n = int(labels.max(initial=0)) + 1
        labels, fits, stats = merge_touching_planes(cloud, labels, fits, stats, adjacency_matrix(labels, n, 1),
                                                    sigma=sigma, max_angle_deg=refine.merge_angle_deg,
                                                    rms_factor=refine.merge_rms_factor,
                                                    inlier_factor=INLIER_SIGMAS)
    return labels, fits, stats


def _grow_free(cloud: OrganizedCloud, labels: np.ndarray, fits: dict, stats: PixelStats, sigma: np.ndarray,
               ranges: np.ndarray, refine):
    """:func:`rangeseg_o3d.fullres.grow_into_free` by the refinement's noise and jump test, on
    ``labels`` as a writeable C-ordered int32 image (a copy when they are not one):
    ``(labels, stats, touch)``."""
    if not (labels.dtype == np.int32 and labels.flags.c_contiguous and labels.flags.writeable):
        labels = np.array(labels, dtype=np.int32, order="C")
    return grow_into_free(cloud, labels, fits, stats, sigma=sigma, ranges=ranges, k_sigma=refine.k_sigma,
                          jump_ratio=refine.jump_ratio, jump_min=refine.jump_min, inlier_factor=INLIER_SIGMAS)


def _settle_planes(cloud: OrganizedCloud, labels: np.ndarray, fits: dict, stats: PixelStats, sigma: np.ndarray,
                   ranges: np.ndarray, refine, *, rings: int, wrap_columns: bool):
    """:func:`rangeseg_o3d.fullres.settle_plane_borders` by the refinement's noise and jump
    test, up to ``rings`` pixels deep: ``(labels, stats)``."""
    return settle_plane_borders(cloud, labels, fits, stats, sigma=sigma, ranges=ranges, k_sigma=refine.k_sigma,
                                jump_ratio=refine.jump_ratio, jump_min=refine.jump_min, iterations=rings,
                                inlier_factor=INLIER_SIGMAS, wrap_columns=wrap_columns)


def _read_only(array: np.ndarray, dtype) -> np.ndarray:
    # a C-contiguous read-only view (or copy): a compiled kernel then sees one array type
    # whether the cloud stored its ranges and mask writeable or not (one machine code)
    view = np.ascontiguousarray(array, dtype=dtype).view()
    view.flags.writeable = False
    return view


def _renumber(regions: Regions) -> tuple[Regions, np.ndarray, np.ndarray]:
    """The regions that have a model (or a failure) and pixels, numbered 1..n in label order,
    their pixel counts (index 0 unused) and their old labels; other pixels become 0."""
    from .kernels import label_counts, relabel

    labels = np.ascontiguousarray(regions.labels)
    pixels = label_counts(labels)
    kept = [int(k) for k in np.flatnonzero(pixels[1:]) + 1 if int(k) in regions.models]
    lut = np.zeros(len(pixels), dtype=np.int32)
    lut[kept] = np.arange(1, len(kept) + 1, dtype=np.int32)
    sizes = np.zeros(len(kept) + 1, np.int64)
    sizes[1:] = pixels[kept]
    models = {new: regions.models[old] for new, old in enumerate(kept, start=1)}
    return Regions(relabel(labels, lut), models), sizes, np.array(kept, np.int64)


def _features(regions: Regions, sizes: np.ndarray, stats: PixelStats, sigma: np.ndarray,
              xyz: np.ndarray, *, pixel_rms: bool) -> tuple[list[Feature], list[Unfitted]]:
    """A Feature per fitted region (``stats`` give the inliers over all its pixels and,
    with ``pixel_rms``, the rms of its pixels' distances) and an Unfitted per failure."""
    labels, xyz_flat = regions.labels, xyz.reshape(-1, 3)
    inliers = stats.inliers.copy()
    source = PatchSource(xyz, labels)  # patch geometry is computed on demand from it
    features, unfitted = [], []
    for label, model in regions.models.items():
        if not model:
            unfitted.append(Unfitted(label=label, n_pixels=int(sizes[label]),
                                     reason=f"{model.kind}: {model.reason}"))
            continue
        if not isinstance(model, (Plane, Sphere, Cylinder)):  # a third-party model type:
            # count with its own distances
            idx = np.flatnonzero(labels.ravel() == label)
            tol = INLIER_SIGMAS * sigma.ravel()[idx]
            inliers[label] = np.count_nonzero(np.abs(model.distances(xyz_flat[idx])) <= tol)
        model = with_statistics(model, inliers=int(inliers[label]))
        if pixel_rms and stats.rms(label) is not None:  # fitted on tile means: the pixels' rms
            model = with_statistics(model, rms=stats.rms(label))
        features.append(Feature(label=label, model=model, n_pixels=int(sizes[label]), source=source))
    return features, unfitted


def warm_up(processes: int = 1) -> float:
    """Compile (or load from numba's cache) every kernel the presets use; returns seconds.

    The first run on a machine compiles for two to three minutes on one core, later
    processes load the cached machine code in well under a second. ``scripts/bootstrap.sh``
    calls this once after installing, so that the first real scan is fast.

    Parameters
    ----------
    processes : int
        With 2 or more, a second Python process compiles the depth-camera frame's kernels
        while this one compiles the laser scan's; numba's cache on disk is shared, so each
        loads what the other saved first (on an idle 2-core machine 134 s instead of 174 s
        wall, docs/benchmarks.md). This process still runs every step itself: a failed helper costs time only.
    """
    import subprocess
    import sys

    if isinstance(processes, bool) or not isinstance(processes, (int, np.integer)) or processes < 1:
        raise ValueError(f"warm_up: processes must be a whole number >= 1, got {processes!r}")
    from .synthetic.lms200 import simulate_lms200
    from .synthetic.suite import default_scene

    start = time.perf_counter()
    helper = None
    if processes > 1:
        helper = subprocess.Popen([sys.executable, "-c", "from rangeseg_o3d.pipeline import _warm_up_frame; "
                                   "_warm_up_frame()"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        Pipeline("lms200").run(simulate_lms200(default_scene(), seed=0).cloud)
        _warm_up_frame()
        _warm_up_rest()
    finally:
        if helper is not None:
            helper.wait()
    return time.perf_counter() - start


def _warm_up_frame() -> None:
    # the depth-camera preset's frame (warm_up's helper process starts here)
    from .synthetic.depth_camera import simulate_depth_camera
    from .synthetic.suite import rgbd_scenes

    Pipeline("rgbd_vga").run(simulate_depth_camera(rgbd_scenes()[1][1], seed=0).cloud)


def _warm_up_rest() -> None:
    # kernels the two default scans do not reach, called on tiny inputs of their signatures;
    # first the public single-model fits' own
    from .fitting import fit_cylinder, fit_plane, fit_sphere

    angle = np.linspace(0.0, np.pi, 12)
    arc = np.stack([np.cos(angle), np.sin(angle), np.tile([0.0, 1.0], 6)], axis=1)
    fit_plane(arc), fit_sphere(arc), fit_cylinder(arc)
    # kernels that only some scans reach (a pool split into pieces, recovered thin surfaces)
    from .kernels import (claim_rings_in_boxes, free_pieces, grow_along_rays, member_pixels, piece_ids,
                          ray_groups_ruled_out)

    piece_ids(np.arange(4, dtype=np.int64), 2)
    member_pixels(np.zeros((2, 2), np.int32), np.zeros(1, bool))
    from .fitting.region_fitter import model_table

    kinds, params, rms = model_table({}, 1)
    points = np.zeros((4, 3))
    points.flags.writeable = False  # (as a cloud's points are: a signature of its own)
    claim_rings_in_boxes(points, np.zeros((2, 2), np.int32), kinds, params, rms, np.ones(4),
                         np.zeros(1, bool), 1, 3.0, np.array([[0, 2, 0, 2]], np.int64))
    # an off-model face's growth along the rays (off_model.faces_along_rays)
    grow_along_rays(points, np.zeros(4, np.int32), 2, 2, np.full((2, 3), np.nan), np.zeros((1, 2), bool),
                    np.zeros((1, 2), bool), np.ones(4), 1, 1, np.array([0, 2, 0, 2], np.int64), 3.0, 1)
    # and its screen of the tile groups before numpy fits them
    ray_groups_ruled_out(points, np.ones(4), np.arange(4, dtype=np.int64), np.array([0, 4], np.int64), 2, 1,
                         np.full((1, 3), np.nan), 0.05, 3.0, 3.0, 8, 3, 1e-5)
    # the free pieces a stereo camera's faces seen near grazing grow from (free_faces.faces_from_free)
    valid = np.ones((2, 2), bool)
    valid.flags.writeable = False  # (as a cloud's validity is)
    free_pieces(np.zeros((2, 2), np.int32), valid, 1)
    # and the pixels plane regions pass on along the rays (ray_claims.claim_outliers_along_rays)
    from .kernels import outlier_claims

    outlier_claims(np.zeros((2, 2), np.int32), points, np.ones(4), np.zeros((1, 3)), np.zeros(1, bool), 3.0, 1)
    # the abw preset's crease settling (fullres.settle_creases)
    from .fullres import _STEPS, CREASE_RINGS
    from .kernels import crease_moves

    crease_moves(points, np.zeros((2, 2), np.int32), np.ones(2, bool), np.zeros((2, 3)), np.zeros(2), np.zeros(2),
                 np.ones(4), 3.0, 0.9, 0.1, _STEPS, CREASE_RINGS)
    crease_moves(points, np.zeros((2, 2), np.int32), np.ones(2, bool), np.zeros((2, 3)), np.zeros(2), np.zeros(2),
                 np.ones(4), 3.0, 0.9, 0.1, _STEPS, CREASE_RINGS, True)
    # the trimmed fit: the fitter's compiled search and the generic one's inlier count
    from .fitting.robust import trimmed_fit

    fitter = Pipeline("rgbd_vga").fitter
    fitter.trimmed(arc, np.arange(len(arc)), sigma=0.01, min_points=6)
    trimmed_fit(arc, fit_plane, sigma=0.01, min_points=6, pool=np.arange(len(arc)))
