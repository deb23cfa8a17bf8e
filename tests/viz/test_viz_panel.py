"""The PNG panel: size, non-empty tiles, grey placeholders, atomic writing, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from viz_scan import H, W, make_scan

from rangeseg_o3d import OrganizedCloud, Result
from rangeseg_o3d.viz.panel import (
    GAP,
    MIN_TILE_WIDTH,
    TILES,
    TITLE_HEIGHT,
    panel_scale,
    render_panel,
    write_panel_png,
)


def _tile_bodies(panel: np.ndarray, scale: int) -> list[np.ndarray]:
    """The image part (below the title) of each tile."""
    tile_width = max(W * scale, MIN_TILE_WIDTH)
    bodies = []
    for k in range(len(TILES)):
        left = k * (tile_width + GAP)
        bodies.append(panel[TITLE_HEIGHT:, left : left + W * scale])
    return bodies


@pytest.mark.parametrize("scale", [1, 3, 8])
def test_panel_size_and_every_tile_has_content(scale):
    cloud, result = make_scan()
    panel = render_panel(cloud, result, scale=scale)
    tile_width = max(W * scale, MIN_TILE_WIDTH)
    assert panel.dtype == np.uint8
    assert panel.shape == (TITLE_HEIGHT + H * scale, 4 * tile_width + 3 * GAP, 3)
    for name, body in zip(TILES, _tile_bodies(panel, scale)):
        assert len(np.unique(body.reshape(-1, 3), axis=0)) >= 2, f"{name} tile is flat"
        # The title bar carries text: more than its background colour.
    for k in range(len(TILES)):
        left = k * (tile_width + GAP)
        assert len(np.unique(panel[:TITLE_HEIGHT, left : left + tile_width])) > 2


def test_labels_tile_shows_each_region_colour():
    cloud, result = make_scan()
    panel = render_panel(cloud, result, scale=2)
    labels_tile = _tile_bodies(panel, 2)[3]
    from rangeseg_o3d.viz.colors import region_colors

    lut = region_colors(result)
    colours = {tuple(c) for c in labels_tile.reshape(-1, 3)}
    for label in (1, 2, 3, 4):
        assert tuple(lut[label]) in colours


def test_upscaling_is_integer_and_nearest():
    cloud, result = make_scan()
    panel = render_panel(cloud, result, scale=3)
    edges_tile = _tile_bodies(panel, 3)[2]
    mask = edges_tile[..., 0] == 255
    np.testing.assert_array_equal(mask[::3, ::3], result.stages["edges"])
    assert set(np.unique(edges_tile)) <= {0, 255}


def test_auto_scale_for_small_and_vga_scans():
    assert panel_scale((70, 131)) == 3
    assert panel_scale((480, 640)) == 1
    assert panel_scale((2, 5)) == 8


def test_missing_stages_are_grey_and_labelled():
    cloud, result = make_scan(with_stages=False)
    panel = render_panel(cloud, result, scale=2)
    bodies = _tile_bodies(panel, 2)
    for body in bodies[1:3]:
        values, counts = np.unique(body.reshape(-1, 3), axis=0, return_counts=True)
        assert tuple(values[np.argmax(counts)]) == (128, 128, 128)  # mostly grey ...
        assert len(values) > 1  # ... with the "not provided" text
    assert len(np.unique(bodies[0].reshape(-1, 3), axis=0)) > 2


def test_all_nan_cloud_renders():
    cloud = OrganizedCloud(np.full((4, 5, 3), np.nan))
    result = Result(np.zeros((4, 5), np.int32), [], stages={"residual": np.full((4, 5), np.nan)})
    panel = render_panel(cloud, result)
    assert panel.shape[0] == TITLE_HEIGHT + 4 * 8


def test_write_panel_png_roundtrip_and_atomic(tmp_path):
    cloud, result = make_scan()
    path = write_panel_png(tmp_path / "panel.png", cloud, result)
    read = cv2.imread(str(path), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(read[..., ::-1], render_panel(cloud, result))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["panel.png"]  # no temp file left


def test_bad_input(tmp_path):
    cloud, result = make_scan()
    with pytest.raises(ValueError, match="must end in .png"):
        write_panel_png(tmp_path / "panel.jpg", cloud, result)
    with pytest.raises(FileNotFoundError):
        write_panel_png(tmp_path / "missing" / "panel.png", cloud, result)
    with pytest.raises(ValueError, match=r"labels must have shape \(20, 30\)"):
        render_panel(cloud, Result(np.zeros((3, 3), np.int32), []))
    with pytest.raises(ValueError, match="stage image 'residual'"):
        render_panel(cloud, Result(result.labels, [], stages={"residual": np.zeros((2, 2))}))
    with pytest.raises(ValueError, match="scale must be a positive integer"):
        render_panel(cloud, result, scale=0)
    with pytest.raises(TypeError, match="cloud must be an OrganizedCloud"):
        render_panel(cloud.xyz, result)
    assert not list(tmp_path.iterdir())
