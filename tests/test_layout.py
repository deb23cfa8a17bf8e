"""The tests mirror the package: a folder per subpackage, top-level modules' tests at the top."""

from pathlib import Path

TESTS = Path(__file__).resolve().parent
PACKAGE = TESTS.parent / "rangeseg_o3d"
# folders that test something other than one subpackage: whole-pipeline runs of
# pipeline.py (and the CLI on them), and the runnable scripts in examples/
OTHER_FOLDERS = {"pipeline", "examples"}


def _folders(root: Path) -> set[str]:
    return {p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith(("_", "."))}


def test_every_test_folder_names_a_subpackage_and_every_subpackage_has_one():
    subpackages = {name for name in _folders(PACKAGE) if (PACKAGE / name / "__init__.py").exists()}
    tested = _folders(TESTS) - OTHER_FOLDERS
    assert tested == subpackages
    assert (TESTS / "pipeline").is_dir() and (PACKAGE / "pipeline.py").exists()
    assert (TESTS / "examples").is_dir() and (TESTS.parent / "examples").is_dir()


def test_refinement_steps_each_have_their_test_file():
    steps = {p.stem for p in (PACKAGE / "refinement").glob("*.py")} - {"__init__", "context"}
    assert steps and {f"test_{step}" for step in steps} <= {p.stem for p in (TESTS / "refinement").glob("test_*.py")}
