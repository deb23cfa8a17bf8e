"""Pydantic configuration of a pipeline run, loaded from YAML presets.

A preset names a segmenter and a fitter from the registry and their parameters; the
parameters are validated against the plugin's own model at load time, so a typo or an
out-of-range value fails before any scan is touched, with the field and value named.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from . import registry

__all__ = ["StageConfig", "RefineConfig", "PipelineConfig", "load_config", "preset_dir", "presets"]


class StageConfig(BaseModel):
    """A registered plugin chosen by name, with its parameters."""

    model_config = ConfigDict(extra="forbid")

    name: str
    params: dict[str, Any] = Field(default_factory=dict)


class RefineConfig(BaseModel):
    """Beyond the paper (its Sec. 6 future work): give edge-band pixels back, merge patches.

    recover_leftovers : fit compact blobs of unlabelled pixels (small curved objects that the
        edge band swallowed whole) and keep those a model explains.
    grow_iterations : rounds of handing unlabelled pixels to a neighbouring region whose
        fitted surface lies within ``k_sigma * max(sigma(r), model rms)`` of them (one pixel
        ring per round; no crossing of jump edges).
    k_sigma : acceptance distance in units of the local noise.
    merge : merge regions of the same kind whose union is explained as well as the parts.
    merge_disjoint : also merge regions that do not touch (one wall split by an occluder).
    merge_angle_deg : maximum angle between normals / axes of merge candidates.
    merge_rms_factor : the union's rms may exceed the larger part's rms by this factor.
    merge_tolerance : metres; offsets, radii and centres of merge candidates must agree within it.
    sigma0, sigma_quadratic : the noise model (see rangeseg_o3d.residual.noise_sigma); None
        takes the segmenter's own ``sigma0``/``sigma_quadratic`` parameters (else 5 mm, 0).
    """

    model_config = ConfigDict(extra="forbid")

    enabled: bool = True
    recover_leftovers: bool = True
    grow_iterations: int = Field(3, ge=0, le=20)
    k_sigma: float = Field(3.0, gt=0)
    merge: bool = True
    merge_disjoint: bool = True
    merge_angle_deg: float = Field(3.0, gt=0, le=90)
    merge_rms_factor: float = Field(1.3, ge=1.0)
    merge_tolerance: float = Field(0.05, gt=0)
    sigma0: float | None = Field(None, ge=0)
    sigma_quadratic: float | None = Field(None, ge=0)


class PipelineConfig(BaseModel):
    """A whole run: sensor preset name, segmenter, fitter, refinement."""

    model_config = ConfigDict(extra="forbid")

    name: str = "custom"
    segmenter: StageConfig = Field(default_factory=lambda: StageConfig(name="residual_edges"))
    fitter: StageConfig = Field(default_factory=lambda: StageConfig(name="primitives"))
    refine: RefineConfig = Field(default_factory=RefineConfig)
    max_fit_points: int = Field(
        3000, ge=50,
        description="regions with more points are fitted on an even subsample of this size",
    )
    tile: int = Field(
        1, ge=1, le=16,
        description="segment, fit and refine the grid of tile x tile means, then label every "
                    "pixel by the models (depth cameras: the noise hides creases at full resolution)",
    )

    @model_validator(mode="after")
    def _validate_plugins(self):
        for kind, stage in (("segmenter", self.segmenter), ("fitter", self.fitter)):
            plugin = registry.get(kind, stage.name)
            # Normalise to the plugin's validated, complete parameter set.
            try:
                stage.params = plugin.config(**stage.params).model_dump()
            except ValidationError as exc:
                problems = "; ".join(
                    f"{kind}.params.{'.'.join(str(p) for p in err['loc'])}: {err['msg']}"
                    f" (got {err.get('input')!r})"
                    for err in exc.errors()
                )
                raise ValueError(problems) from None
        return self


def preset_dir() -> Path:
    """The configs/ folder beside the package (a source checkout or editable install)."""
    return Path(__file__).resolve().parent.parent / "configs"


def presets() -> list[str]:
    """Names of the preset files in :func:`preset_dir`."""
    folder = preset_dir()
    return sorted(p.stem for p in folder.glob("*.yaml")) if folder.is_dir() else []


def _format_error(source: str, exc: ValidationError) -> str:
    lines = [f"invalid configuration in {source}:"]
    for err in exc.errors():
        where = ".".join(str(p) for p in err["loc"]) or "(top level)"
        value = err.get("input")
        shown = repr(value) if not isinstance(value, dict) else "{...}"
        lines.append(f"  {where}: {err['msg']} (got {shown})")
    return "\n".join(lines)


def load_config(source: str | Path | dict | PipelineConfig | None = None) -> PipelineConfig:
    """Load a :class:`PipelineConfig`.

    Parameters
    ----------
    source : a YAML path, a preset name (``"lms200"``, ``"rgbd_vga"``, ... from configs/),
        a dict, an existing PipelineConfig, or None for the default (lms200).

    Raises
    ------
    ValueError
        Unknown preset or file, unreadable YAML, or invalid values (field and value named).
    """
    if isinstance(source, PipelineConfig):
        return source
    if source is None:
        source = "lms200"
    if isinstance(source, dict):
        data, where = source, "dict"
    else:
        path = Path(source)
        if not path.suffix and not path.exists():
            path = preset_dir() / f"{source}.yaml"
            if not path.exists():
                raise ValueError(
                    f"unknown preset {str(source)!r}; known presets: {', '.join(presets())} "
                    "(or give a path to a YAML file)"
                )
        if not path.is_file():
            raise ValueError(f"configuration file {str(path)!r} does not exist")
        try:
            data = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            raise ValueError(f"configuration file {path} is not valid YAML: {exc}") from None
        if not isinstance(data, dict):
            raise ValueError(f"configuration file {path} must hold a mapping; got {type(data).__name__}")
        where = str(path)
    try:
        return PipelineConfig(**data)
    except ValidationError as exc:
        raise ValueError(_format_error(where, exc)) from None
