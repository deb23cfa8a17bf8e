"""Shared fixtures for the I/O tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rangeseg_o3d import NoddingGeometry, OrganizedCloud

#: <repo>/../shared/data, absent on machines without the shared data.
SHARED_DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"


def _shared_file(relative: str) -> Path:
    path = SHARED_DATA / relative
    if not path.is_file():
        pytest.skip(f"shared data file {relative} not present")
    return path


def _random_xyz(h=4, w=5, *, seed=0, nan_pixels=((0, 0), (2, 3))) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xyz = rng.normal(size=(h, w, 3))
    for r, c in nan_pixels:
        xyz[r, c] = np.nan
    return xyz


@pytest.fixture
def shared_file():
    """``shared_file("pcl/office1.pcd")`` -> its path, or skip when the shared data are absent."""
    return _shared_file


@pytest.fixture
def random_xyz():
    """``random_xyz(h, w, seed=, nan_pixels=)`` -> (h, w, 3) normal points with NaN pixels."""
    return _random_xyz


@pytest.fixture
def full_cloud() -> OrganizedCloud:
    """A 4x5 cloud with NaN pixels and every optional field, nodding geometry."""
    xyz = _random_xyz()
    rng = np.random.default_rng(1)
    geometry = NoddingGeometry(
        beam_angles=np.linspace(0.1, 3.0, 5),
        tilt_angles=np.linspace(-0.4, 0.3, 4),
        mount_offset=(0.01, 0.02, 0.15),
        tilt_sign=-1.0,
    )
    return OrganizedCloud(
        xyz,
        ranges=rng.uniform(0.5, 8.0, size=(4, 5)),
        intensity=rng.integers(0, 255, size=(4, 5)).astype(np.uint16),
        geometry=geometry,
        timestamps=np.array([0.0, 0.0133, 0.0266, 0.04]),
    )


@pytest.fixture
def pinhole_cloud() -> OrganizedCloud:
    depth = np.full((6, 8), 1.5)
    depth[0, :3] = 0.0
    return OrganizedCloud.from_depth(depth, 525.0, 526.0, 3.5, 2.5)
