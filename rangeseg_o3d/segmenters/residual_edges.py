"""The paper's segmenter: residual image -> closing x2 -> threshold -> flood fill (Sec. 3.2)."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, model_validator

from ..segmentation.edges import close_residual, crease_edges, edge_mask, jump_edges
from ..segmentation.regions import join_wrapped, label_regions, wrap_columns
from ..registry import Plugin, params_model
from ..segmentation.residual import MIN_VALID, residual_image
from ..result import Segmentation
from ..sensor import Sensor
from ..timing import now

__all__ = ["segment_residual_edges", "ResidualEdgesConfig", "PLUGIN"]


def segment_residual_edges(
    cloud,
    *,
    sensor: Sensor | None = None,
    window: int = 3,
    min_valid: int = MIN_VALID,
    threshold: float = 9.0,
    closing_iterations: int = 2,
    jump_ratio: float | None = None,
    jump_min: float | None = None,
    min_region_size: int | None = None,
    connectivity: int = 4,
    crease_angle_deg: float = 20.0,
) -> Segmentation:
    """Segment an organized cloud by the plane-fit residual of each pixel's neighbourhood.

    Parameters
    ----------
    cloud : OrganizedCloud
    sensor : the sensor; its noise model ``sigma(r) = sigma0 + sigma_quadratic r^2`` (m)
        normalises the residual, which is divided by ``(N - 3) sigma(r)^2`` (see
        :func:`rangeseg_o3d.segmentation.residual.residual_image`). None: ``Sensor()`` (5 mm, constant).
    window : neighbourhood size (odd); the paper uses 3.
    min_valid : windows with fewer valid points are edges.
    threshold : edge threshold on the normalised residual, in units of the noise variance
        (about 1 inside a plane; 9 is "three sigma").
    closing_iterations : grey-level closings of the residual image (the paper: 2).
    jump_ratio, jump_min : depth-discontinuity test of :func:`rangeseg_o3d.segmentation.edges.jump_edges`;
        ``jump_ratio`` is per sensor pixel step. None: derived from the sensor
        (:func:`rangeseg_o3d.scales.derive_scales`).
    min_region_size : smaller connected areas are no region (sensor pixels). None: derived.
    connectivity : 4 or 8 for the flood fill.
    crease_angle_deg : where the noise is comparable to the point spacing (the 3x3 residual
        is blind to creases there), normal discontinuities above this angle between
        flanking windows wide enough for well-determined normals are edges too
        (:func:`rangeseg_o3d.segmentation.edges.crease_edges`; the grid's angular spacing is measured
        from the cloud); 0 turns the test off.

    A cloud of tile means (:meth:`OrganizedCloud.tile_means`, as the pipeline's ``tile``
    makes for depth cameras) is segmented as such: each point's noise is divided by the
    square root of its ``samples``, ``jump_ratio`` is per sensor pixel (a grid step spans
    ``cloud.tile`` of them) and ``min_region_size`` counts sensor pixels.

    Returns
    -------
    Segmentation with ``labels`` and the stages ``residual``, ``closed``, ``edges``, ``jumps``.
    """
    sensor = sensor if sensor is not None else Sensor()
    if None in (jump_ratio, jump_min, min_region_size):
        from ..scales import scales_for_cloud

        scales = scales_for_cloud(sensor, cloud, tile=cloud.tile)
        jump_ratio = scales.jump_ratio if jump_ratio is None else jump_ratio
        jump_min = scales.jump_min if jump_min is None else jump_min
        min_region_size = scales.min_region_size if min_region_size is None else min_region_size
    if sensor.wrap_columns:
        return _segment_wrapped(cloud, sensor, dict(
            window=window, min_valid=min_valid, threshold=threshold,
            closing_iterations=closing_iterations, jump_ratio=jump_ratio, jump_min=jump_min,
            min_region_size=min_region_size, connectivity=connectivity,
            crease_angle_deg=crease_angle_deg))
    noise = sensor.noise
    timings = {}
    t0 = now()
    tile = cloud.tile
    xyz, ranges = cloud.xyz, cloud.range_image()
    noise_scale = 1.0 if cloud.samples is None else noise.mean_scale(cloud.samples)
    valid = cloud.valid
    residual, _ = residual_image(
        xyz, window=window, min_valid=min_valid, ranges=ranges, sigma0=noise.sigma0,
        sigma_quadratic=noise.sigma_quadratic, with_normals=False, noise_scale=noise_scale,
    )
    t1 = now()
    timings["residual"] = t1 - t0
    # jump_ratio is per sensor pixel; neighbouring tile means are ``tile`` pixels apart.
    # On a laser's single returns (refinement.single_returns' test: no tile, a constant
    # range noise) a step continued on one side beyond that noise is a narrow face near
    # grazing, no jump (jump_edges' single_return_noise).
    single = noise.sigma0 if tile == 1 and sensor.laser_returns else 0.0
    jumps = jump_edges(np.where(valid, ranges, np.nan), jump_ratio=jump_ratio * tile,
                       jump_min=jump_min, single_return_noise=single)
    closed = close_residual(residual, iterations=closing_iterations)
    edges = edge_mask(closed, threshold=threshold, valid=valid, jumps=jumps)
    t2 = now()
    timings["edges"] = t2 - t1
    stages = {"residual": residual, "closed": closed, "edges": edges, "jumps": jumps}
    if crease_angle_deg > 0:
        sigma = noise.sigma(ranges, cloud.samples)
        creases, _ = crease_edges(xyz, ranges, sigma, min_angle_deg=crease_angle_deg)
        edges |= creases
        stages["creases"] = creases
        t3 = now()
        timings["creases"], t2 = t3 - t2, t3
    min_size = max(1, -(-min_region_size // (tile * tile)))
    # (compiled: the residual above ran the kernels already)
    labels = label_regions(edges, min_size=min_size, connectivity=connectivity, compiled=True)
    timings["regions"] = now() - t2
    return Segmentation(labels=labels, stages=stages, timings=timings, jumps=jumps)


# Columns copied across the seam of a 360-degree grid: the farthest any test looks (the
# crease test's outer windows, 3 x 4 columns away and 9 wide) plus the closing's reach.
_SEAM_PAD = 20


def _segment_wrapped(cloud, sensor, params: dict) -> Segmentation:
    """Segment a 360-degree grid: the columns are unrolled with copies across the seam
    (:func:`rangeseg_o3d.segmentation.regions.wrap_columns`) so every window, the closing and the flood
    fill see the first and last columns as neighbours; the regions continuing across the
    seam are then joined (:func:`rangeseg_o3d.segmentation.regions.join_wrapped`)."""
    from dataclasses import replace

    from ..cloud import OrganizedCloud

    pad = min(_SEAM_PAD, cloud.shape[1] // 2)
    if pad < 1:
        return segment_residual_edges(cloud, sensor=replace(sensor, wrap_columns=False), **params)
    unrolled = OrganizedCloud(
        wrap_columns(cloud.xyz, pad),
        ranges=None if cloud.ranges is None else wrap_columns(cloud.ranges, pad),
        samples=None if cloud.samples is None else wrap_columns(cloud.samples, pad),
        tile=cloud.tile)
    seg = segment_residual_edges(unrolled, sensor=replace(sensor, wrap_columns=False), **params)
    width = cloud.shape[1]
    stages = {name: image[:, pad:pad + width] for name, image in seg.stages.items()}
    jumps = None if seg.jumps is None else seg.jumps[:, pad:pad + width]
    return Segmentation(labels=join_wrapped(seg.labels, pad), stages=stages, timings=seg.timings,
                        jumps=jumps)


class _ResidualEdgesChecks(BaseModel):
    # the checks across fields; the fields (and their defaults) come from the signature
    model_config = ConfigDict(extra="forbid")

    @model_validator(mode="after")
    def _check(self):
        if self.window % 2 == 0:
            raise ValueError(f"window must be odd; got {self.window}")
        if self.min_valid > self.window**2:
            raise ValueError(
                f"min_valid must be at most window**2 = {self.window**2}; got {self.min_valid}"
            )
        if self.connectivity not in (4, 8):
            raise ValueError(f"connectivity must be 4 or 8; got {self.connectivity}")
        return self


ResidualEdgesConfig = params_model(segment_residual_edges, dict(
    window=dict(ge=3, le=15),
    min_valid=dict(ge=4),
    threshold=dict(gt=0),
    closing_iterations=dict(ge=0, le=10),
    jump_ratio=dict(gt=0),
    jump_min=dict(ge=0),
    min_region_size=dict(ge=1),
    connectivity={},
    crease_angle_deg=dict(ge=0, lt=90),
), name="ResidualEdgesConfig", base=_ResidualEdgesChecks)


PLUGIN = Plugin(
    name="residual_edges",
    config=ResidualEdgesConfig,
    run=segment_residual_edges,
    description="Plane-fit residual edges, closing, threshold and flood fill (the paper's method).",
)
