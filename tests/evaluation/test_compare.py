"""The method-versus-baselines comparison: configuration swapping and an end-to-end quick run."""

import argparse

import numpy as np
import pytest

from rangeseg_o3d.evaluation.compare import (
    SEGMENTERS,
    ScanRun,
    add_arguments,
    config_for,
    markdown_table,
    run,
    summarise,
)
from rangeseg_o3d.config import load_config
from rangeseg_o3d.pipeline import Pipeline
from rangeseg_o3d.result import Result
from rangeseg_o3d.synthetic.suite import lms200_scenes
from rangeseg_o3d.synthetic.lms200 import simulate_lms200


@pytest.fixture(scope="module")
def lms_scan():
    return simulate_lms200(lms200_scenes()[0][1], seed=0)


@pytest.mark.parametrize("preset", ["lms200", "rgbd_vga"])
def test_region_growing_presets_are_the_sensor_presets_with_another_segmenter(preset):
    base = load_config(preset)
    rg = load_config(f"{preset}_region_growing")
    assert rg.segmenter.name == "region_growing"
    assert rg.fitter == base.fitter
    assert rg.tile == 1  # region growing thins points on its own voxel grid
    assert rg.sensor == base.sensor
    # Same refinement; the region size and jump test are the refinement's defaults, which
    # it used before they were explicit (region growing has no such parameters).
    expected = base.refine.model_copy(update={"min_region_size": 30, "jump_ratio": 0.08,
                                              "jump_min": 0.05})
    assert rg.refine == expected


def test_configuration_switches_the_segmenter(lms_scan):
    pipeline = Pipeline(load_config("lms200_region_growing"))
    assert pipeline.segmenter.name == "region_growing"
    result = pipeline.run(lms_scan.cloud)
    assert isinstance(result, Result)
    assert result.labels.shape == (70, 131)
    assert {"knn", "normals", "growth"} <= set(result.timings)  # region growing's own stages ran
    assert len(result.features) >= 5


@pytest.mark.parametrize("segmenter", SEGMENTERS)
def test_config_for_swaps_only_the_segmenter(segmenter):
    base = load_config("lms200")
    cfg = config_for("lms200", segmenter)
    assert cfg.segmenter.name == segmenter
    assert cfg.fitter == base.fitter
    assert cfg.refine.grow_iterations == base.refine.grow_iterations
    assert cfg.sensor == base.sensor
    if segmenter == "region_growing":
        assert cfg.segmenter.params == load_config("lms200_region_growing").segmenter.params


@pytest.mark.parametrize("segmenter", SEGMENTERS)
def test_only_residual_edges_works_on_the_presets_tile_means(segmenter):
    # the depth-camera preset's tiles belong to the residual-edge method; the
    # baselines see the points as their users would (region growing: its own preset)
    cfg = config_for("rgbd_vga", segmenter)
    expected = 6 if segmenter == "residual_edges" else load_config("rgbd_vga_region_growing").tile
    assert cfg.tile == expected


def _run(segmenter, suite, seconds, correct, n_truth=10):
    hoover = dict(n_truth=n_truth, correct=correct, over=1, under=0, missed=n_truth - correct - 1, noise=2)
    return ScanRun(segmenter, suite, "s", 9000, seconds, correct, {}, segment_seconds=seconds / 2,
                   hoover=hoover, false_fittings=0)


def test_summary_sums_counts_and_gives_ratio_to_residual_edges():
    runs = [_run("residual_edges", "lms200", 0.002, 9), _run("residual_edges", "lms200", 0.004, 8),
            _run("region_growing", "lms200", 0.100, 7), _run("region_growing", "lms200", 0.060, 9)]
    rows = {r["segmenter"]: r for r in summarise(runs)}
    assert rows["residual_edges"]["correct"] == 17 and rows["residual_edges"]["n_truth"] == 20
    assert rows["residual_edges"]["correct_pct"] == pytest.approx(85.0)
    assert rows["region_growing"]["median_ms"] == pytest.approx(80.0)
    assert rows["region_growing"]["time_ratio"] == pytest.approx(80.0 / 3.0)
    assert rows["residual_edges"]["time_ratio"] == pytest.approx(1.0)
    assert rows["region_growing"]["median_segment_ms"] == pytest.approx(40.0)
    assert rows["region_growing"]["segment_ratio"] == pytest.approx(80.0 / 3.0)
    table = markdown_table(list(rows.values()))
    assert table.count("\n") == 3 and "| 26.7 |" in table


def test_real_scans_without_truth_show_dashes():
    runs = [ScanRun("o3d_ransac_planes", "real", "x", 1000, 0.5, 3, {"plane": 3})]
    (row,) = summarise(runs)
    assert "correct" not in row and np.isnan(row["time_ratio"])  # no residual_edges run to compare
    line = markdown_table([row]).splitlines()[-1]
    assert "(planes only)" in line and "| - |" in line and "n/a" in line


def _args(**kw):
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args([f"--{k.replace('_', '-')}={v}" if v is not True else f"--{k.replace('_', '-')}"
                              for k, v in kw.items()])


@pytest.mark.slow
def test_quick_comparison_runs_end_to_end(tmp_path, capsys):
    assert run(_args(quick=True, repeats=1, out_dir=tmp_path)) == 0
    out = capsys.readouterr().out
    for name in SEGMENTERS:
        assert name in out
    md = (tmp_path / "compare.md").read_text()
    assert "| lms200 | residual_edges |" in md and "| rgbd | region_growing |" in md
    assert "(planes only)" in md and "max / min time per point" in md
    for png in ("time_vs_points.png", "quality.png", "region_growing_scaling.png"):
        data = (tmp_path / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 1000
    assert not list(tmp_path.glob("*.tmp*"))  # atomic writes left nothing behind


def test_bad_options_raise(tmp_path):
    with pytest.raises(ValueError, match="--segmenters"):
        run(_args(quick=True, segmenters="nope", out_dir=tmp_path))
    with pytest.raises(ValueError, match="--repeats"):
        run(_args(quick=True, repeats=0, out_dir=tmp_path))


def test_rangeseg_cli_has_the_compare_subcommand(capsys):
    from rangeseg_o3d.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["compare", "--help"])
    assert exc.value.code == 0
    assert "--segmenters" in capsys.readouterr().out
