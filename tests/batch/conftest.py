import pytest

from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.suite import default_scene


@pytest.fixture(scope="session")
def room_cloud():
    return simulate_lms200(default_scene(), seed=0).cloud


@pytest.fixture
def scan_tree(tmp_path, room_cloud):
    """Four small LMS200 scans: a/scan.npz, b/scan.npz (same name), c/room.npz, c/room.pcd."""
    root = tmp_path / "scans"
    paths = []
    for rel in ("a/scan.npz", "b/scan.npz", "c/room.npz", "c/room.pcd"):
        target = root / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        paths.append(room_cloud.save(target))
    return root, paths
