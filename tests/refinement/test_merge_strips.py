"""Planes on strips one or two grid lines across a column tell no bend of their own; the merge
of planes into curved regions must still try them (refinement.merge.planes_into_curved)."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.evaluation import evaluate
from rangeseg_o3d.synthetic.matrix import get_sensor, matrix_rng


def test_parallel_lines_of_returns_on_a_column_fit_a_plane_whatever_its_radius():
    # two lines of points along a vertical column's axis (as two columns of a nodding laser
    # see it): the least-squares plane through them leaves nothing, so no bend test on the
    # strip can see the column
    angles = np.radians([0.0, 1.0])
    z = np.linspace(-0.5, 0.5, 20)
    points = np.concatenate([np.column_stack([np.full_like(z, 0.3 * np.cos(a)), np.full_like(z, 0.3 * np.sin(a)), z])
                             for a in angles])
    plane = rs.fit_plane(points)
    assert plane.rms < 1e-12


@pytest.fixture(scope="module")
def noise_2mm():
    spec = get_sensor("noise_2mm")
    config = rs.load_config(spec.preset, overrides={f"sensor.{k}": v for k, v in spec.sensor_facts().items()})
    return spec, rs.Pipeline(config)


def test_a_column_cut_into_narrow_strips_is_one_cylinder(noise_2mm):
    # matrix scan (study seed 37, scan 7): a vertical column of radius 0.295 m at ~4.7 m,
    # about 7 columns wide, its lower part left to the recovery as strips of one and two
    # columns (each a plane within the 2 mm noise); the pieces were scored as one surface
    # split in five (two planes of two columns, two of one, and the upper part's cylinder)
    spec, pipeline = noise_2mm
    made = spec.simulate(matrix_rng(37, spec.name, 7), False)
    result = pipeline.run(made.cloud)
    score = evaluate(made, result, tolerance=0.8, min_region=60)
    assert 13 in score.hoover.correct
    feature = next(f for f in result.features if f.label == score.hoover.correct[13])
    truth = made.truth[13]
    assert feature.kind == "cylinder"
    assert abs(feature.radius - truth.radius) < 0.1 * truth.radius
    assert abs(abs(float(feature.axis @ truth.axis)) - 1.0) < 1e-3
