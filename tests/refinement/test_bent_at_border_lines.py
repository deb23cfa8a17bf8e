"""polish.bent_at_border_lines: the one decision on a laser region less the border grid lines whose
returns lie off the rest beyond their noise (one side, or two opposite ones); what it gives is the
rest's own least-squares plane, and polish asks it once, for the curved regions and for the planes
the fitter's final decision bends alike."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from rangeseg_o3d.fitting import fit_cylinder, fit_plane
from rangeseg_o3d.fitting.primitives import Sphere
from rangeseg_o3d.refinement import polish
from rangeseg_o3d.refinement.polish import bent_at_border_lines, border_sides, polish_models


def _load(name: str):  # the tests are not a package: their scenes by path
    spec = importlib.util.spec_from_file_location(f"_{name}", Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_one = _load("test_bend_on_one_side")
_two = _load("test_bent_on_two_sides")


@pytest.mark.parametrize("seed", [0, 1])
def test_one_side_off_gives_the_plane_of_the_rest_without_it(seed):
    ctx, labels, columns = _one._wide_face(seed)
    idx = np.flatnonzero(labels.ravel())
    sides = border_sides(labels, idx, False)
    assert np.array_equal(idx[sides[2]] % 40, np.full(21, columns[0] - 1))  # the left side: the mixed column
    out = bent_at_border_lines(ctx, labels, {1: fit_cylinder(ctx.xyz[idx])}, 1.0)
    expected = fit_plane(ctx.xyz[idx[~sides[2]]])
    assert list(out) == [1]
    assert out[1].normal @ expected.normal == pytest.approx(1.0, abs=1e-12)
    assert out[1].d == pytest.approx(expected.d, abs=1e-9) and out[1].rms == pytest.approx(expected.rms, rel=1e-9)


@pytest.mark.parametrize("seed", [0, 1])
def test_two_sides_off_give_the_plane_between_them_on_a_shallow_cylinder_only(seed):
    ctx, labels, columns = _two._two_sided(seed, "face")
    idx = np.flatnonzero(labels.ravel())
    points = ctx.xyz[idx]
    out = bent_at_border_lines(ctx, labels, {1: _two._face_cylinder(points)}, 1.0)
    middle = np.isin(idx % 40, columns)
    expected = fit_plane(points[middle])
    assert list(out) == [1]
    assert out[1].normal @ expected.normal == pytest.approx(1.0, abs=1e-12)
    assert out[1].d == pytest.approx(expected.d, abs=1e-9)
    # a plane region the decision bent (its plane kept) is asked one side only
    assert bent_at_border_lines(ctx, labels, {1: _two._face_cylinder(points)}, 1.0, kept={1}) == {}
    # no arc to weigh on a sphere: both sides off, and neither alone is the bend (the other one
    # lies off the plane between them), so it is left to its model
    sphere = Sphere(center=points.mean(axis=0) + np.array([2.0, 0.0, 2.0]), radius=2.8, rms=0.01, inliers=idx.size)
    assert bent_at_border_lines(ctx, labels, {1: sphere}, 1.0) == {}


def test_the_compiled_pass_only_skips_what_no_single_side_could_free(monkeypatch):
    ctx, labels, _ = _one._wide_face(0)
    assert polish._one_side_flat(ctx, labels, [1], 10) == {1}
    cylinder = fit_cylinder(ctx.xyz[labels.ravel() == 1])
    monkeypatch.setattr(polish, "_one_side_flat", lambda *a: set())
    assert bent_at_border_lines(ctx, labels, {1: cylinder}, 1.0) == {}
    ctx, labels, _ = _two._two_sided(0, "face")  # two sides are asked all the same
    cylinder = _two._face_cylinder(ctx.xyz[labels.ravel() == 1])
    assert list(bent_at_border_lines(ctx, labels, {1: cylinder}, 1.0)) == [1]


def test_polish_asks_it_once_for_curved_regions_and_bent_planes_alike(monkeypatch):
    # region 1: the one-sided face as a cylinder; region 2: the same face's returns 10 columns
    # to the right, a plane the decision bends
    ctx, labels, _ = _one._wide_face(0)
    xyz = ctx.xyz.reshape(40, 40, 3)
    two = np.zeros_like(labels)
    two[:, 10:] = np.where(labels[:, :30] == 1, 2, 0)
    assert not np.any(labels[two == 2]) and (two == 2).sum() == (labels == 1).sum()  # (on the wall alone)
    xyz = xyz.copy()
    xyz[:, 10:][two[:, 10:] == 2] = xyz[:, :30][labels[:, :30] == 1]
    ctx = _one._scenes._context(xyz)
    both = labels + two
    points = {k: ctx.xyz[both.ravel() == k] for k in (1, 2)}
    plane2, cylinder2 = fit_plane(points[2]), fit_cylinder(points[2])
    calls = []
    real = polish.bent_at_border_lines

    def spy(ctx, labels, curved, *a, **k):
        calls.append(dict(curved))
        return real(ctx, labels, curved, *a, **k)

    monkeypatch.setattr(polish, "bent_at_border_lines", spy)
    monkeypatch.setattr(polish, "_curved_planes", lambda ctx, labels, fits, *a, **k: {2: cylinder2})
    monkeypatch.setattr(polish, "_planes_off_rays", lambda ctx, labels, fits, **_: {})
    out = polish_models(ctx, both, {1: fit_cylinder(points[1]), 2: plane2}, resolve_bends=1.0, along_rays=True)
    assert len(calls) == 1 and sorted(calls[0]) == [1, 2] and calls[0][2] is cylinder2
    assert out[1].kind == "plane" and out[2] is plane2  # the curved region its rest's plane; the bent plane kept
