"""A pipe's end cap, taken into its cylinder's region by the segmentation, comes back as its own plane.

On a spinning lidar (1.5 cm range noise) a cylinder's region that took the cap fits within
the range noise: the flanks of the pipe are seen at grazing incidence, where the noise of a
point's distance to the surface is far below the range noise. Against that noise
(:func:`rangeseg_o3d.fitting.robust.distance_noise`) the region is beyond it, and the
facets step gives the cap back, each pixel to the nearer model.
"""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.evaluation import evaluate
from rangeseg_o3d.synthetic.scene import Scene, cylinder, room
from rangeseg_o3d.synthetic.spinning import simulate_spinning_lidar

PIPE, CAP = 7, 9  # cylinder() numbers the side, then the cap at its base, then the far cap
_AXIS = np.array([-0.357, 0.934, 0.0]) / np.linalg.norm([-0.357, 0.934, 0.0])


@pytest.fixture(scope="module")
def pipeline():
    config = rs.load_config("spinning_lidar", overrides={
        "sensor.sigma0": 0.015, "sensor.row_spacing_deg": 45 / 63, "sensor.column_spacing_deg": 360 / 1024})
    return rs.Pipeline(config)


PIPES = [  # radius, length, base, noise seed: pipes 2.2-3.8 m away, the cap towards the sensor
    (0.14, 1.5, (2.6, -2.0, 0.0), 1),
    (0.18, 1.5, (2.4, -2.0, 0.3), 2),
    (0.14, 1.2, (2.2, -1.8, -0.2), 3),
    (0.20, 1.5, (3.0, -2.2, 0.2), 4),
]


def test_pipes_end_caps_are_found_beside_their_cylinders(pipeline):
    caps = 0
    for radius, length, base, seed in PIPES:
        scene = Scene([room(x=(-4.0, 6.0), y=(-3.0, 5.0), z=(-1.2, 1.8), first_id=1),
                       cylinder(base, _AXIS, radius, length, first_id=PIPE)])
        scan = simulate_spinning_lidar(scene, rows=64, cols=1024, noise_sigma=0.015, seed=seed)
        sizes = np.bincount(scan.truth_ids.ravel(), minlength=CAP + 1)
        assert sizes[CAP] >= 100 and sizes[PIPE] >= 3 * sizes[CAP]  # the cap is seen, smaller than the pipe
        evaluation = evaluate(scan, pipeline.run(scan.cloud), min_region=30)
        correct = set(evaluation.hoover.correct)  # each at T = 0.8, both ways
        kinds = {r.truth_id: r.kind for r in evaluation.regions}
        assert PIPE in correct and kinds[PIPE] == "cylinder"
        if CAP in correct:
            assert kinds[CAP] == "plane"
            caps += 1
        assert evaluation.false_fittings == 0
    # Today 3 of the 4 caps (2 before the noise of the distances was used); the fourth
    # keeps a silhouette band no region grows into.
    assert caps >= 3
