import os
from pathlib import Path

import pytest

from rangeseg_o3d.batch import check_regular_file, expand_inputs, output_names, plan_tasks


def test_output_names_keep_folders_apart_and_suffixes_only_when_needed():
    assert output_names(["a/scan.npz", "b/scan.npz"]) == ["a/scan", "b/scan"]
    assert output_names(["x/room.npz", "x/room.pcd", "x/hall.pcd"]) == ["room.npz", "room.pcd", "hall"]
    assert output_names(["/d/run1/s.npz", "/d/run2/deep/s.pcd"]) == ["run1/s", "run2/deep/s"]
    # Names that differ only by case would overwrite each other on a case-insensitive disk.
    assert output_names(["Scan.npz", "scan.pcd"]) == ["Scan.npz", "scan.pcd"]
    assert output_names([]) == []


def test_output_names_are_always_distinct():
    paths = ["a.npz", "a.npz.npz", "a.pcd", "b/a.npz", "b/A.NPZ"]
    names = output_names(paths)
    assert len({n.casefold() for n in names}) == len(paths)
    assert output_names(paths) == names  # deterministic


def test_expand_inputs_takes_files_folders_and_globs(scan_tree):
    root, paths = scan_tree
    (root / "c" / "notes.txt").write_text("not a scan")
    assert expand_inputs([root]) == sorted(paths)
    assert expand_inputs([str(root / "*" / "*.npz")]) == [p for p in sorted(paths) if p.suffix == ".npz"]
    assert expand_inputs([str(root / "**" / "room.*")]) == [root / "c/room.npz", root / "c/room.pcd"]
    # The same file twice (directly and through the folder) is read once.
    assert expand_inputs([paths[0], root / "a"]) == [paths[0]]
    # A missing file stays: it fails as its own input, the others go on.
    assert expand_inputs(["missing.npz"]) == [Path("missing.npz")]
    with pytest.raises(ValueError, match="matches no file"):
        expand_inputs([str(root / "*.nothing")])
    (root / "empty").mkdir()
    with pytest.raises(ValueError, match="holds no"):
        expand_inputs([root / "empty"])


def test_special_files_are_refused_without_opening(tmp_path):
    fifo = tmp_path / "x.3d"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="is a FIFO, not a regular file"):
        check_regular_file(fifo)  # opening it would wait for a writer forever
    with pytest.raises(ValueError, match="character device"):
        check_regular_file("/dev/null")
    with pytest.raises(ValueError, match="directory"):
        check_regular_file(tmp_path)
    with pytest.raises(FileNotFoundError, match="no such file"):
        check_regular_file(tmp_path / "none.npz")


def test_plan_refuses_one_output_file_for_several_inputs(scan_tree, tmp_path):
    _, paths = scan_tree
    with pytest.raises(ValueError, match="names one file but 2 inputs"):
        plan_tasks(paths[:2], out=tmp_path / "x.json")
    plan = plan_tasks(paths[:1], out=tmp_path / "x.json")
    assert plan.folder is None and plan.tasks[0].outputs == (("json", str(tmp_path / "x.json")),)
    plan = plan_tasks(paths, out=tmp_path / "res")
    targets = [t for task in plan.tasks for _, t in task.outputs]
    assert len(set(targets)) == len(targets) == 4


def test_folders_skip_the_outputs_and_take_a_ros2_bag_whole(scan_tree, tmp_path):
    root, paths = scan_tree
    bag = root / "c" / "run.bag2"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (bag / "run_0.db3").write_bytes(b"")
    results = root / "results"
    (results / "a").mkdir(parents=True)
    (results / "a" / "scan.png").write_bytes(b"")  # an output of an earlier run
    assert expand_inputs([root], skip=[results]) == sorted([*paths, bag])
    check_regular_file(bag)  # a bag folder is one input
    plan = plan_tasks([root], out=results, targets={"labels": results})
    assert [t.path for t in plan.tasks] == [str(p) for p in sorted([*paths, bag])]
