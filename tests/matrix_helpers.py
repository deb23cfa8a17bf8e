"""Scans of the sensor matrix and the row's pipeline on them, for tests that trace a matrix case."""

import numpy as np

import rangeseg_o3d as rs
from rangeseg_o3d.synthetic.matrix import get_sensor, matrix_rng


def matrix_result(name: str, seed: int, k: int):
    """Scan ``k`` of matrix row ``name`` drawn from ``seed`` (full size) and the row's pipeline
    result on it (the row's preset given the row's sensor facts, as scripts/benchmark.py runs it)."""
    spec = get_sensor(name)
    config = rs.load_config(spec.preset, overrides={f"sensor.{key}": value
                                                     for key, value in spec.sensor_facts(False).items()})
    scan = spec.simulate(matrix_rng(seed, spec.draws, k), False)
    return scan, rs.Pipeline(config).run(scan.cloud)


def region_holding(labels: np.ndarray, mask: np.ndarray) -> tuple[int, int]:
    """``(label, pixels)``: the label holding most of ``mask``'s pixels (0: in no region) and how many."""
    found, counts = np.unique(labels[mask], return_counts=True)
    return int(found[counts.argmax()]), int(counts.max())


def surface_feature(scan, result, truth_id: int, *, of_surface: float, of_region: float = 0.9):
    """The feature of the region holding most of truth surface ``truth_id`` of ``scan`` in
    ``result``, once that region holds at least ``of_surface`` of the surface's pixels and the
    surface at least ``of_region`` of the region's (AssertionError otherwise)."""
    surface = scan.truth_ids == truth_id
    label, count = region_holding(result.labels, surface)
    assert label > 0 and count >= of_surface * surface.sum(), (truth_id, label, count, int(surface.sum()))
    assert count >= of_region * (result.labels == label).sum(), (truth_id, label, count)
    return {f.label: f for f in result.features}[label]


def matrix_result_region_growing(name: str, seed: int, k: int, growing: str = "lms200_region_growing"):
    """As :func:`matrix_result`, with the row's preset's segmenter swapped for region growing
    (the ``growing`` preset's parameters and tile; the refinement's region size and jump test
    its own defaults), as scripts/benchmark.py runs the baseline."""
    spec = get_sensor(name)
    facts = {f"sensor.{key}": value for key, value in spec.sensor_facts(False).items()}
    config = rs.load_config(spec.preset, overrides=facts).model_dump()
    own = rs.load_config(growing)
    config["segmenter"] = {"name": "region_growing", "params": dict(own.segmenter.params)}
    config["tile"] = own.tile
    for key in ("min_region_size", "jump_ratio", "jump_min"):
        config["refine"][key] = None
    scan = spec.simulate(matrix_rng(seed, spec.draws, k), False)
    return scan, rs.Pipeline(rs.load_config(config)).run(scan.cloud)


def feature_of_kind(name: str, seed: int, k: int, truth_id: int, kind: type, *, of_region: float):
    """``(scan, truth, feature)``: truth surface ``truth_id`` of scan ``k`` of matrix row ``name`` drawn
    from ``seed``, asserted a ``kind`` (the case's premise), and the feature of the region holding
    at least 90 % of it (:func:`surface_feature`, ``of_region``), asserted of the same kind."""
    scan, result = matrix_result(name, seed, k)
    truth = scan.truth[truth_id]
    assert isinstance(truth, kind), truth
    feature = surface_feature(scan, result, truth_id, of_surface=0.9, of_region=of_region)
    assert isinstance(feature.model, kind), feature.model
    return scan, truth, feature
