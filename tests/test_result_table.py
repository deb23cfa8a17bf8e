"""Result.table: the text the CLI prints, one line per feature with its parameters."""

import re

import numpy as np
import pytest

import rangeseg_o3d as rs


@pytest.fixture(scope="module")
def result():
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    return rs.Pipeline("lms200").run(simulate_lms200(default_scene(), seed=1).cloud)


def _rows(text: str) -> dict[int, str]:
    rows = {}
    for line in text.splitlines():
        match = re.match(r"\s*(\d+)\s+(plane|cylinder|sphere|unfitted)\s", line)
        if match:
            rows[int(match.group(1))] = line
    return rows


def test_one_row_per_feature_and_unfitted_region_under_the_title(result):
    text = result.table(title="scan 7")
    assert text.splitlines()[0] == "scan 7"
    rows = _rows(text)
    assert set(rows) == {f.label for f in result.features} | {u.label for u in result.unfitted}
    for f in result.features:
        assert f" {f.kind} " in rows[f.label]
        assert f" {f.n_pixels} " in rows[f.label]


def test_rows_carry_the_fitted_parameters_to_a_millimetre(result):
    rows = _rows(result.table())
    planes = [f for f in result.features if f.kind == "plane"]
    assert planes, "the default scene has planes"
    for f in planes:
        n = re.search(r"n=\(([-+.\d]+), ([-+.\d]+), ([-+.\d]+)\) d=([-+.\d]+) m", rows[f.label])
        np.testing.assert_allclose([float(v) for v in n.groups()[:3]], f.normal, atol=5e-4)
        assert float(n.group(4)) == pytest.approx(f.d, abs=5e-4)
    for f in result.features:
        if f.kind != "plane":
            radius = re.search(r"r=([.\d]+) m", rows[f.label])
            assert float(radius.group(1)) == pytest.approx(f.radius, abs=5e-4)


def test_closing_lines_count_the_kinds_and_list_the_timings(result):
    lines = result.table().splitlines()
    counts = result.counts()
    named = {"plane": "planes", "cylinder": "cylinders", "sphere": "spheres"}
    kinds = [f"{counts[k]} {k if counts[k] == 1 else named[k]}" for k in named]
    assert lines[-2] == ", ".join(kinds) + f", {counts['unfitted']} unfitted"
    assert lines[-1].startswith("timings: ")
    assert all(name in lines[-1] for name in result.timings)
    assert "scan" not in lines[0]  # no title line when none is given


def test_a_single_feature_of_a_kind_is_counted_in_the_singular():
    from rangeseg_o3d.result import counted

    assert [counted(n, "sphere") for n in (0, 1, 2)] == ["0 spheres", "1 sphere", "2 spheres"]
