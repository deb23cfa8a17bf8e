"""rangeseg_o3d.memory: glibc keeps a frame's freed temporaries in the process."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

import rangeseg_o3d.pipeline as pipeline_module
from rangeseg_o3d import memory

REPO = Path(__file__).resolve().parents[1]
GLIBC = memory._glibc_mallopt() is not None

# A frame's pattern: three 8 MiB temporaries written and freed, 20 times, after one 8 MiB
# block was freed (glibc then raises its thresholds to 8 MiB mapped / 16 MiB trimmed, so
# the 24 MiB free at the heap's top goes back to the system after every round). Prints the
# minor page faults of the last 10 rounds and the pages they wrote.
_FRAMES = """
import ctypes, resource, sys
sys.path.insert(0, {repo!r})
from rangeseg_o3d import memory
if {keep}:
    assert memory.keep_freed_memory()
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = (ctypes.c_size_t,)
libc.free.argtypes = (ctypes.c_void_p,)
libc.memset.argtypes = (ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t)
size = 8 << 20
libc.free(libc.malloc(size))
for round in range(20):
    if round == 10:
        start = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    blocks = [libc.malloc(size) for _ in range(3)]
    for block in blocks:
        libc.memset(block, 1, size)
    for block in blocks:
        libc.free(block)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - start, 10 * 3 * size // 4096)
"""


def _faults(keep: bool) -> tuple[int, int]:
    env = {k: v for k, v in os.environ.items() if k not in memory._GLIBC_MALLOC_ENV and k != "GLIBC_TUNABLES"}
    out = subprocess.run([sys.executable, "-c", _FRAMES.format(repo=str(REPO), keep=keep)], env=env,
                         capture_output=True, text=True, check=True)
    faults, pages = map(int, out.stdout.split())
    return faults, pages


@pytest.mark.skipif(not GLIBC, reason="glibc only")
def test_kept_memory_is_not_faulted_again():
    faults, pages = _faults(keep=False)
    if faults < pages // 2:
        pytest.skip(f"this glibc keeps the blocks by itself ({faults} faults for {pages} pages written)")
    kept, pages = _faults(keep=True)
    # without: nearly every page written faults (the blocks went back to the system)
    assert kept < pages // 100, (kept, faults, pages)


@pytest.fixture
def fresh(monkeypatch):
    """keep_freed_memory as if never called, with a recording stand-in for mallopt."""
    calls = []

    def mallopt(parameter, value):
        calls.append((parameter, value))
        return 1

    monkeypatch.setattr(memory, "_applied", False)
    monkeypatch.setattr(memory, "_glibc_mallopt", lambda: mallopt)
    for name in (*memory._GLIBC_MALLOC_ENV, "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)
    return calls


def test_sets_both_thresholds_once(fresh):
    assert memory.keep_freed_memory() is True
    assert sorted(fresh) == sorted([(memory._M_MMAP_THRESHOLD, memory.MMAP_THRESHOLD_BYTES),
                                    (memory._M_TRIM_THRESHOLD, memory.TRIM_THRESHOLD_BYTES)])
    assert memory.keep_freed_memory() is True
    assert len(fresh) == 2


@pytest.mark.parametrize("name, value", [("MALLOC_TRIM_THRESHOLD_", "65536"),
                                         ("MALLOC_MMAP_THRESHOLD_", "131072"),
                                         ("GLIBC_TUNABLES", "glibc.malloc.trim_threshold=65536")])
def test_the_environments_malloc_settings_win(fresh, monkeypatch, name, value):
    monkeypatch.setenv(name, value)
    assert memory.keep_freed_memory() is False
    assert fresh == []


def test_unrelated_tunables_do_not_stop_it(fresh, monkeypatch):
    monkeypatch.setenv("GLIBC_TUNABLES", "glibc.rtld.optional_static_tls=2048")
    assert memory.keep_freed_memory() is True


def test_refused_value_reports_false(monkeypatch, fresh):
    monkeypatch.setattr(memory, "_glibc_mallopt", lambda: lambda parameter, value: 0)
    assert memory.keep_freed_memory() is False


def test_no_op_off_glibc(monkeypatch):
    def no_such_name(name):
        raise ValueError(f"unrecognized configuration name {name!r}")

    monkeypatch.setattr(memory, "_applied", False)
    monkeypatch.setattr(os, "confstr", no_such_name)
    assert memory._glibc_mallopt() is None
    assert memory.keep_freed_memory() is False


def test_large_frame_is_one_of_128_kib_per_float64_array():
    assert memory.LARGE_FRAME_PIXELS * 8 == 128 << 10
    assert memory.large_frame((480, 640)) and memory.large_frame((128, 128))
    assert not memory.large_frame((70, 131)) and not memory.large_frame((127, 128))


@pytest.mark.parametrize("keep", [True, False])
def test_pipeline_keeps_memory_on_a_large_frame_unless_told_not_to(monkeypatch, keep):
    from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
    from rangeseg_o3d.synthetic.suite import rgbd_scenes

    calls = []
    monkeypatch.setattr(pipeline_module, "keep_freed_memory", lambda: calls.append(True))
    cloud = simulate_depth_camera(rgbd_scenes()[1][1], seed=0).cloud
    assert memory.large_frame(cloud.shape)
    pipeline_module.Pipeline("rgbd_vga", keep_memory=keep).run(cloud)
    assert calls == ([True] if keep else [])


def test_pipeline_leaves_malloc_alone_on_small_scans(monkeypatch):
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    calls = []
    monkeypatch.setattr(pipeline_module, "keep_freed_memory", lambda: calls.append(True))
    cloud = simulate_lms200(default_scene(), seed=0).cloud
    assert not memory.large_frame(cloud.shape)
    pipeline_module.Pipeline("lms200").run(cloud)
    assert calls == []
