"""The paper's segmentation stages (Sec. 3.1), one module each, in the order a scan flows:

1. :mod:`.residual`: every pixel's window-plane residual, normalised by the sensor noise
   (the residual image), and the tile means a run on a coarser grid starts from.
2. :mod:`.edges`: depth jumps, the grey-level closing of the residual, its threshold into
   an edge mask, and the crease test for grids whose noise hides the residual's ridges.
3. :mod:`.regions`: the connected pieces of what no edge covers become the regions;
   360-degree grids are padded across the seam and joined again.

Each stage is plain functions on numpy arrays over the whole grid; the segmenter plugin
:mod:`rangeseg_o3d.segmenters.residual_edges` chains them. Names load lazily (PEP 562):
importing this package, or one stage module, loads neither numba nor OpenCV.
"""

from __future__ import annotations

from .._lazy import lazy_attributes

# stage module -> the public names it defines
_SOURCES = {
    "residual": ("MIN_VALID", "neighbourhood_moments", "smallest_eigenpairs", "residual_image", "block_means"),
    "edges": ("jump_edges", "close_residual", "edge_mask", "angular_steps", "crease_edges"),
    "regions": ("label_regions", "relabel_sequential", "wrap_columns", "join_wrapped"),
}
_EXPORTS = {name: module for module, names in _SOURCES.items() for name in names}

__all__ = list(_EXPORTS)

# the stage modules resolve too: segmentation.edges, ...
__getattr__, __dir__ = lazy_attributes(__name__, _EXPORTS)
