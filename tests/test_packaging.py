"""What a wheel or sdist carries: every package of the tree and the presets."""

from __future__ import annotations

from pathlib import Path

import pytest

from rangeseg_o3d.config import load_config, preset_dir, presets

ROOT = Path(__file__).resolve().parent.parent


def test_pyproject_lists_every_package_of_the_tree():
    # pyproject.toml names its packages explicitly (the presets are a package mapped from
    # configs/); a package added to the tree but not to that list would be missing from the wheel.
    tomllib = pytest.importorskip("tomllib", reason="tomllib is Python >= 3.11")
    declared = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(init.parent.relative_to(ROOT).parts)
             for init in (ROOT / "rangeseg_o3d").rglob("__init__.py")}
    assert found - declared == set(), "add these to [tool.setuptools] packages in pyproject.toml"
    assert declared - found == {"rangeseg_o3d.configs"}


def test_presets_are_the_top_level_configs_in_a_checkout():
    assert preset_dir() == ROOT / "configs"
    assert presets() == sorted(p.stem for p in (ROOT / "configs").glob("*.yaml"))
    assert {"lms200", "rgbd_vga", "sick_3dtk", "tls_andreashaus"} <= set(presets())


def test_preset_found_by_name_from_another_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert load_config("rgbd_vga").tile == 6
