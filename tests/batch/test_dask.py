"""The same batch on a dask.distributed cluster: same bytes, failures reported, a killed
worker's inputs run again and no finished result is lost."""

import json
import os
import signal
import sys
import time
from pathlib import Path

import pytest

distributed = pytest.importorskip("distributed")

from rangeseg_o3d.batch import inputs, run_batch  # noqa: E402
from rangeseg_o3d.cli import main  # noqa: E402

pytestmark = pytest.mark.slow  # (files holding a slow test run first: tests/conftest.py)


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*.json"))}


class SlowLoader(distributed.WorkerPlugin):
    """Adds a ``.slow`` input kind on every worker (also on one that replaces a dead one):
    a text file naming a scan, read after a pause, so that a run lasts long enough to
    kill a worker in the middle of it."""

    def setup(self, worker):
        inputs.LOADERS[".slow"] = f"{__name__}:_slow_load"


def _slow_load(path, **options):
    from rangeseg_o3d.io import load_cloud

    time.sleep(0.4)
    return load_cloud(Path(path).read_text().strip())


@pytest.fixture(scope="module")
def client():
    import cloudpickle

    # The plugin and its loader travel by value: the workers cannot import test modules.
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None, worker_dashboard_address=None)
    with distributed.Client(cluster) as dask_client:
        yield dask_client
    cluster.close()
    cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


def test_two_worker_cluster_writes_the_local_pool_bytes(client, scan_tree, tmp_path):
    root, paths = scan_tree
    broken = root / "c" / "broken.pcd"
    broken.write_text("VERSION 0.7\nFIELDS x y z\nDATA ascii\n")
    pooled = {r.input: r for r in run_batch([root], out=tmp_path / "pool", jobs=2)}
    started = time.perf_counter()
    rows = []
    for row in run_batch([root], out=tmp_path / "dask", client=client):
        rows.append((time.perf_counter() - started, row))
    by_input = {row.input: row for _, row in rows}
    assert set(by_input) == set(pooled) and len(rows) == 5
    assert by_input[str(broken)].status == "failed"
    assert by_input[str(broken)].error == pooled[str(broken)].error
    assert str(broken) in by_input[str(broken)].error
    workers = {row.worker for _, row in rows}
    assert all(w.split(":")[1] != str(os.getpid()) for w in workers)  # run on the workers
    assert _files(tmp_path / "dask") == _files(tmp_path / "pool") and len(_files(tmp_path / "pool")) == 4
    for row in by_input.values():
        if row.status == "ok":
            assert (row.planes, row.cylinders, row.spheres) == (
                pooled[row.input].planes, pooled[row.input].cylinders, pooled[row.input].spheres)


def test_cli_on_a_running_scheduler(client, scan_tree, tmp_path, capsys):
    root, _ = scan_tree
    out = tmp_path / "out"
    assert main(["segment", str(root), "--out", str(out), "--scheduler", client.scheduler.address]) == 0
    rows = [json.loads(line) for line in (out / "summary.jsonl").read_text().splitlines()]
    assert [r["status"] for r in rows] == ["ok"] * 4
    assert len(list(out.rglob("*.json"))) == 4


def test_cli_refuses_a_scheduler_that_is_not_there(scan_tree, tmp_path, capsys, monkeypatch):
    root, _ = scan_tree
    monkeypatch.setattr("rangeseg_o3d.batch.CONNECT_TIMEOUT_S", 1.0)
    code = main(["segment", str(root), "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:9"])
    assert code == 2
    assert "no Dask scheduler answers at tcp://127.0.0.1:9" in capsys.readouterr().err


def test_killing_a_worker_mid_run_loses_nothing(client, scan_tree, tmp_path):
    _, paths = scan_tree
    client.register_plugin(SlowLoader(), name="slow-loader")
    slow = []
    for i in range(12):
        target = tmp_path / "in" / f"s{i:02d}.slow"
        target.parent.mkdir(exist_ok=True)
        target.write_text(str(paths[i % 2]))
        slow.append(target)
    out = tmp_path / "out"
    finished: dict[str, bytes] = {}
    killed = None
    rows = []
    for row in run_batch(slow, out=out, client=client):
        rows.append(row)
        assert row.status == "ok", row.error
        finished[row.outputs[0]] = Path(row.outputs[0]).read_bytes()
        if killed is None and len(rows) == 2:
            # Kill a worker process (not the one that just answered, if there are two).
            pids = client.run(os.getpid)
            victim = next(pid for pid in pids.values() if pid != int(row.worker.split(":")[1]))
            os.kill(victim, signal.SIGKILL)
            killed = victim
    assert killed is not None and len(rows) == 12
    assert sorted(r.index for r in rows) == list(range(12))
    assert killed not in {int(r.worker.split(":")[1]) for r in rows[2:]}
    # Every result that had arrived is still there, unchanged; nothing is missing.
    for target, data in finished.items():
        assert Path(target).read_bytes() == data
    assert len(list(out.rglob("*.json"))) == 12
    client.unregister_worker_plugin("slow-loader")


def test_scheduler_local_starts_lean_workers_and_runs(scan_tree, tmp_path, capsys):
    from rangeseg_o3d.batch import dask_client

    root, _ = scan_tree
    with dask_client("local", workers=1) as local:
        env = local.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))
        assert list(env.values()) == [None]  # Dask's default 65536 costs ~35 % per frame
        rows = list(run_batch([root / "a"], out=tmp_path / "out", client=local))
    assert [r.status for r in rows] == ["ok"] and (tmp_path / "out" / "scan.json").is_file()
