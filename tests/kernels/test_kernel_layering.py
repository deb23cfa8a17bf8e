"""kernels/ is the bottom layer: it imports nothing else of rangeseg_o3d, and its kinds are the decision's."""

import ast
from pathlib import Path

import numpy as np
import pytest

import rangeseg_o3d
from rangeseg_o3d.kernels import kinds

KERNELS = Path(rangeseg_o3d.__file__).parent / "kernels"


def _imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file at ``path`` (relative ones resolved)."""
    package = "rangeseg_o3d.kernels"
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                name = f"{base}.{node.module}" if node.module else base
            else:
                name = node.module
            found.append((node.lineno, name))
            if node.module is None:  # "from . import x": x may be a module
                found += [(node.lineno, f"{name}.{alias.name}") for alias in node.names]
    return found


def test_the_scan_resolves_relative_imports(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("from ..fitting import _compiled\nfrom .grid import x\nimport numpy\n"
                     "from . import linalg\n")
    assert _imported_modules(probe) == [(1, "rangeseg_o3d.fitting"), (2, "rangeseg_o3d.kernels.grid"),
                                        (3, "numpy"), (4, "rangeseg_o3d.kernels"),
                                        (4, "rangeseg_o3d.kernels.linalg")]


def test_kernels_import_nothing_from_the_rest_of_the_package():
    files = sorted(KERNELS.glob("*.py"))
    assert len(files) >= 7, files  # the scan really looked at the kernel modules
    outside = [f"{path.name}:{line} imports {name}" for path in files
               for line, name in _imported_modules(path)
               if (name == "rangeseg_o3d" or name.startswith("rangeseg_o3d."))
               and not (name == "rangeseg_o3d.kernels" or name.startswith("rangeseg_o3d.kernels."))]
    assert outside == []


def test_the_kinds_table_is_the_decisions_and_the_model_tables():
    from rangeseg_o3d.fitting.region_fitter import model_table
    from rangeseg_o3d.fitting import Cylinder, Plane, Sphere

    assert [int(k) for k in kinds.ModelKind] == [kinds.NONE, kinds.PLANE, kinds.SPHERE, kinds.CYLINDER]
    models = {1: Plane([0, 0, 1], 1.0, 0.0, 3), 2: Sphere([0, 0, 2], 0.5, 0.0, 4),
              3: Cylinder([0, 1, 0], [0, 0, 3], 0.2, 0.0, 5)}
    table_kinds, params, _ = model_table(models, 5)
    assert table_kinds.tolist() == [kinds.NONE, kinds.PLANE, kinds.SPHERE, kinds.CYLINDER, kinds.NONE]
    assert params.shape == (5, kinds.PARAM_SLOTS)
    assert [kinds.kind_of(m.kind) for m in models.values()] == [kinds.PLANE, kinds.SPHERE, kinds.CYLINDER]
    with pytest.raises(ValueError, match="model kind must be one of plane, sphere, cylinder; got 'cone'"):
        kinds.kind_of("cone")


def test_the_decision_answers_by_name_in_the_same_kinds():
    from rangeseg_o3d.fitting import _decide
    from rangeseg_o3d.fitting.classify import fit_primitive

    rng = np.random.default_rng(0)
    angle, along = rng.uniform(0, 2.5, 400), rng.uniform(-0.5, 0.5, 400)
    pts = np.c_[2.0 + 0.3 * np.cos(angle), along, 1.0 + 0.3 * np.sin(angle)] + rng.normal(0, 0.001, (400, 3))
    seen = {}
    original = _decide.decide

    def spy(*args):
        seen["decision"] = original(*args)
        return seen["decision"]

    _decide.decide = spy
    try:
        model = fit_primitive(pts)
    finally:
        _decide.decide = original
    decision = seen["decision"]
    assert isinstance(decision, _decide.Decision)
    assert decision.kind == kinds.CYLINDER == kinds.kind_of(model.kind)
    assert decision.status == _decide.ACCEPTED and decision.first == kinds.CYLINDER
    assert decision.codes[kinds.CYLINDER] == _decide.ACCEPTED
    assert decision.plane_rms > decision.plane_tolerance or decision.plane_rms > 1.5 * model.rms
    assert abs(decision.curved[kinds.CYLINDER, _decide.RADIUS] * decision.scale - 0.3) < 0.01


def test_the_kernel_package_loads_lazily():
    import subprocess
    import sys

    code = ("import sys; import rangeseg_o3d.kernels as k; from rangeseg_o3d.kernels import kinds;"
            "print('numba' in sys.modules); k.label_moments; print('numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "True"]
