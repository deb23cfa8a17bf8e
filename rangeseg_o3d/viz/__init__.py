"""Looking at a segmentation: rerun logging, CLI helpers for rerun, and a PNG panel.

Names are loaded on first use, so ``import rangeseg_o3d.viz`` stays cheap and the PNG
panel never imports rerun; rerun itself is imported only when something is logged or a
recording is created.
"""

from __future__ import annotations

import importlib

__all__ = [
    "log_scan",
    "log_range",
    "log_stage_images",
    "log_labels",
    "log_points",
    "log_features",
    "log_timings",
    "log_static_context",
    "add_rerun_arguments",
    "recording_from_args",
    "finish_recording",
    "render_panel",
    "write_panel_png",
    "region_colors",
    "region_names",
]

_SOURCES = {
    **dict.fromkeys(__all__[:8], "rerun_log"),
    **dict.fromkeys(["add_rerun_arguments", "recording_from_args", "finish_recording"], "rerun_cli"),
    **dict.fromkeys(["render_panel", "write_panel_png"], "panel"),
    **dict.fromkeys(["region_colors", "region_names"], "colors"),
}


def __getattr__(name: str):
    # PEP 562 lazy attribute: import the defining module only when the name is used.
    if name in _SOURCES:
        module = importlib.import_module(f".{_SOURCES[name]}", __name__)
        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__)
