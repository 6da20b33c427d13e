"""Typed, validated configuration built once from TOML (and CLI overrides).

A project file holds shared ``[defaults]`` (mould, charge, press, data, part), the material constants,
the calibrated parameters with bounds, the effects switched on, and one
``[[configuration]]`` table per press trial.  Defaults are merged into every
configuration before validation.  Any error becomes a :class:`ConfigError` whose message
is one line naming the key, what is accepted and, for a misspelt key, the closest one.
"""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, Field, ValidationError, model_validator

from smcbayes.config.settings import CalibrationSpec, DiagnoseSpec, PosteriorSpec, Strict
from smcbayes.config.specs import LossSpec, PreprocessSpec
from smcbayes.errors import ConfigError, closest


class MouldSpec(Strict):
    """Rectangular plaque cavity."""

    length_mm: float = Field(305.0, gt=0, description="cavity length along the bar's flow direction")
    width_mm: float = Field(305.0, gt=0, description="cavity width")
    temperature_C: float = Field(135.0, gt=-273.15, lt=1000.0)


class PieceSpec(Strict):
    """One rectangle of a charge layout, centred at (x_mm, y_mm) from the mould centre."""

    x_mm: float = Field(0.0, description="centre along the mould length, from the mould centre")
    y_mm: float = Field(0.0, description="centre across the mould, from the mould centre")
    length_mm: float = Field(gt=0, description="side along the mould length")
    width_mm: float = Field(gt=0, description="side across the mould")


class ChargeSpec(Strict):
    """Charge layout: ``center`` (centred square/rectangle), ``bar`` (full-width strip) or
    ``layout`` (union of rectangles ``pieces``; the 1-D solver uses its equal-area disc)."""

    shape: Literal["center", "bar", "layout"]
    pieces: list[PieceSpec] | None = Field(None, description="rectangles of a layout charge")
    coverage_pct: float | None = Field(None, gt=0, le=100)
    length_mm: float | None = Field(None, gt=0, description="explicit size along the flow direction")
    width_mm: float | None = Field(None, gt=0, description="explicit size across (center only)")
    stack_height_mm: float = Field(8.0, gt=0)
    mass_g: float | None = Field(None, gt=0)
    temperature_C: float | None = Field(None, gt=-273.15, lt=1000.0,
                                        description="charge start temperature (heating effect)")

    @model_validator(mode="after")
    def _size_given(self) -> ChargeSpec:
        if self.shape == "layout":
            if not self.pieces:
                raise ValueError("a layout charge needs pieces = [{ x_mm, y_mm, length_mm, width_mm }, ...]")
            if self.coverage_pct is not None or self.length_mm is not None or self.width_mm is not None:
                raise ValueError("a layout charge takes its size from pieces; "
                                 "remove coverage_pct/length_mm/width_mm")
            return self
        if self.pieces is not None:
            raise ValueError("pieces need shape = \"layout\"")
        if self.coverage_pct is None and self.length_mm is None:
            raise ValueError("give coverage_pct or length_mm")
        return self


class PressSpec(Strict):
    """Press programme: speed control until the force limit, then force control."""

    speed_mm_s: float = Field(gt=0)
    force_limit_kN: float = Field(1400.0, gt=0)
    hold_s: float = Field(500.0, ge=0)
    profile: str | None = Field(None, description="CSV of measured ram position vs time")


class DataSpec(Strict):
    """Files of measured curves, relative to the project's data directory."""

    force: str | None = None
    hold: str | None = None
    displacement: str | None = None
    format: Literal["csv", "press", "moldflow"] = "csv"
    time_column: str | None = Field(None, description="csv: time column (default time_s)")
    force_column: str | None = Field(None, description="default force_kN (csv), dbPr\\diIstKraftGes (press)")
    displacement_column: str | None = Field(None, description="default displacement_mm (csv), "
                                                              "dbPr\\diIstPos (press)")
    force_unit: str | None = Field(None, description="N, kN, MN, tonne-force; default from the file")
    displacement_unit: str | None = Field(None, description="mm, m, um; default from the file")


