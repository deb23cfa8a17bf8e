"""The local process pool and the Python API: same bytes as in-process, lean results,
a dying worker costs no other input."""

import os
import pickle
from pathlib import Path

import pytest

from rangeseg_o3d.batch import MAX_ATTEMPTS, inputs, run_batch


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*.json"))}


def test_pool_writes_the_same_bytes_as_this_process(scan_tree, tmp_path):
    root, paths = scan_tree
    serial = list(run_batch([root], out=tmp_path / "serial", jobs=1))
    pooled = list(run_batch([root], out=tmp_path / "pool", jobs=2))
    assert sorted(r.index for r in pooled) == [0, 1, 2, 3]
    assert all(r.status == "ok" for r in serial + pooled)
    assert {os.getpid()} == {int(r.worker.split(":")[1]) for r in serial}
    assert os.getpid() not in {int(r.worker.split(":")[1]) for r in pooled}
    a, b = _files(tmp_path / "serial"), _files(tmp_path / "pool")
    assert list(a) == ["a/scan.json", "b/scan.json", "c/room.npz.json", "c/room.pcd.json"]
    assert a == b


def test_results_cross_processes_without_intermediate_images(scan_tree):
    _, paths = scan_tree
    [lean] = run_batch(paths[:1], jobs=1, keep_results=True)
    [full] = run_batch(paths[:1], jobs=1, keep_results=True, keep_stages=True)
    assert lean.result.stages == {} and set(full.result.stages) >= {"residual", "edges"}
    assert [f.to_dict() for f in lean.result.features] == [f.to_dict() for f in full.result.features]
    lean_size, full_size = len(pickle.dumps(lean)), len(pickle.dumps(full))
    labels = lean.result.labels.nbytes
    stages = sum(image.nbytes for image in full.result.stages.values())
    # The labels and some kB of features (with their patch geometry), not the scan's
    # points the features were found in; the stages add their images.
    assert lean_size < labels + 30_000
    assert full_size > lean_size + 0.9 * stages
    assert lean.result.features[0].area == pytest.approx(full.result.features[0].area, rel=1e-12)
    [row] = run_batch(paths[:1], jobs=1)
    assert row.result is None and len(pickle.dumps(row)) < 5_000
    # Through the pool the same lean result arrives.
    pooled = sorted(run_batch(paths[:2], jobs=2, keep_results=True), key=lambda r: r.index)
    assert pooled[0].result.stages == {} and (pooled[0].result.labels == lean.result.labels).all()


def _die(path, **options):
    os._exit(3)  # a worker killed mid-input (out of memory, segfault)


def _die_once(path, **options):
    marker = Path(str(path) + ".died")
    if not marker.exists():
        marker.write_text("")
        os._exit(3)
    from rangeseg_o3d.io import load_cloud

    return load_cloud(Path(path).read_text().strip())


def test_pool_survives_a_worker_that_dies(scan_tree, tmp_path, monkeypatch):
    _, paths = scan_tree
    # Loaders that kill their worker process; forked workers inherit this table.
    monkeypatch.setitem(inputs.LOADERS, ".die", f"{__name__}:_die")
    monkeypatch.setitem(inputs.LOADERS, ".once", f"{__name__}:_die_once")
    killer = tmp_path / "killer.die"
    killer.write_text("")
    flaky = tmp_path / "flaky.once"
    flaky.write_text(str(paths[0]))
    rows = {r.input: r for r in run_batch([*map(str, paths), str(killer), str(flaky)],
                                          out=tmp_path / "out", jobs=2)}
    assert len(rows) == 6
    assert rows[str(killer)].status == "failed"
    assert f"died {MAX_ATTEMPTS} times" in rows[str(killer)].error
    assert rows[str(flaky)].status == "ok", rows[str(flaky)].error  # run again after its worker died
    assert all(rows[str(p)].status == "ok" for p in paths)
    assert len(list((tmp_path / "out").rglob("*.json"))) == 5


def test_run_batch_checks_everything_before_work(scan_tree, tmp_path):
    _, paths = scan_tree
    with pytest.raises(ValueError, match="names one file"):
        run_batch(paths, out=tmp_path / "x.json")
    with pytest.raises(ValueError, match="unknown preset"):
        run_batch(paths, config="no_such_preset")
    with pytest.raises(ValueError, match="jobs must be at least 1"):
        run_batch(paths, jobs=0)
    assert not (tmp_path / "x.json").exists()
