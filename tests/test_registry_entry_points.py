"""Entry points: discovered once, a plugin that shadows a built-in warned about and never used."""

from importlib.metadata import EntryPoint

import pytest
from pydantic import BaseModel

import rangeseg_o3d as rs
from rangeseg_o3d import registry


class _NoParams(BaseModel):
    pass


def _never(cloud):
    raise AssertionError("the shadowing plugin must not run")


SHADOW = rs.Plugin(name="residual_edges", config=_NoParams, run=_never)
OTHER = rs.Plugin(name="entry_point_test_a", config=_NoParams, run=_never)
SAME_NAME = rs.Plugin(name="entry_point_test_a", config=_NoParams, run=_never, description="second")


def _ep(name, attr):
    return EntryPoint(name=name, value=f"{__name__}:{attr}", group="rangeseg_o3d.segmenters")


@pytest.fixture
def fresh_registry(monkeypatch):
    """The registry as in a new process, with the installed entry points replaced by ``installed``."""
    installed = []
    calls = []

    def fake_entry_points(*, group):
        calls.append(group)
        return list(installed)

    monkeypatch.setattr(registry, "entry_points", fake_entry_points)
    monkeypatch.setattr(registry, "_FROM_ENTRY_POINTS", {"segmenter": {}, "fitter": {}})
    monkeypatch.setattr(registry, "_ENTRY_POINTS_LOADED", set())
    registry.installed_entry_points.cache_clear()
    yield installed, calls
    registry.installed_entry_points.cache_clear()


def test_entry_points_are_discovered_once(fresh_registry):
    installed, calls = fresh_registry
    installed.append(_ep("entry_point_test_a", "OTHER"))
    assert "entry_point_test_a" in registry.available("segmenter")
    assert registry.get("segmenter", "entry_point_test_a") is OTHER
    with pytest.raises(ValueError, match="unknown segmenter 'nope'"):
        registry.get("segmenter", "nope")
    registry.available("segmenter")
    assert calls == ["rangeseg_o3d.segmenters"]


def test_a_plugin_shadowing_a_built_in_is_warned_about_and_never_used(fresh_registry):
    installed, _ = fresh_registry
    installed.append(_ep("residual_edges", "SHADOW"))
    builtin = registry.get("segmenter", "residual_edges")  # before the entry points are loaded
    with pytest.warns(RuntimeWarning) as caught:
        names = registry.available("segmenter")
    message = str(caught[0].message)
    assert f"{__name__}:SHADOW" in message  # the plugin ...
    assert "rangeseg_o3d.segmenters.residual_edges:PLUGIN" in message  # ... and the built-in it shadows
    assert names.count("residual_edges") == 1
    assert registry.get("segmenter", "residual_edges") is builtin is not SHADOW  # after: the same


def test_two_entry_points_with_one_name_keep_the_first(fresh_registry):
    installed, _ = fresh_registry
    installed += [_ep("a", "OTHER"), _ep("b", "SAME_NAME")]
    with pytest.warns(RuntimeWarning, match=f"{__name__}:SAME_NAME.*{__name__}:OTHER"):
        registry.available("segmenter")
    assert registry.get("segmenter", "entry_point_test_a") is OTHER


def test_a_plugin_registered_in_code_comes_first(fresh_registry, monkeypatch):
    installed, _ = fresh_registry
    installed.append(_ep("entry_point_test_a", "OTHER"))
    mine = rs.Plugin(name="entry_point_test_a", config=_NoParams, run=_never, description="mine")
    monkeypatch.setitem(registry._REGISTERED["segmenter"], "entry_point_test_a", mine)
    with pytest.warns(RuntimeWarning, match="registered in code"):
        registry.available("segmenter")
    assert registry.get("segmenter", "entry_point_test_a") is mine


def test_loading_the_same_entry_point_twice_is_quiet(fresh_registry, recwarn):
    ep = _ep("entry_point_test_a", "OTHER")
    assert registry.load_entry_points("segmenter", [ep]) == ["entry_point_test_a"]
    assert registry.load_entry_points("segmenter", [ep]) == ["entry_point_test_a"]
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