class PartSpec(Strict):
    """The moulded part as measured after demoulding.

    Its thickness is the gap at the end of the force-controlled hold; with the hold's
    closing and the ram's travel to the force limit it says how high the charge stood at
    first contact (``[loss] contact = "end_state"``).  Give ``thickness_mm``, or
    ``mass_g`` (flash removed) with ``density_g_cm3``, which spreads the mass over the
    whole cavity at the consolidated density.
    """

    thickness_mm: float | None = Field(None, gt=0, description="measured thickness of the part")
    mass_g: float | None = Field(None, gt=0, description="mass of the part after demoulding, flash removed")
    density_g_cm3: float | None = Field(None, gt=0, description="consolidated density "
                                                                "that turns mass_g into a "
                                        "thickness (e.g. in [defaults.part])")

    @model_validator(mode="after")
    def _one_measure(self) -> PartSpec:
        if self.thickness_mm is not None and self.mass_g is not None:
            raise ValueError("give part.thickness_mm or part.mass_g, not both")
        if self.mass_g is not None and self.density_g_cm3 is None:
            raise ValueError("part.mass_g needs part.density_g_cm3 (the consolidated density, "
                             "e.g. 1.5 for CF-epoxy SMC at 60 wt% fibre) to give a thickness")
        return self

    def thickness(self, mould: MouldSpec) -> float | None:
        """The part's thickness (mm): measured, or its mass over the cavity at the
        consolidated density; None when neither is given."""
        if self.thickness_mm is not None:
            return self.thickness_mm
        if self.mass_g is None or self.density_g_cm3 is None:
            return None
        return self.mass_g / (self.density_g_cm3 * mould.length_mm * mould.width_mm) * 1e3


class ConfigurationSpec(Strict):
    """One press trial setup."""

    id: str = Field(min_length=1)
    role: Literal["train", "validation"] = "train"
    mould: MouldSpec = MouldSpec()
    charge: ChargeSpec
    press: PressSpec
    data: DataSpec | None = None
    part: PartSpec | None = None


class MaterialSpec(Strict):
    """Material constants that are neither calibrated nor owned by an effect.

    The Arrhenius activation temperature and the cure constants belong to the heating and
    curing effects; the isothermal, cure-free base model does not need them.
    """

    slip_coefficient: float = Field(1e-8, ge=0, description="a_s of the slip law, SI (m/s/Pa^m)")
    slip_threshold_exponent: float = Field(10.0, gt=0)


class ParameterSpec(Strict):
    """A calibrated parameter: value (fixes it if ``fixed``) and search bounds."""

    value: float | None = None
    bounds: tuple[float, float] | None = None
    fixed: bool = False


class SolverSpec(Strict):
    """Discretisation of the forward solver."""

    fidelity: Literal["1d", "2d"] = "1d"
    closing_steps: int = Field(300, ge=20, le=100000)
    hold_steps: int = Field(60, ge=5, le=100000)
    stress_points_per_decade: int = Field(12, ge=4, le=400)
    output_closing_points: int = Field(200, ge=10, le=100000)
    output_hold_points: int = Field(50, ge=2, le=100000)
    shape_correction: bool = Field(True, description="1-D: correct the equal-area disc of a centred "
                                   "square charge towards the 2-D force")
    cells_2d: int = Field(48, ge=4, le=4096, description="2-D grid: cells along the longer mould side")
    courant_2d: float = Field(0.5, gt=0, le=1.0, description="2-D front: largest cell share filled per step")
    closing_steps_2d: int = Field(100, ge=5, le=100000, description="2-D: minimum steps over the closing")
    hold_steps_2d: int = Field(40, ge=5, le=100000, description="2-D: minimum steps under force control")


class ProjectConfig(Strict):
    """A whole project file."""

    name: str = "smcbayes"
    data_dir: str | None = None
    material: MaterialSpec = MaterialSpec()
    parameters: dict[str, ParameterSpec] = {}
    effects: list[str] = []
    solver: SolverSpec = SolverSpec()
    calibration: CalibrationSpec = CalibrationSpec()
    posterior: PosteriorSpec = PosteriorSpec()
    diagnose: DiagnoseSpec = DiagnoseSpec()
    preprocess: PreprocessSpec = PreprocessSpec()
    loss: LossSpec = LossSpec()
    configuration: list[ConfigurationSpec] = Field(min_length=1)
    base_dir: str = "."

    @model_validator(mode="after")
    def _unique_ids(self) -> ProjectConfig:
        ids = [c.id for c in self.configuration]
        dup = {i for i in ids if ids.count(i) > 1}
        if dup:
            raise ValueError(f"configuration ids must be unique; repeated: {sorted(dup)}")
        return self

    def get(self, config_id: str) -> ConfigurationSpec:
        """Configuration by id; unknown ids raise with the closest match."""
        ids = [c.id for c in self.configuration]
        for c in self.configuration:
            if c.id == config_id:
                return c
        raise ConfigError(f"unknown configuration '{config_id}'{closest(config_id, ids)}; "
                          f"available: {', '.join(ids)}")

    def data_path(self) -> Path | None:
        """Absolute data directory (relative paths are taken from the config file)."""
        if self.data_dir is None:
            return None
        p = Path(self.data_dir).expanduser()
        return p if p.is_absolute() else (Path(self.base_dir) / p).resolve()


