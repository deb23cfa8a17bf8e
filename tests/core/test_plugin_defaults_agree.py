"""A built-in plugin's defaults are written in its parameter model and its functions' signatures: they must agree."""

import inspect

import pytest

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
