"""Test helpers for tests/viz: a small hand-built scan and its segmentation, an .rrd reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rangeseg_o3d import Cylinder, Feature, OrganizedCloud, Plane, Result, Sphere, Unfitted

H, W = 20, 30
PLANE_LABEL, CYLINDER_LABEL, SPHERE_LABEL, UNFITTED_LABEL = 1, 2, 3, 4
CYLINDER_RADIUS = 0.25
SPHERE_CENTER = np.array([1.0, 4.0, 1.0])
SPHERE_RADIUS = 0.3


def make_scan(with_stages: bool = True):
    """(cloud, result) on a 20 x 30 grid: plane, cylinder, sphere, unfitted, unlabelled, NaN.

    Rows 0-7: plane z = 0 (label 1). Rows 8-13: cylinder of radius 0.25 around the
    x axis shifted to y = 2, z = 0.5, spanning x in [0, 2.9] (label 2). Rows 14-19,
    cols 0-14: sphere (label 3); cols 15-28: scattered points (unfitted, label 4);
    col 29: no return. Row 7, cols 0-4: valid but in no region (label 0).
    """
    rng = np.random.default_rng(0)
    xyz = np.full((H, W, 3), np.nan)
    labels = np.zeros((H, W), dtype=np.int32)
    cols = np.arange(W)
    rows, cc = np.meshgrid(np.arange(8), cols, indexing="ij")
    xyz[:8] = np.stack([cc * 0.1, rows * 0.1, np.zeros_like(rows, dtype=float)], axis=-1)
    labels[:8] = PLANE_LABEL
    labels[7, :5] = 0
    theta = np.linspace(-1.0, 1.0, 6)[:, None] * np.ones((1, W))
    x = np.ones((6, 1)) * cols[None, :] * 0.1
    xyz[8:14] = np.stack(
        [x, 2 + CYLINDER_RADIUS * np.sin(theta), 0.5 - CYLINDER_RADIUS * np.cos(theta)], axis=-1
    )
    labels[8:14] = CYLINDER_LABEL
    el = np.linspace(-0.6, 0.6, 6)[:, None] * np.ones((1, 15))
    az = np.ones((6, 1)) * np.linspace(-0.8, 0.8, 15)[None, :]
    dirs = np.stack([np.cos(el) * np.sin(az), -np.cos(el) * np.cos(az), np.sin(el)], axis=-1)
    xyz[14:, :15] = SPHERE_CENTER + SPHERE_RADIUS * dirs
    labels[14:, :15] = SPHERE_LABEL
    xyz[14:, 15:29] = rng.uniform(5, 6, size=(6, 14, 3))
    labels[14:, 15:29] = UNFITTED_LABEL
    cloud = OrganizedCloud(xyz)
    features = [
        Feature(PLANE_LABEL, Plane(normal=(0, 0, 1), d=0.0, rms=0.0, inliers=235), 235),
        Feature(
            CYLINDER_LABEL,
            Cylinder(axis=(1, 0, 0), point=(1.45, 2, 0.5), radius=CYLINDER_RADIUS, rms=0.0, inliers=180),
            180,
        ),
        Feature(
            SPHERE_LABEL,
            Sphere(center=SPHERE_CENTER, radius=SPHERE_RADIUS, rms=0.0, inliers=90),
            90,
        ),
    ]
    unfitted = [Unfitted(UNFITTED_LABEL, 84, "no model below the rms threshold")]
    stages = {}
    if with_stages:
        residual = rng.uniform(0, 0.05, size=(H, W))
        residual[:, -1] = np.nan
        stages = {
            "residual": residual,
            "closed": np.maximum(residual, 0.01),
            "edges": residual > 0.04,
        }
    timings = {"residual": 0.004, "labels": 0.001, "fit": 0.01, "total": 0.02}
    return cloud, Result(labels, features, unfitted, timings, stages)


def read_rrd(path: Path) -> dict[str, list]:
    """Entity path -> list of pyarrow RecordBatches (one per chunk) from an .rrd file."""
    from rerun.chunk import RrdReader

    out: dict[str, list] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        entity = batch.schema.metadata[b"rerun:entity_path"].decode()
        out.setdefault(entity, []).append(batch)
    return out


def columns(batches) -> set[str]:
    """Names of all data columns in a list of RecordBatches."""
    return {name for batch in batches for name in batch.schema.names}


def column_values(batches, name: str) -> list:
    """Every row's value of column ``name`` across ``batches`` (rows lacking it skipped)."""
    values = []
    for batch in batches:
        if name in batch.schema.names:
            values += [v for v in batch.column(name).to_pylist() if v is not None]
    return values