_MODELS: dict[str, type[BaseModel]] = {
    "": ProjectConfig, "configuration": ConfigurationSpec, "mould": MouldSpec,
    "charge": ChargeSpec, "pieces": PieceSpec, "press": PressSpec, "data": DataSpec, "material": MaterialSpec,
    "solver": SolverSpec, "parameters": ParameterSpec, "calibration": CalibrationSpec,
    "posterior": PosteriorSpec, "diagnose": DiagnoseSpec,
    "preprocess": PreprocessSpec, "loss": LossSpec,
}


def _model_for(loc: tuple[Any, ...]) -> type[BaseModel]:
    names = [p for p in loc if isinstance(p, str)]
    for name in reversed(names[:-1]):
        if name in _MODELS:
            return _MODELS[name]
    return ProjectConfig


def _where(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def format_validation_error(err: ValidationError, source: str) -> str:
    """One line for the first error of ``err``: the key, what is wrong, what is accepted."""
    errors = err.errors()
    # a misspelt key also makes the key it stands for missing: report the misspelling
    e = next((x for x in errors if x["type"] == "extra_forbidden"), errors[0])
    loc = tuple(p for p in e["loc"] if p not in ("function-after",))
    key = _where(loc)
    kind = e["type"]
    if kind == "extra_forbidden":
        fields = list(_model_for(loc).model_fields)
        fields = [f for f in fields if f != "base_dir"]
        hint = closest(str(loc[-1]), fields)
        return f"{source}: unknown key '{key}'{hint}; accepted here: {', '.join(fields)}"
    if kind == "missing":
        return f"{source}: required key '{key}' is missing"
    if kind == "literal_error":
        expected = e.get("ctx", {}).get("expected", "")
        return f"{source}: {key} = {e.get('input')!r} is not accepted; accepted: {expected}"
    msg = e["msg"].removeprefix("Value error, ")
    return f"{source}: {key} = {e.get('input')!r}: {msg}" if loc else f"{source}: {msg}"


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(dict(base))
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) else v
    return out


def build_project(raw: Mapping[str, Any], source: str, base_dir: Path) -> ProjectConfig:
    """Validate a parsed TOML document; ``[defaults]`` is merged into every configuration."""
    raw = dict(raw)
    defaults = raw.pop("defaults", {})
    if not isinstance(defaults, Mapping):
        raise ConfigError(f"{source}: [defaults] must be a table")
    accepted = ["mould", "charge", "press", "data", "part"]
    unknown = set(defaults) - set(accepted)
    if unknown:
        key = sorted(unknown)[0]
        raise ConfigError(f"{source}: unknown key 'defaults.{key}'"
                          f"{closest(key, accepted)}; accepted here: {', '.join(accepted)}")
    configs = raw.get("configuration", [])
    if isinstance(configs, list):
        raw["configuration"] = [_merge(defaults, c) if isinstance(c, Mapping) else c for c in configs]
    raw["base_dir"] = str(base_dir)
    try:
        return ProjectConfig.model_validate(raw)
    except ValidationError as err:
        raise ConfigError(format_validation_error(err, source)) from None


def load_project(path: str | Path, data_dir: str | Path | None = None) -> ProjectConfig:
    """Read and validate a project TOML file.

    Args:
        path: the TOML file.
        data_dir: overrides the file's ``data_dir`` (absolute, or relative to the cwd).
    """
    path = Path(path)
    if path.is_dir():
        found = sorted(p.name for p in path.glob("*.toml"))
        hint = f"; it holds {', '.join(found)}" if found else ""
        raise ConfigError(f"{path}: is a directory; give the project TOML file, e.g. "
                          f"{path / (found[0] if found else 'project.toml')}{hint}")
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from None
    project = build_project(raw, str(path), path.resolve().parent)
    if data_dir is not None:
        project = project.model_copy(update={"data_dir": str(Path(data_dir).resolve())})
    return project


def parse_assignments(items: list[str] | None, option: str = "--set") -> dict[str, float]:
    """Parse ``name=value`` strings from the command line into floats."""
    out: dict[str, float] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ConfigError(f"{option} {item!r}: expected name=value, e.g. n=0.4")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"{option} {item!r}: value {value!r} is not a number") from None
    return out
