"""Compiled (numba) loops over whole label images: one pass each, whatever the number of regions.

Region-level work in numpy costs a handful of small-array calls per region; at 10-50
regions per scan that Python overhead, not arithmetic, dominated the pipeline. These
kernels do per-pixel work for every region at once: window planes, label-wise moments, quadric normal
equations, growth of regions into the edge band, inlier counts and region adjacency.

Models are passed as a table indexed by label (see :func:`rangeseg_o3d.fitstage.model_table`): ``kinds[k]`` is
0 (no model), 1 plane ``(nx, ny, nz, d)``, 2 sphere ``(cx, cy, cz, r)`` or 3 cylinder
``(ax, ay, az, px, py, pz, r)`` in ``params[k]``, and ``rms[k]`` its rms.

Modules: ``moments`` (label-wise sums, planes, quadric test, distances to models),
``grid`` (grouping by label, jump edges, adjacency, growth, tile means, full-resolution labelling),
``trimmed`` (the trimmed fit's proposals), ``window`` (the residual image: every pixel's
window plane), ``models`` (shared inline helpers).
Compiled on first use and cached beside the modules (``cache=True``): the first run on a
machine pays the compilation (about a minute for all of them, with the fits' on the 2-core CI machine).
"""

from .grid import (
    adjacency_matrix,
    assign_tiles,
    block_means,
    claim_rings,
    group_by_label,
    grow_rings,
    jump_mask,
    largest_piece,
    member_pixels,
)
from .moments import (
    count_inliers,
    distance_stats,
    height_field_shape,
    label_moments,
    planes_from_moment_rows,
    quadric_shapes,
    quadric_sums,
    settle_planes,
)
from .trimmed import trimmed_proposals
from .window import eigenvectors, smallest_eigenvalues, window_moments

__all__ = [
    "label_moments",
    "planes_from_moment_rows",
    "quadric_sums",
    "quadric_shapes",
    "height_field_shape",
    "settle_planes",
    "count_inliers",
    "distance_stats",
    "group_by_label",
    "jump_mask",
    "adjacency_matrix",
    "grow_rings",
    "claim_rings",
    "block_means",
    "assign_tiles",
    "largest_piece",
    "member_pixels",
    "trimmed_proposals",
    "window_moments",
    "smallest_eigenvalues",
    "eigenvectors",
]
