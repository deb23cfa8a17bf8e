"""A plugin's defaults are written once, in its function's signature: the parameter model is
read off it (registry.params_model) and the other hooks take its defaults (registry.defaults_of)."""

import inspect

import pytest
from pydantic import Field, ValidationError

from rangeseg_o3d import registry

HOOKS = ("run", "refit", "fit_batch", "refit_moments")


def _keyword_defaults(function) -> dict:
    return {name: p.default for name, p in inspect.signature(function).parameters.items()
            if p.default is not inspect.Parameter.empty}


@pytest.mark.parametrize("kind, name", [(kind, name) for kind in registry.GROUPS
                                        for name in sorted(registry._BUILTIN[kind])])
def test_model_defaults_equal_the_signature_defaults(kind, name):
    plugin = registry.get(kind, name)
    model = {field: info.default for field, info in plugin.config.model_fields.items()}
    checked = 0
    for hook in HOOKS:
        function = getattr(plugin, hook)
        if function is None:
            continue
        signature = _keyword_defaults(function)
        common = set(model) & set(signature)
        assert {k: (model[k], signature[k]) for k in common if model[k] != signature[k]} == {}, hook
        checked += len(common)
    assert checked > 0  # the model and the functions share keywords: something was compared


def test_a_disagreement_would_be_caught(monkeypatch):
    plugin = registry.get("fitter", "primitives")
    info = plugin.config.model_fields["plane_rms"]
    monkeypatch.setattr(info, "default", 0.02)
    with pytest.raises(AssertionError):
        test_model_defaults_equal_the_signature_defaults("fitter", "primitives")


def _segment(cloud, *, sensor=None, window: int = 5, spacing: float | None = None, seed: int = 0):
    """A stand-in plugin function."""


def test_the_model_takes_types_defaults_and_constraints_from_the_signature():
    model = registry.params_model(_segment, dict(window=dict(ge=3), spacing=dict(gt=0),
                                                 gain=(float, Field(2.0, ge=1))), name="Params")
    assert list(model.model_fields) == ["window", "spacing", "gain"]
    assert model().model_dump() == {"window": 5, "spacing": None, "gain": 2.0}
    assert model(window="7").window == 7  # the signature's int
    for bad in (dict(window=2), dict(spacing=0.0), dict(gain=0.5), dict(seed=1), dict(window="many")):
        with pytest.raises(ValidationError):
            model(**bad)


def test_a_field_the_function_does_not_take_is_refused_at_import():
    with pytest.raises(ValueError, match="no keyword 'windw' with a default"):
        registry.params_model(_segment, dict(windw={}), name="Params")
    with pytest.raises(ValueError, match="no keyword 'cloud'"):
        registry.params_model(_segment, dict(cloud={}), name="Params")


def test_hooks_take_the_defaults_of_the_run_function():
    @registry.defaults_of(_segment)
    def hook(points, *, window: int, seed: int = 3):
        return window, seed

    assert hook(None) == (5, 3)  # run's window, its own seed
    assert hook(None, window=9) == (9, 3)
    with pytest.raises(ValueError, match="no default for \\['other'\\]"):
        registry.defaults_of(_segment)(lambda *, other: other)


def test_the_residual_image_and_the_segmenter_share_min_valid():
    from rangeseg_o3d.segmentation.residual import MIN_VALID, residual_image
    from rangeseg_o3d.segmenters.residual_edges import ResidualEdgesConfig, segment_residual_edges

    assert (_keyword_defaults(residual_image)["min_valid"] == _keyword_defaults(segment_residual_edges)["min_valid"]
            == ResidualEdgesConfig().min_valid == MIN_VALID)
