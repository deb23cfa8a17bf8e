"""CLI helpers: flags mirror rerun's, no flag means no recording, --save writes atomically."""

from __future__ import annotations

import argparse
import subprocess
import sys

import numpy as np
import pytest
from viz_scan import column_values, make_scan, read_rrd

from rangeseg_o3d.viz.rerun_cli import (
    add_rerun_arguments,
    finish_recording,
    recording_from_args,
    wants_recording,
)
from rangeseg_o3d.viz.rerun_log import log_scan


def _parse(*argv):
    return add_rerun_arguments(argparse.ArgumentParser()).parse_args(list(argv))


def test_flags_cover_rerun_script_add_args():
    import rerun as rr  # a core dependency: missing is a failure, not a skip
    theirs = argparse.ArgumentParser()
    rr.script_add_args(theirs)
    ours = add_rerun_arguments(argparse.ArgumentParser())
    their_options = {s for a in theirs._actions for s in a.option_strings}
    our_options = {s for a in ours._actions for s in a.option_strings}
    assert their_options <= our_options
    assert {"--spawn", "--png"} <= our_options
    assert vars(theirs.parse_args([])).keys() <= vars(ours.parse_args([])).keys()


@pytest.mark.parametrize(
    "argv, wanted",
    [((), False), (("--png", "x.png"), False), (("--headless",), False),
     (("--save", "x.rrd"), True), (("--connect",), True), (("--serve",), True),
     (("--spawn",), True), (("--stdout",), True), (("--url", "rerun+http://h:1/proxy"), True)],
)
def test_which_flags_ask_for_a_recording(argv, wanted):
    assert wants_recording(_parse(*argv)) is wanted


def test_no_flag_gives_none_without_importing_rerun():
    code = (
        "import argparse, sys\n"
        "from rangeseg_o3d.viz import add_rerun_arguments, recording_from_args, finish_recording\n"
        "args = add_rerun_arguments(argparse.ArgumentParser()).parse_args(['--png', 'a.png'])\n"
        "assert recording_from_args(args) is None\n"
        "assert finish_recording(args, None) is None\n"
        "assert 'rerun' not in sys.modules, 'rerun was imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_save_writes_a_readable_rrd_atomically(tmp_path):
    target = tmp_path / "run.rrd"
    args = _parse("--save", str(target))
    rec = recording_from_args(args, application_id="rangeseg_test")
    cloud, result = make_scan()
    log_scan(rec, cloud, result, scan_index=0)
    assert not target.exists()  # only the temporary file while logging
    assert finish_recording(args, rec) == target
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.rrd"]
    entities = read_rrd(target)
    (positions,) = column_values(entities["/world/points"], "Points3D:positions")
    assert len(positions) == cloud.n_valid
    assert np.isfinite(np.array(positions)).all()


def test_bad_combinations(tmp_path):
    with pytest.raises(ValueError, match="--stdout cannot be combined with --save"):
        recording_from_args(_parse("--stdout", "--save", str(tmp_path / "a.rrd")))
    with pytest.raises(ValueError, match="--serve cannot be combined with --spawn"):
        recording_from_args(_parse("--serve", "--spawn"))
    with pytest.raises(ValueError, match="does not exist"):
        recording_from_args(_parse("--save", str(tmp_path / "nope" / "a.rrd")))
    with pytest.raises(TypeError, match="ArgumentParser"):
        add_rerun_arguments(object())
