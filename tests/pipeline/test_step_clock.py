"""The clock the steps are timed on (rangeseg_o3d.timing.set_clock): every step reads it."""

import itertools
import time

import pytest

from rangeseg_o3d import timing
from rangeseg_o3d.timing import StepTimer, set_clock


@pytest.fixture
def restore_clock():
    previous = set_clock(time.perf_counter)
    set_clock(previous)
    yield
    set_clock(previous)


def test_step_timer_reads_the_clock_set(restore_clock):
    ticks = itertools.count(10.0, 2.5)  # each reading 2.5 s after the last
    set_clock(lambda: next(ticks))
    timings = {}
    timer = StepTimer(timings, "x.")  # reads 10.0
    timer.lap("a")  # 12.5
    timer.lap("b")  # 15.0
    assert timings == {"x.a": 2.5, "x.b": 2.5}
    assert timer.elapsed() == 7.5  # 17.5 - 10.0
    assert timing.now() == 20.0


def test_set_clock_returns_the_previous_clock(restore_clock):
    first = set_clock(time.process_time)
    assert first is time.perf_counter
    assert set_clock(first) is time.process_time


def test_every_pipeline_step_reads_the_clock_set(restore_clock):
    # a clock that stands still: every step, the segmenter's own and the total, takes 0 s
    from rangeseg_o3d.pipeline import Pipeline
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    cloud = simulate_lms200(default_scene(), seed=0).cloud
    set_clock(lambda: 7.0)
    result = Pipeline("lms200").run(cloud)
    assert {"residual", "edges", "segment", "fit", "refine", "refine.grow", "total"} <= set(result.timings)
    assert all(seconds == 0.0 for seconds in result.timings.values())
    set_clock(time.perf_counter)
    result = Pipeline("lms200").run(cloud)
    assert result.timings["total"] > 0.0
