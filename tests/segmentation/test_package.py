"""rangeseg_o3d.segmentation re-exports every stage module's public names, lazily."""

import importlib

import pytest

from rangeseg_o3d import segmentation


@pytest.mark.parametrize("stage", sorted(segmentation._SOURCES))
def test_the_package_lists_exactly_the_names_each_stage_defines(stage):
    module = importlib.import_module(f"rangeseg_o3d.segmentation.{stage}")
    # names a stage re-exports from elsewhere (residual's noise_sigma is the sensor's) stay there
    defined = {name for name in module.__all__
               if getattr(getattr(module, name), "__module__", module.__name__) == module.__name__}
    assert set(segmentation._SOURCES[stage]) == defined
    for name in defined:
        assert getattr(segmentation, name) is getattr(module, name)


def test_stage_modules_resolve_as_attributes_and_unknown_names_fail():
    assert segmentation.edges is importlib.import_module("rangeseg_o3d.segmentation.edges")
    assert set(segmentation.__all__) <= set(dir(segmentation))
    with pytest.raises(AttributeError, match="has no attribute 'no_such_stage'"):
        segmentation.no_such_stage
