"""fitting.primitives: dataclasses.replace of a model's fit statistics, faster (with_statistics); a
model's vector fields checked."""

from dataclasses import replace

import numpy as np
import pytest

from rangeseg_o3d.fitting.primitives import Cylinder, FitFailure, Plane, Sphere, with_statistics

MODELS = [Plane([0.0, 0.6, 0.8], 2.5, 0.004, 120),
          Sphere([0.1, -0.2, 1.5], 0.25, 0.002, 80),
          Cylinder([0.0, 0.0, 1.0], [0.3, 0.1, 0.0], 0.05, 0.001, 300)]


def _fields(model) -> dict:
    return {name: value for name, value in vars(model).items()}


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.kind)
@pytest.mark.parametrize("changes", [{"rms": 0.0125}, {"inliers": 7}, {"rms": 0.5, "inliers": 0}])
def test_with_statistics_is_replace_for_the_statistics(model, changes):
    fast, slow = with_statistics(model, **changes), replace(model, **changes)
    assert type(fast) is type(model) and fast is not model
    assert _fields(fast).keys() == _fields(slow).keys()
    for name, value in _fields(slow).items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(getattr(fast, name), value)
            assert getattr(fast, name) is getattr(model, name)  # shared, read-only, as replace shares it
            assert not getattr(fast, name).flags.writeable
        else:
            assert getattr(fast, name) == value and type(getattr(fast, name)) is type(value)
    # the original is untouched, and the copy stays frozen
    assert (model.rms, model.inliers) != (fast.rms, fast.inliers)
    with pytest.raises(AttributeError):
        fast.rms = 1.0
    points = np.array([[0.0, 0.0, 2.0], [0.3, 0.2, 1.4], [0.1, 0.1, 0.1]])
    np.testing.assert_array_equal(fast.distances(points), slow.distances(points))


def test_other_changes_and_other_models_go_through_replace():
    plane = MODELS[0]
    moved = with_statistics(plane, d=3.0, rms=0.01)
    assert moved.d == 3.0 and moved.rms == 0.01 and moved.normal is plane.normal
    turned = with_statistics(plane, normal=[1, 0, 0])  # checked and frozen by the model itself
    assert not turned.normal.flags.writeable and turned.normal.tolist() == [1.0, 0.0, 0.0]
    with pytest.raises(ValueError):
        with_statistics(plane, normal=[1, 0])  # a bad vector is refused as replace refuses it
    failure = with_statistics(FitFailure("plane", "too few points"), rms=0.1)
    assert not failure and failure.rms == 0.1 and failure.reason == "too few points"


@pytest.mark.parametrize("make, field, got", [
    (lambda: Plane([0.0, 1.0], 1.0, 0.0, 3), "normal", r"shape \(2,\)"),
    (lambda: Sphere(np.zeros((2, 3)), 1.0, 0.0, 3), "center", r"shape \(2, 3\)"),
    (lambda: Cylinder([0.0, 0.0, 1.0], "origin", 1.0, 0.0, 3), "point", "str 'origin'"),
    (lambda: Cylinder(None, np.zeros(3), 1.0, 0.0, 3), "axis", r"shape \(\)"),
])
def test_a_model_built_with_a_vector_not_of_three_numbers_names_the_field(make, field, got):
    with pytest.raises(ValueError, match=rf"{field} must be 3 numbers; got {got}"):
        make()
    assert Plane(np.array([[0.0], [0.0], [1.0]]), 1.0, 0.0, 3).normal.shape == (3,)  # a column still reads
