"""The npz round trip keeps every field of an OrganizedCloud, found from its constructor's parameters."""

import dataclasses
import inspect

import numpy as np
import pytest

from rangeseg_o3d import NoddingGeometry, OrganizedCloud
from rangeseg_o3d.io import load_npz, save_npz

FIELDS = [name for name in inspect.signature(OrganizedCloud.__init__).parameters
          if name not in ("self", "xyz") and not name.startswith("_")]


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is b
    if dataclasses.is_dataclass(a):
        return type(a) is type(b) and all(_same(getattr(a, f.name), getattr(b, f.name))
                                          for f in dataclasses.fields(a))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


@pytest.fixture
def every_field_cloud():
    rng = np.random.default_rng(7)
    h, w = 4, 5
    xyz = rng.normal(size=(h, w, 3))
    xyz[1, 2] = np.nan
    pose = np.eye(4)
    pose[:3, 3] = (1.0, -2.0, 0.5)
    return OrganizedCloud(
        xyz,
        ranges=rng.uniform(0.5, 8.0, (h, w)),
        intensity=rng.integers(0, 255, (h, w)).astype(np.uint16),
        geometry=NoddingGeometry(beam_angles=np.linspace(0.1, 3.0, w), tilt_angles=np.linspace(-0.4, 0.3, h),
                                 mount_offset=(0.01, 0.02, 0.15), tilt_sign=-1.0),
        timestamps=np.linspace(0.0, 0.04, h),
        samples=rng.integers(0, 37, (h, w)).astype(np.int32),
        tile=6,
        colors=rng.integers(0, 256, (h, w, 3)).astype(np.uint8),
        extras={"normals": rng.normal(size=(h, w, 3)), "curvature": rng.uniform(size=(h, w)).astype(np.float32)},
        pose=pose,
    )


def test_the_fixture_sets_every_field(every_field_cloud):
    default = OrganizedCloud(every_field_cloud.xyz)
    unset = [name for name in FIELDS if _same(getattr(every_field_cloud, name), getattr(default, name))]
    assert unset == []  # a field added to OrganizedCloud must be set here (and saved)


@pytest.mark.parametrize("compress", [False, True])
def test_every_field_survives_bit_for_bit(tmp_path, every_field_cloud, compress):
    back = load_npz(save_npz(every_field_cloud, tmp_path / "scan.npz", compress=compress))
    assert _same(every_field_cloud.xyz, back.xyz)
    changed = [name for name in FIELDS if not _same(getattr(every_field_cloud, name), getattr(back, name))]
    assert changed == []


def test_a_raw_scan_stores_no_tile_key(tmp_path, every_field_cloud):
    raw = OrganizedCloud(every_field_cloud.xyz)
    path = save_npz(raw, tmp_path / "raw.npz")
    with np.load(path) as data:
        assert "tile" not in data and "samples" not in data
    back = load_npz(path)
    assert back.tile == 1 and back.samples is None


@pytest.mark.parametrize("tile", [np.asarray(0), np.asarray(2.5), np.asarray([2, 2])])
def test_a_bad_tile_is_refused(tmp_path, tile):
    path = tmp_path / "bad.npz"
    np.savez(path, format_version=np.asarray(1), xyz=np.zeros((2, 2, 3)), tile=tile)
    with pytest.raises(ValueError, match="bad.npz: tile must be one positive integer"):
        load_npz(path)


def test_tile_means_round_trip(tmp_path, every_field_cloud):
    means = OrganizedCloud(every_field_cloud.xyz).tile_means(2)
    back = load_npz(save_npz(means, tmp_path / "means.npz"))
    assert back.tile == 2 and _same(back.samples, means.samples) and _same(back.xyz, means.xyz)
