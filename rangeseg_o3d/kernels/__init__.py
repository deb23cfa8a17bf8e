"""Compiled (numba) loops over whole label images: one pass each, whatever the number of regions.

Region-level work in numpy costs a handful of small-array calls per region; at 10-50
regions per scan that Python overhead, not arithmetic, dominated the pipeline. These
kernels do per-pixel work for every region at once: window planes, label-wise moments, quadric normal
equations, growth of regions into the edge band, inlier counts and region adjacency.

Models are passed as a table indexed by label (see :func:`rangeseg_o3d.fitting.region_fitter.model_table`):
``kinds[k]`` is a kind of :mod:`.kinds` (0 no model, 1 plane ``(nx, ny, nz, d)``, 2 sphere
``(cx, cy, cz, r)``, 3 cylinder ``(ax, ay, az, px, py, pz, r)``) with its parameters in
``params[k]`` and its rms in ``rms[k]``.

Modules: ``labelwise`` (label-wise sums, planes, quadric test, distances to models),
``grid`` (grouping by label, jump edges, adjacency, growth, tile means), ``tiles`` (full-resolution
labels from the tile grid with their distance statistics, leftover blobs),
``trimmed`` (the trimmed fit's proposals), ``rays`` (label-wise sums along the viewing rays; numpy's sums of planes fitted along them, bit for bit), ``claims`` (pixels passed between plane regions along the rays), ``growth`` (the ring growth of faces fitted along the rays, and the sums of their refits), ``raygroups`` (the screen of the tile groups those faces are fitted to, the free pieces stereo faces grow from), ``sides`` (a cylinder region as the two sides of a crease, the bound on its end cap's band, and the facets step's pretest), ``borders`` (every curved region less one side's returns), ``creases`` (the plane pixels settled by the rays at a crease), ``modelnoise`` (models' distances to pixels against the pixels' noise), ``edgestrips`` (the edge-plane step's pretest on the grid), ``handovers`` (the dissolve step's pretests on the grid), ``limbs`` (the ring claim of curved regions' limbs seen near grazing), ``mixed`` (a laser's mixed returns, per pixel and counted per region), ``strips`` (the leftover strips' statistics), ``unions`` (the merge's loop over its pairs of planes), ``pieces`` (the pieces a split searches next), ``detached`` (a region's pieces apart from its body), ``window`` (the residual image: every pixel's
window plane), ``project`` (points from ranges or depth, used by the cloud constructors), ``inline`` (inline helpers: model distances, grid neighbours), ``linalg``
(small solves and plane helpers, also used by the fits) and ``kinds`` (the table of model
kinds, plain Python). The package imports nothing from the rest of ``rangeseg_o3d``.
Compiled on first use and cached beside the modules (``cache=True``): the first run on a
machine pays the compilation (about a minute for all of them, with the fits' on the 2-core CI machine;
a wheel carries them compiled when it was built, see setup.py).
Names load lazily (PEP 562): ``import rangeseg_o3d.kernels`` does not import numba.
"""

from __future__ import annotations

import importlib

_SOURCES = {
    "grid": ("adjacency_matrix", "count_either_side", "first_ring_grows", "block_means", "claim_rings", "claim_rings_in_boxes", "settle_borders", "group_by_label", "group_members",
             "label_counts",
             "relabel", "grow_rings", "grow_rings_in_boxes", "jump_mask", "largest_piece", "labels_near", "free_pixels", "member_pixels", "member_counts", "group_counted", "even_samples", "box_members", "piece_ids",
             "member_pixels_in_boxes", "differing_in_boxes", "free_pixels_in_boxes",
             "ranges_and_noise"),
    "labelwise": ("label_moments", "member_moments", "label_noise_sums", "member_centres", "planes_from_moment_rows", "plane_refit_rows", "quadric_sums", "quadric_shapes",
                  "height_field_shape", "settle_planes", "count_inliers", "distance_stats", "within_plane_noise", "planes_may_hold_half",
                  "rows_with_any", "piece_votes", "nearer_models", "voted_columns", "claim_parts"),
    "rays": ("plane_ray_sums", "trimmed_ray_plane", "band_bend", "settle_moves_along_rays", "ray_moment_sums",
             "pixel_ray_moments", "pairwise_sum",
             "box_ray_terms", "grid_line_order", "crease_cut_squares"),
    "claims": ("outlier_claims", "box_claims", "block_offsets"),
    "bends": ("bend_screen", "curve_screen", "stepped_bend_screen"),
    "tiles": ("label_pixels", "off_model_tiles", "tile_groups", "tile_members", "free_blocks", "leftover_blobs", "grow_free", "label_boxes", "label_sample", "labels_touch"),
    "growth": ("grow_along_rays", "grow_face", "refit_terms", "ray_terms_of"),
    "raygroups": ("ray_groups_ruled_out", "robust_ray_sets", "free_pieces", "tilt_noise", "plane_scores", "pixel_plane_scores"),
    "sides": ("crease_sides", "crease_cut", "cap_band_most", "curved_may_split"),
    "borders": ("side_rest_planes",),
    "creases": ("crease_moves", "cap_moves"),
    "modelnoise": ("plane_noise_sums", "plane_noise_near", "plane_distances_noise", "pieces_near_models"),
    "edgestrips": ("strips_near_models",),
    "handovers": ("fragments_may_pass", "ripples_may_pass"),
    "limbs": ("claim_limbs",),
    "mixed": ("mixed_at", "mixed_counts"),
    "strips": ("strip_fit_stats", "strip_touching", "grow_faces"),
    "unions": ("merge_plane_pairs", "part_within_step", "plane_candidates", "plane_prediction_sd"),
    "trimmed": ("trimmed_proposals", "local_proposals", "pool_inliers"),
    "pieces": ("pool_pieces",),
    "detached": ("detached_pieces",),
    "window": ("window_moments", "window_normals", "smallest_eigenvalues", "window_residuals", "eigenvectors", "crease_mask",
               "ray_steps", "blind_spacing"),
}
_MODULE_OF = {name: module for module, names in _SOURCES.items() for name in names}

__all__ = [name for names in _SOURCES.values() for name in names]


def __getattr__(name):
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
