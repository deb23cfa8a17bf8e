"""Pydantic configuration of a pipeline run, loaded from YAML presets.

A preset describes its sensor (``sensor:``: noise model, units, grid, working ranges),
names a segmenter and a fitter from the registry with their parameters, and sets the
refinement. Everything is validated at load time (plugin parameters against the
plugin's own model), so a typo or an out-of-range value fails before any scan is
touched, with the field and value named. ``load_config(..., overrides={"sensor.sigma0":
0.01})`` changes single values by dotted key without editing the YAML.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, model_validator

from . import registry
from .cloud import DEFAULT_MAX_GRID_POINTS
from .sensor import UNIT_SCALES, NoiseModel, Sensor

__all__ = ["SensorConfig", "StageConfig", "RefineConfig", "PipelineConfig", "load_config",
           "parse_overrides", "apply_overrides", "preset_dir", "presets"]


class SensorConfig(BaseModel):
    """The ``sensor:`` section: facts about the scanner, resolved into a :class:`Sensor`.

    sigma0, sigma_quadratic : range noise ``sigma(r) = sigma0 + sigma_quadratic r^2`` (m).
    noise_correlation_px : neighbouring returns err together over this many pixels square
        (stereo matching averages disparity over a window); means of tiles then average
        fewer independent returns (:meth:`rangeseg_o3d.sensor.NoiseModel.mean_scale`).
    units : unit of the coordinates in the sensor's ``.pcd`` / ``.npz`` files; inputs are
        converted to metres when read (formats with a unit of their own, such as 3DTK's
        ``.3d`` in cm, are converted by their reader).
    wrap_columns : the columns close a full turn (360-degree scanners).
    row_spacing_deg, column_spacing_deg : angular step between rows / columns, if known.
    min_range, max_range : working ranges (m), for the unit plausibility check.
    depth_step : the depth quantisation step (m) of a sensor that reports depth in steps
        (8-bit structured light); 0 for none.
    step_quadratic : the depth step ``step_quadratic r^2`` (1/m) of a camera that measures
        disparity in fixed sub-pixel steps (Kinect v1: 1/8 px); 0 for none
        (:class:`rangeseg_o3d.sensor.NoiseModel`).
    lateral_noise_px : rms offset across its ray, in grid steps, of the point a return
        measures (a camera's spot or blur wider than its pixel); 0 for none.
    beam_width_deg : a laser beam's full width (deg), whose returns straddling an occlusion
        are mixed between the two surfaces; 0 for none stated.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    sigma0: float = Field(0.005, ge=0, description="constant range noise, m")
    sigma_quadratic: float = Field(0.0, ge=0, description="range noise growth, 1/m (sigma += this * r^2)")
    noise_correlation_px: int = Field(1, ge=1, le=64, description="returns err together over this many "
                                      "pixels square (a stereo camera's matching window)")
    units: Literal[tuple(UNIT_SCALES)] = Field("m", description="unit of the input coordinates")
    wrap_columns: bool = Field(False, description="first and last column are neighbours (360 deg)")
    row_spacing_deg: float | None = Field(None, gt=0, le=360)
    column_spacing_deg: float | None = Field(None, gt=0, le=360)
    min_range: float = Field(0.01, ge=0, description="shortest working range, m")
    max_range: float = Field(1000.0, gt=0, description="longest working range, m")
    depth_step: float = Field(0.0, ge=0, description="depth quantisation step, m (0: none)")
    step_quadratic: float = Field(0.0, ge=0, description="depth step growing with the range, 1/m "
                                  "(step = this * r^2; 0: none)")
    lateral_noise_px: float = Field(0.0, ge=0, le=16, description="rms offset across the ray of the point a "
                                    "return measures, grid steps (0: none)")
    beam_width_deg: float = Field(0.0, ge=0, le=180, description="a laser beam's full width, deg: its returns "
                                  "straddling an occlusion are mixed (0: none stated)")

    @model_validator(mode="after")
    def _check(self):
        if self.sigma0 == 0 and self.sigma_quadratic == 0:
            raise ValueError("sigma0 and sigma_quadratic cannot both be 0 (the noise model would be zero)")
        if self.min_range >= self.max_range:
            raise ValueError(f"min_range ({self.min_range}) must be below max_range ({self.max_range})")
        return self

    def resolve(self) -> Sensor:
        """The immutable :class:`Sensor` every stage receives."""
        noise = NoiseModel(self.sigma0, self.sigma_quadratic, self.noise_correlation_px, self.step_quadratic)
        return Sensor(noise=noise, units=self.units, wrap_columns=self.wrap_columns,
                      row_spacing_deg=self.row_spacing_deg, column_spacing_deg=self.column_spacing_deg,
                      min_range=self.min_range, max_range=self.max_range, depth_step=self.depth_step,
                      lateral_noise_px=self.lateral_noise_px, beam_width_deg=self.beam_width_deg)


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
    merge_disjoint : also merge regions that do not touch (one wall split by an occluder); and
        let the recover step give unlabelled strips a plane region's surface passes through,
        apart from it, to that region (``refinement.recover.claim_occluded_strips``).
    merge_angle_deg : maximum angle between normals / axes of merge candidates.
    merge_rms_factor : the union's rms may exceed the larger part's rms by this factor.
    merge_tolerance : metres; offsets, radii and centres of merge candidates must agree within
        it. Left out: derived from the sensor's noise (:mod:`rangeseg_o3d.scales`).
    close_gaps : on a tile grid, after the full-resolution labelling: regions grow into the
        free pixels their models explain until none joins, then pieces of one plane that meet
        merge (:func:`rangeseg_o3d.fullres.grow_into_free`,
        :func:`rangeseg_o3d.fullres.merge_touching_planes`), and the surfaces split out of a
        leftover blob are held to the recovered floor, not the blob floor
        (:func:`rangeseg_o3d.fullres.recover_thin_surfaces`), and the free strips too thin
        for a blob's 3x3 core (a face seen edge-on) come with the blobs, each fitted on its
        own, not in the batched step after the off-model step
        (:func:`rangeseg_o3d.strips.recover_strips`). Off by default: it costs one or two
        passes over the frame (about 1-3 ms CPU per 640 x 480 frame).
    min_region_size : smallest region the refinement keeps or creates (sensor pixels).
    jump_ratio, jump_min : growth never crosses a range step over ``max(jump_ratio r, jump_min)``
        (``jump_ratio`` per sensor pixel step; see :func:`rangeseg_o3d.segmentation.edges.jump_edges`).
        Left out, each takes the segmenter's parameter of the same name when it sets one
        (resolved once at load), else it is derived from the sensor for each scan
        (:func:`rangeseg_o3d.scales.derive_scales`), as the segmenter's own.

    The noise model is the sensor's (``sensor:``).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    enabled: bool = True
    recover_leftovers: bool = True
    grow_iterations: int = Field(3, ge=0, le=20)
    k_sigma: float = Field(3.0, gt=0)
    merge: bool = True
    merge_disjoint: bool = True
    merge_angle_deg: float = Field(3.0, gt=0, le=90)
    merge_rms_factor: float = Field(1.3, ge=1.0)
    merge_tolerance: float | None = Field(None, gt=0)
    close_gaps: bool = False
    min_region_size: int | None = Field(None, ge=1)
    jump_ratio: float | None = Field(None, gt=0)
    jump_min: float | None = Field(None, ge=0)


# What the refinement shares with a segmenter that has the same parameter (None when the
# segmenter has none or leaves it to the sensor: derived per scan, rangeseg_o3d.scales).
_SHARED_WITH_SEGMENTER = ("min_region_size", "jump_ratio", "jump_min")
# Keys that moved to the sensor section, for a helpful error on old configuration files.
_MOVED = {
    ("segmenter", "params", "sigma0"): "sensor.sigma0",
    ("segmenter", "params", "sigma_quadratic"): "sensor.sigma_quadratic",
    ("refine", "sigma0"): "sensor.sigma0",
    ("refine", "sigma_quadratic"): "sensor.sigma_quadratic",
    ("fitter", "params", "rms_per_range2"):
        "sensor.sigma_quadratic (the fitter's thresholds grow by fitter.params.range_growth times it)",
}


class PipelineConfig(BaseModel):
    """A whole run: sensor preset name, segmenter, fitter, refinement."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: str = "custom"
    sensor: SensorConfig = Field(default_factory=SensorConfig)
    # refine fields left out that took the segmenter's value (or the default) at load
    _refine_resolved: set = PrivateAttr(default_factory=set)
    segmenter: StageConfig = Field(default_factory=lambda: StageConfig(name="residual_edges"))
    fitter: StageConfig = Field(default_factory=lambda: StageConfig(name="primitives"))
    refine: RefineConfig = Field(default_factory=RefineConfig)
    max_fit_points: int = Field(
        3000, ge=50,
        description="regions with more points are fitted on an even subsample of this size",
    )
    max_grid_points: int = Field(
        DEFAULT_MAX_GRID_POINTS, ge=1,
        description="largest grid (rows x columns) the command line loads; a bigger one is an "
                    "error before anything is allocated (library: rangeseg_o3d.cloud.set_max_grid_points)",
    )
    tile: int | None = Field(
        1, ge=1, le=16,
        description="segment, fit and refine the grid of tile x tile means, then label every "
                    "pixel by the models (depth cameras: the noise hides creases at full "
                    "resolution); null: derived per scan from the sensor's noise and spacing "
                    "(rangeseg_o3d.scales)",
    )

    @model_validator(mode="before")
    @classmethod
    def _moved_keys(cls, data):
        if isinstance(data, dict):
            for path, target in _MOVED.items():
                node = data
                for key in path[:-1]:
                    node = node.get(key) if isinstance(node, dict) else None
                if isinstance(node, dict) and path[-1] in node:
                    raise ValueError(f"{'.'.join(path)} has moved to {target}")
        return data

    @model_validator(mode="after")
    def _validate_plugins(self):
        for kind, stage in (("segmenter", self.segmenter), ("fitter", self.fitter)):
            plugin = registry.get(kind, stage.name)
            # Normalise to the plugin's validated, complete parameter set.
            try:
                stage.params = plugin.config(**stage.params).model_dump()
            except TypeError:
                raise ValueError(f"{kind}.params must be a mapping of parameter names to values; "
                                 f"got {stage.params!r}") from None
            except ValidationError as exc:
                problems = "; ".join(
                    f"{kind}.params.{'.'.join(str(p) for p in err['loc'])}: {err['msg']}"
                    f" (got {err.get('input')!r})"
                    for err in exc.errors()
                )
                raise ValueError(problems) from None
            for name, value in _non_finite(stage.params):
                raise ValueError(f"{kind}.params.{name} must be a finite number; got {value!r}")
        # Resolve once what the refinement shares with the segmenter.
        for key in _SHARED_WITH_SEGMENTER:
            if getattr(self.refine, key) is None:
                setattr(self.refine, key, self.segmenter.params.get(key))
                self._refine_resolved.add(key)
        return self


def _non_finite(params: dict, prefix: str = ""):
    """(dotted name, value) of every float in ``params`` that is NaN or infinite.

    Plugins' own models may not forbid them; a threshold of inf would silently turn
    every edge off.
    """
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _non_finite(value, f"{name}.")
        elif isinstance(value, (list, tuple)):
            yield from _non_finite({str(i): v for i, v in enumerate(value)}, f"{name}.")
        elif isinstance(value, float) and not math.isfinite(value):
            yield name, value


def preset_dir() -> Path:
    """The folder of the preset YAML files.

    The presets live in the repository's top-level ``configs/``; a wheel or sdist install
    carries them as package data in ``rangeseg_o3d/configs/`` (pyproject.toml maps the
    one onto the other). A source checkout or editable install has no such copy and uses
    ``configs/`` beside the package, recognised by the ``pyproject.toml`` next to it.
    """
    package = Path(__file__).resolve().parent
    installed = package / "configs"
    if installed.is_dir():
        return installed
    checkout = package.parent
    if (checkout / "pyproject.toml").is_file():
        return checkout / "configs"
    return installed


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


def parse_overrides(items) -> dict[str, Any]:
    """``["sensor.sigma0=0.01", "refine.merge=false"]`` -> ``{"sensor.sigma0": 0.01, ...}``.

    Values are read as YAML scalars (numbers, true/false, null, strings); pydantic then
    validates them as the field requires.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = str(item).partition("=")
        if not sep or not key.strip():
            raise ValueError(f"an override must look like KEY=VALUE (e.g. sensor.sigma0=0.01); got {item!r}")
        try:
            out[key.strip()] = yaml.safe_load(text) if text.strip() else text
        except yaml.YAMLError as exc:
            raise ValueError(f"override {item!r}: the value is not a YAML scalar: {exc}") from None
    return out


def _section_model(section: str, data: dict) -> type[BaseModel]:
    # The parameter model of the plugin the (partly overridden) data names.
    default = PipelineConfig.model_fields[section].default_factory().name
    stage = data.get(section)
    name = stage.get("name", default) if isinstance(stage, dict) else default
    return registry.get(section, name).config


def _check_key(dotted: str, data: dict) -> None:
    """ValueError unless ``dotted`` names one value of the configuration."""
    path = dotted.split(".")
    model: type[BaseModel] = PipelineConfig
    for depth, key in enumerate(path):
        where = ".".join(path[:depth]) or "the configuration"
        fields = model.model_fields
        if key not in fields:
            raise ValueError(f"unknown configuration key {dotted!r}: {where} has no {key!r} "
                             f"(it has {', '.join(fields)})")
        if model is StageConfig and key == "params":
            model = _section_model(path[depth - 1], data)
            continue
        annotation = fields[key].annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            model = annotation
            continue
        if depth != len(path) - 1:
            raise ValueError(f"unknown configuration key {dotted!r}: {'.'.join(path[:depth + 1])} "
                             "is a value, not a section")
        return
    raise ValueError(f"configuration key {dotted!r} names a section; give one of its keys "
                     f"({', '.join(f'{dotted}.{k}' for k in model.model_fields)})")


def apply_overrides(data: dict, overrides: dict[str, Any]) -> dict:
    """A copy of the configuration mapping ``data`` with dotted-key ``overrides`` set.

    Stage names (``segmenter.name``, ``fitter.name``) are set first, so that their
    parameters are checked against the plugin chosen. Unknown keys raise ValueError
    naming them.
    """
    data = copy.deepcopy(data)
    ordered = sorted(overrides.items(), key=lambda item: not item[0].endswith(".name"))
    for dotted, value in ordered:
        if not isinstance(dotted, str):
            raise ValueError(f"override keys must be dotted strings; got {dotted!r}")
        _check_key(dotted, data)
        *parents, leaf = dotted.split(".")
        node = data
        for key in parents:
            if not isinstance(node.get(key), dict):
                node[key] = {}
            node = node[key]
        node[leaf] = value
    return data


def _read_source(source) -> tuple[dict, str]:
    if isinstance(source, PipelineConfig):
        data = source.model_dump()
        for key in source._refine_resolved:  # resolved again, after the overrides
            data["refine"][key] = None
        return data, f"configuration {source.name!r}"
    if isinstance(source, dict):
        return source, "dict"
    path = Path(source)
    if not path.suffix and not path.exists():
        path = preset_dir() / f"{source}.yaml"
        if not path.exists():
            raise ValueError(
                f"unknown preset {str(source)!r}; known presets: {', '.join(presets())} "
                "(or give a path to a YAML file)"
            )
    if not path.is_file():
        what = "is not a regular file" if path.exists() else "does not exist"
        raise ValueError(f"configuration file {str(path)!r} {what}")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"configuration file {path} is not valid YAML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"configuration file {path} is not UTF-8 text (a YAML file): {exc}") from None
    except OSError as exc:
        raise ValueError(f"configuration file {path} cannot be read: {exc.strerror or exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"configuration file {path} must hold a mapping; got {type(data).__name__}")
    return data, str(path)


def load_config(source: str | Path | dict | PipelineConfig | None = None, *,
                overrides: dict[str, Any] | None = None) -> PipelineConfig:
    """Load a :class:`PipelineConfig`.

    Parameters
    ----------
    source : a YAML path, a preset name (``"lms200"``, ``"rgbd_vga"``, ... from configs/),
        a dict, an existing PipelineConfig, or None for the default (lms200).
    overrides : dotted keys and values set over the source, e.g.
        ``{"sensor.sigma0": 0.01, "refine.k_sigma": 2.5, "segmenter.params.threshold": 5}``.

    Raises
    ------
    ValueError
        Unknown preset or file, unreadable YAML, unknown override keys, or invalid values
        (field and value named).

    Examples
    --------
    >>> load_config("lms200", overrides={"sensor.sigma0": 0.01}).sensor.sigma0
    0.01
    """
    if isinstance(source, PipelineConfig) and not overrides:
        return source
    data, where = _read_source("lms200" if source is None else source)
    if overrides:
        try:
            data = apply_overrides(data, overrides)
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
        where += " with overrides " + ", ".join(f"{k}={v!r}" for k, v in overrides.items())
    try:
        return PipelineConfig(**data)
    except ValidationError as exc:
        raise ValueError(_format_error(where, exc)) from None
