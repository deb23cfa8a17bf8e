import subprocess
import sys


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


def test_plain_import_leaves_the_compiler_for_first_use():
    # numba costs ~0.5 s to import: the first fit or scan pays it, not the import.
    code = ("import sys, rangeseg_o3d as rs; print('numba' in sys.modules); "
            "print(rs.fit_plane([[0, 0, 1], [1, 0, 1], [0, 1, 1]]).d, 'numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "1.0", "True"]


def test_warm_up_compiles_the_kernels_the_presets_use():
    from rangeseg_o3d import kernels
    from rangeseg_o3d.fitting import _compiled, _decide
    from rangeseg_o3d.pipeline import warm_up

    assert warm_up() > 0.0
    for kernel in (kernels.label_moments, kernels.grow_rings, kernels.assign_tiles,
                   kernels.block_means, kernels.distance_stats, kernels.window_moments,
                   kernels.smallest_eigenvalues, _compiled.prepare_points, _decide.primitive_decision,
                   _decide.curved_refit, _decide.sphere_checked, _decide.cylinder_checked):
        assert kernel.signatures, f"{kernel.__name__} was not compiled"
