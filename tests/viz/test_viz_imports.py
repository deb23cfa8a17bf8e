"""Import hygiene: without a recording, nothing here imports rerun (or open3d)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

CODE = f"""
import sys
sys.path.insert(0, {str(HERE)!r})
import rangeseg_o3d
import rangeseg_o3d.viz as viz
from rangeseg_o3d.viz import rerun_log, rerun_cli, panel, colors, shapes
from viz_scan import make_scan
cloud, result = make_scan()
viz.log_scan(None, cloud, result, scan_index=0)
viz.log_points(None, cloud, result.labels)
viz.render_panel(cloud, result)
heavy = sorted(m for m in ('rerun', 'open3d', 'serial') if m in sys.modules)
assert not heavy, f'imported {{heavy}}'
"""


def test_viz_without_recording_does_not_import_rerun():
    subprocess.run([sys.executable, "-c", CODE], check=True)


PIPELINE_CODE = f"""
import sys
sys.path.insert(0, {str(HERE)!r})
from rangeseg_o3d.pipeline import Pipeline
from rangeseg_o3d.config import load_config
from viz_scan import make_scan
cloud, _ = make_scan()
Pipeline(load_config('lms200')).run(cloud)
assert 'rerun' not in sys.modules, 'Pipeline.run without a recording imported rerun'
"""


def test_pipeline_without_recording_does_not_import_rerun():
    subprocess.run([sys.executable, "-c", PIPELINE_CODE], check=True)


def test_lazy_names_resolve():
    import rangeseg_o3d.viz as viz

    for name in viz.__all__:
        assert callable(getattr(viz, name)), name
