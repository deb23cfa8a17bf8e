"""The paper's segmenter: residual image -> closing x2 -> threshold -> flood fill (Sec. 3.2)."""

from __future__ import annotations

import time

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from ..edges import close_residual, edge_mask, jump_edges
from ..regions import label_regions
from ..registry import Plugin, Segmentation
from ..residual import block_means, residual_image

__all__ = ["segment_residual_edges", "ResidualEdgesConfig", "PLUGIN"]


def segment_residual_edges(
    cloud,
    *,
    window: int = 3,
    min_valid: int = 6,
    sigma0: float = 0.005,
    sigma_quadratic: float = 0.0,
    threshold: float = 9.0,
    closing_iterations: int = 2,
    jump_ratio: float = 0.08,
    jump_min: float = 0.05,
    min_region_size: int = 30,
    connectivity: int = 4,
    stride: int = 1,
) -> Segmentation:
    """Segment an organized cloud by the plane-fit residual of each pixel's neighbourhood.

    Parameters
    ----------
    cloud : OrganizedCloud
    window : neighbourhood size (odd); the paper uses 3.
    min_valid : windows with fewer valid points are edges.
    sigma0, sigma_quadratic : range-noise model ``sigma(r) = sigma0 + sigma_quadratic r^2`` (m);
        the residual is divided by ``(N - 3) sigma(r)^2`` (see :func:`rangeseg_o3d.residual.residual_image`).
    threshold : edge threshold on the normalised residual, in units of the noise variance
        (about 1 inside a plane; 9 is "three sigma").
    closing_iterations : grey-level closings of the residual image (the paper: 2).
    jump_ratio, jump_min : depth-discontinuity test of :func:`rangeseg_o3d.edges.jump_edges`;
        ``jump_ratio`` is per full-resolution pixel step.
    min_region_size : smaller connected areas are no region.
    connectivity : 4 or 8 for the flood fill.
    stride : segment the grid of ``stride x stride`` tile means, then expand the labels.
        For VGA depth cameras the 3x3 window spans only a few millimetres, less than the
        depth noise, so creases are invisible at full resolution; tile means widen the window
        on the surface, divide the noise by ``stride`` and the cost by ``stride**2``. Pixels of blocks next to an edge
        are left unlabelled for the pipeline's refinement to hand back. ``min_region_size``
        counts full-resolution pixels.

    Returns
    -------
    Segmentation with ``labels`` and the stages ``residual``, ``closed``, ``edges``, ``jumps``
    (all at full resolution).
    """
    if stride < 1:
        raise ValueError(f"stride must be >= 1; got {stride}")
    timings = {}
    t0 = time.perf_counter()
    full_shape = cloud.shape
    if stride > 1:
        xyz, counts = block_means(cloud.xyz, stride)
        noise_scale = 1.0 / np.sqrt(np.maximum(counts, 1))
        ranges = np.linalg.norm(xyz, axis=2)
    else:
        xyz, noise_scale, ranges = cloud.xyz, 1.0, cloud.range_image()
    valid = ~np.isnan(xyz[..., 2])
    residual, _ = residual_image(
        xyz, window=window, min_valid=min_valid, ranges=ranges, sigma0=sigma0,
        sigma_quadratic=sigma_quadratic, with_normals=False, noise_scale=noise_scale,
    )
    t1 = time.perf_counter()
    timings["residual"] = t1 - t0
    # jump_ratio is per pixel step; strided neighbours are ``stride`` steps apart.
    jumps = jump_edges(np.where(valid, ranges, np.nan), jump_ratio=jump_ratio * stride,
                       jump_min=jump_min)
    closed = close_residual(residual, iterations=closing_iterations)
    edges = edge_mask(closed, threshold=threshold, valid=valid, jumps=jumps)
    t2 = time.perf_counter()
    timings["edges"] = t2 - t1
    coarse_min = max(1, -(-min_region_size // (stride * stride)))
    labels = label_regions(edges, min_size=coarse_min, connectivity=connectivity)
    stages = {"residual": residual, "closed": closed, "edges": edges, "jumps": jumps}
    if stride > 1:
        stages = {k: _expand(v, stride, full_shape) for k, v in stages.items()}
        labels = _expand(labels, stride, full_shape)
        # A block beside an edge may hold the edge itself: leave its pixels to refinement.
        near_edge = cv2.dilate(stages["edges"].astype(np.uint8), np.ones((3, 3), np.uint8))
        labels[near_edge.astype(bool) | ~cloud.valid] = 0
    timings["regions"] = time.perf_counter() - t2
    return Segmentation(labels=labels, stages=stages, timings=timings)


def _expand(image: np.ndarray, stride: int, shape: tuple[int, int]) -> np.ndarray:
    # Nearest-neighbour upsampling of a strided image back to the full grid.
    return np.repeat(np.repeat(image, stride, axis=0), stride, axis=1)[: shape[0], : shape[1]].copy()


class ResidualEdgesConfig(BaseModel):
    """Parameters of :func:`segment_residual_edges`."""

    model_config = ConfigDict(extra="forbid")

    window: int = Field(3, ge=3, le=15)
    min_valid: int = Field(6, ge=4)
    sigma0: float = Field(0.005, ge=0)
    sigma_quadratic: float = Field(0.0, ge=0)
    threshold: float = Field(9.0, gt=0)
    closing_iterations: int = Field(2, ge=0, le=10)
    jump_ratio: float = Field(0.08, gt=0)
    jump_min: float = Field(0.05, ge=0)
    min_region_size: int = Field(30, ge=1)
    connectivity: int = Field(4)
    stride: int = Field(1, ge=1, le=16)

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
        if self.sigma0 == 0 and self.sigma_quadratic == 0:
            raise ValueError("sigma0 and sigma_quadratic cannot both be 0 (the noise model would be zero)")
        return self


PLUGIN = Plugin(
    name="residual_edges",
    config=ResidualEdgesConfig,
    run=segment_residual_edges,
    description="Plane-fit residual edges, closing, threshold and flood fill (the paper's method).",
)
