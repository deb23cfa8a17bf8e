"""polish.bend_on_one_side: a plane region the fitter's decision bends, whose bend rests on the
returns along one side of it (a laser's column of mixed returns beside a face), keeps its plane;
a pipe, whose far limb falls behind its front's plane too or whose rest's plane is tilted across
its arc, is left to the decision."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from rangeseg_o3d.fitting import fit_cylinder, fit_plane
from rangeseg_o3d.fitting.robust import beyond_noise
from rangeseg_o3d.refinement import polish
from rangeseg_o3d.refinement.polish import bend_on_one_side, polish_models

# the scenes of test_bent_by_one_side (a face or a pipe in front of a wall, one column of mixed
# returns on its left), loaded by path: the tests are not a package
_spec = importlib.util.spec_from_file_location("_one_side_scenes", Path(__file__).with_name("test_bent_by_one_side.py"))
_scenes = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_scenes)
SIGMA = _scenes.SIGMA


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_face_bent_by_one_column_of_mixed_returns_is_found(seed):
    ctx, labels, columns = _scenes._scene(seed, "face")
    idx = np.flatnonzero(labels.ravel())
    # the premise: the mixed column lies off the face's plane beyond the noise, the face's own
    # columns do not
    rest = idx[(idx % 40) >= columns[0]]
    plane = fit_plane(ctx.xyz[rest])
    mixed = idx[(idx % 40) < columns[0]]
    assert beyond_noise(float(np.sqrt(np.mean(plane.distances(ctx.xyz[mixed]) ** 2))), SIGMA, mixed.size)
    assert plane.rms < 0.7 * SIGMA  # seen at 57 degrees: its distances carry the noise's cosine share
    assert bend_on_one_side(ctx, labels, [1], 1.0) == [1]
    assert bend_on_one_side(ctx, labels, [], 1.0) == []


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_pipe_with_one_column_of_mixed_returns_is_not(seed):
    ctx, labels, columns = _scenes._scene(seed, "pipe")
    assert columns.size >= 5
    assert bend_on_one_side(ctx, labels, [1], 1.0) == []


@pytest.mark.parametrize("seed", [0, 1])
def test_a_rest_on_two_grid_lines_tells_nothing(seed, monkeypatch):
    ctx, labels, columns = _scenes._scene(seed, "narrow face")
    assert columns.size == 2
    assert bend_on_one_side(ctx, labels, [1], 1.0) == []


def test_a_tilted_rest_whose_returns_lie_off_it_as_head_on_ones_is_a_bent_arc(monkeypatch):
    # the face's rest passes; hold its plane to a fifth of the range noise along its rays (as if
    # its returns lay off it five times as much as a plane there leaves) and it no longer does:
    # the ray-noise test alone refuses it
    ctx, labels, _ = _scenes._scene(0, "face")
    assert bend_on_one_side(ctx, labels, [1], 1.0) == [1]
    real = polish._ray_noise
    monkeypatch.setattr(polish, "_ray_noise", lambda points, sigma, model, rays, each=False:
                        real(points, 0.2 * sigma, model, rays, each))
    assert bend_on_one_side(ctx, labels, [1], 1.0) == []


@pytest.mark.parametrize("seed", [0, 1])
def test_polish_keeps_the_plane_the_decision_would_bend_on_a_lasers_single_returns(seed, monkeypatch):
    ctx, labels, _ = _scenes._scene(seed, "face")
    points = ctx.xyz[labels.ravel() == 1]
    plane, cylinder = fit_plane(points), fit_cylinder(points)
    assert cylinder.kind == "cylinder"
    # the decision bends it (as noise_20mm seed 1014 scan 1's face under 20 mm noise)
    monkeypatch.setattr(polish, "_curved_planes", lambda ctx, labels, fits, *a, **k: {1: cylinder})
    monkeypatch.setattr(polish, "_planes_off_rays", lambda ctx, labels, fits: {})
    kept = polish_models(ctx, labels, {1: plane}, resolve_bends=1.0, along_rays=True)[1]
    assert kept.kind == "plane" and kept is plane
    assert polish_models(ctx, labels, {1: plane}, resolve_bends=1.0)[1].kind == "cylinder"  # not a laser's
    monkeypatch.setattr(polish, "bend_on_one_side", lambda *a, **k: [])
    assert polish_models(ctx, labels, {1: plane}, resolve_bends=1.0, along_rays=True)[1].kind == "cylinder"


def test_lines_beside_counts_the_grid_lines_across_line_by_line():
    from rangeseg_o3d.refinement.polish import _lines_beside

    labels = np.zeros((8, 10), np.int32)
    labels[1:7, 2:6] = 1  # a block 6 rows deep and 4 columns wide
    idx = np.flatnonzero(labels.ravel())
    assert _lines_beside(idx, 10, rows=False) == 4.0  # columns across, on each row
    assert _lines_beside(idx, 10, rows=True) == 6.0  # rows across, on each column
    band = np.zeros((8, 10), np.int32)
    for r in range(8):  # two pixels wide, drifting one column a row: 9 columns spanned
        band[r, r:r + 2] = 1
    idx = np.flatnonzero(band.ravel())
    assert _lines_beside(idx, 10, rows=False) == 2.0
    assert _lines_beside(idx[:0], 10, rows=False) == 0.0


def test_a_diagonal_band_two_pixels_wide_is_no_evidence(monkeypatch):
    # the face's scene cut so that the region drifts by one column halfway down: the upper
    # half holds the mixed column and the face's first two, the lower half the face's last two;
    # without its left side the rest spans all three face columns, but holds at most two
    # pixels on any row
    ctx, labels, columns = _scenes._scene(0, "face")
    assert bend_on_one_side(ctx, labels, [1], 1.0) == [1]
    cut = labels.copy()
    rows = np.arange(40)
    cut[(rows >= 10) & (rows <= 20), columns[-1]] = 0
    cut[(rows > 20) & (rows <= 30), columns[0] - 1:columns[0] + 1] = 0
    assert bend_on_one_side(ctx, cut, [1], 1.0) == []
    monkeypatch.setattr(polish, "BEND_LINES", 2)  # the line-by-line count alone refused it
    assert bend_on_one_side(ctx, cut, [1], 1.0) == [1]
