from importlib.metadata import EntryPoint

import pytest
from pydantic import BaseModel

import rangeseg_o3d as rs
from rangeseg_o3d import registry
from rangeseg_o3d.config import load_config, presets


def test_presets_load_and_name_their_sensor():
    assert {"lms200", "rgbd_vga"} <= set(presets())
    lms = load_config("lms200")
    assert lms.name == "lms200"
    assert lms.segmenter.name == "residual_edges"
    assert lms.sensor.sigma0 == pytest.approx(0.005)
    rgbd = load_config("configs/rgbd_vga.yaml")
    assert rgbd.sensor.sigma_quadratic > 0


def test_defaults_are_completed_from_the_plugin_models():
    cfg = load_config({"segmenter": {"name": "residual_edges", "params": {"threshold": 5}}})
    assert cfg.segmenter.params["threshold"] == 5
    assert cfg.segmenter.params["window"] == 3
    assert "plane_rms" in cfg.fitter.params


def test_validation_error_names_field_and_value():
    with pytest.raises(ValueError, match=r"segmenter\.params\.threshold.*-1"):
        load_config({"segmenter": {"name": "residual_edges", "params": {"threshold": -1}}})
    with pytest.raises(ValueError, match=r"segmenter\.params\.windw"):
        load_config({"segmenter": {"name": "residual_edges", "params": {"windw": 3}}})
    with pytest.raises(ValueError, match=r"refine\.k_sigma"):
        load_config({"refine": {"k_sigma": 0}})
    with pytest.raises(ValueError, match="window must be odd"):
        load_config({"segmenter": {"name": "residual_edges", "params": {"window": 4}}})


def test_unknown_names_list_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown segmenter 'nope'.*residual_edges"):
        load_config({"segmenter": {"name": "nope"}})
    with pytest.raises(ValueError, match="unknown preset 'nope'.*lms200"):
        load_config("nope")


def test_bad_yaml_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("segmenter: [1, 2\n")
    with pytest.raises(ValueError, match="not valid YAML"):
        load_config(bad)
    bad.write_text("- 1\n- 2\n")
    with pytest.raises(ValueError, match="mapping"):
        load_config(bad)
    with pytest.raises(ValueError, match="does not exist"):
        load_config(tmp_path / "missing.yaml")


class _Params(BaseModel):
    level: int = 1


def _constant_segmenter(cloud, *, level=1):
    import numpy as np

    return rs.Segmentation(labels=np.where(cloud.valid, level, 0).astype("int32"))


PLUGIN = rs.Plugin(name="constant_test", config=_Params, run=_constant_segmenter)


def test_entry_point_plugins_register_and_run():
    ep = EntryPoint(name="constant_test", value=f"{__name__}:PLUGIN", group="rangeseg_o3d.segmenters")
    assert registry.load_entry_points("segmenter", [ep]) == ["constant_test"]
    assert "constant_test" in registry.available("segmenter")
    cfg = load_config({"segmenter": {"name": "constant_test", "params": {"level": 1}}})
    import numpy as np

    xyz = np.zeros((4, 5, 3))
    xyz[..., 0], xyz[..., 1] = np.meshgrid(np.arange(5.0), np.arange(4.0))
    xyz[..., 2] = 2.0
    result = rs.Pipeline(cfg).run(rs.OrganizedCloud(xyz))
    assert result.labels.max() == 1 and result.features[0].kind == "plane"


def test_broken_plugin_warns_instead_of_crashing():
    ep = EntryPoint(name="broken", value="no_such_module_xyz:PLUGIN", group="rangeseg_o3d.segmenters")
    with pytest.warns(RuntimeWarning, match="broken"):
        assert registry.load_entry_points("segmenter", [ep]) == []
    ep = EntryPoint(name="wrong", value="math:pi", group="rangeseg_o3d.segmenters")
    with pytest.warns(RuntimeWarning, match="wrong"):
        assert registry.load_entry_points("segmenter", [ep]) == []


def test_register_rejects_duplicates_and_bad_kinds():
    with pytest.raises(ValueError, match="already registered"):
        registry.register("segmenter", rs.Plugin("residual_edges", _Params, _constant_segmenter))
    with pytest.raises(ValueError, match="kind must be one of"):
        registry.get("painter", "x")
    with pytest.raises(TypeError):
        registry.register("fitter", object())
