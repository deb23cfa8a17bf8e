import ast
import subprocess
import sys

import pytest


@pytest.mark.slow
def test_import_does_not_pull_heavy_or_device_modules():
    code = (
        "import sys, numpy as np, rangeseg_o3d as rs\n"
        "from rangeseg_o3d.synthetic.lms200 import simulate_lms200\n"
        "from rangeseg_o3d.synthetic.suite import default_scene\n"
        "r = rs.Pipeline('lms200').run(simulate_lms200(default_scene(), seed=0).cloud)\n"
        "assert r.features\n"
        "print(sorted(m for m in ('open3d', 'rerun', 'serial') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


CONFIG_EDGE = ("pydantic", "yaml", "cv2", "numba", "scipy", "open3d", "rerun", "serial")


def _loaded_after(statement: str) -> list[str]:
    # which of CONFIG_EDGE a fresh interpreter has loaded after ``statement``
    code = f"import sys\n{statement}\nprint(sorted(m for m in {CONFIG_EDGE!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return ast.literal_eval(out.stdout.strip())


@pytest.mark.parametrize("statement", [
    "import rangeseg_o3d",
    "import rangeseg_o3d.segmentation.residual",
    "import rangeseg_o3d.segmentation.edges",
    "import rangeseg_o3d.segmentation.regions",
    "from rangeseg_o3d.segmentation import residual, edges, regions",
    "from rangeseg_o3d.segmentation import residual_image, label_regions, crease_edges",
    "from rangeseg_o3d.evaluation import evaluate, hoover, parameter_errors",
])
def test_importing_the_package_or_a_stage_loads_no_config_or_image_library(statement):
    assert _loaded_after(statement) == []


def test_a_stage_loads_opencv_only_when_it_runs():
    statement = ("import numpy as np\nfrom rangeseg_o3d.segmentation.regions import label_regions\n"
                 "assert label_regions(np.zeros((40, 40), bool), min_size=1).max() == 1")
    assert _loaded_after(statement) == ["cv2"]


def test_public_names_load_on_first_use():
    import rangeseg_o3d as rs

    assert set(rs.__all__) <= set(dir(rs))
    for name in rs.__all__:
        assert getattr(rs, name).__name__ == name
    assert rs.registry.get("fitter", "primitives").name == "primitives"  # submodules too
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        rs.no_such_name
    assert _loaded_after("import rangeseg_o3d as rs\nrs.Plane") == []
    assert "pydantic" in _loaded_after("import rangeseg_o3d as rs\nrs.load_config")


def test_plain_import_leaves_the_compiler_for_first_use():
    # numba costs ~0.5 s to import: the first fit or scan pays it, not the import.
    code = ("import sys, rangeseg_o3d as rs; print('numba' in sys.modules); "
            "print(rs.fit_plane([[0, 0, 1], [1, 0, 1], [0, 1, 1]]).d, 'numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "1.0", "True"]


def test_warm_up_with_a_helper_process_waits_for_it_and_the_helper_succeeds(monkeypatch):
    from rangeseg_o3d.pipeline import warm_up

    started = []

    class Recorded(subprocess.Popen):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            started.append(self)

    monkeypatch.setattr(subprocess, "Popen", Recorded)
    assert warm_up(processes=2) > 0.0
    # one helper, ended (returncode set) by the time warm_up returns, and without an error
    assert [helper.returncode for helper in started] == [0]


@pytest.mark.parametrize("processes", [0, -1, 1.5, "2", True])
def test_warm_up_refuses_a_process_count_that_is_not_a_whole_number_from_1(processes):
    from rangeseg_o3d.pipeline import warm_up

    with pytest.raises(ValueError, match="processes must be a whole number >= 1"):
        warm_up(processes=processes)


def test_warm_up_compiles_the_kernels_the_presets_use():
    from rangeseg_o3d import kernels
    from rangeseg_o3d.fitting import _compiled, _decide
    from rangeseg_o3d.pipeline import warm_up

    assert warm_up() > 0.0
    for kernel in (kernels.label_moments, kernels.grow_rings, kernels.label_pixels, kernels.leftover_blobs,
                   kernels.block_means, kernels.distance_stats, kernels.window_residuals, kernels.crease_sides,
                   kernels.crease_moves,
                   _compiled.prepare_points, _decide.primitive_decision,
                   _decide.curved_refit, _decide.sphere_checked, _decide.cylinder_checked):
        assert kernel.signatures, f"{kernel.__name__} was not compiled"
