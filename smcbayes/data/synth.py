"""Synthetic measurements with known truth: forward model + a realistic noise model.

The simulated closing force (contact to the limit) and hold displacement are sampled like
a recording, then disturbed by

* white sensor noise (standard deviation ``white_kN``),
* a slowly varying error: a stationary Ornstein-Uhlenbeck / AR(1) process with standard
  deviation ``correlated_kN`` and correlation time ``correlation_s`` (drift, calibration
  and digitising errors that span many samples),
* optionally the quantisation of digitised data: times rounded to ``resolution_s``
  (duplicates dropped), forces to ``resolution_kN``.

The output folder looks like the measured-data folder: ``force/<id>.csv``
(``time_s,force_kN``), ``hold/<id>.csv`` (``time_s,displacement_mm``), a project TOML
pointing at it and ``truth.json`` (parameters, effects, noise, seed).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import ProjectConfig
from smcbayes.data.readers.csv import write_csv
from smcbayes.errors import ConfigError
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.result import SimulationResult

Array = NDArray[np.float64]

PROJECT_FILE = "project.toml"
TRUTH_FILE = "truth.json"


@dataclass(frozen=True)
class NoiseSpec:
    """Noise model of synthetic measurements (all >= 0; 0 switches a part off).

    Attributes:
        white_kN: white force noise standard deviation (kN).
        correlated_kN: standard deviation of the correlated force error (kN).
        correlation_s: its correlation time (s).
        resolution_s, resolution_kN: quantisation of time and force (0: none).
        white_mm: white noise of the hold displacement (mm).
        sample_s: sampling interval of the closing force (s).
        hold_sample_s: sampling interval of the hold displacement (s).
    """

    white_kN: float = 0.0
    correlated_kN: float = 0.0
    correlation_s: float = 1.0
    resolution_s: float = 0.0
    resolution_kN: float = 0.0
    white_mm: float = 0.0
    sample_s: float = 0.02
    hold_sample_s: float = 1.0

    def check(self) -> None:
        """Raise :class:`ConfigError` on negative or zero values where they are not allowed."""
        for name, value in asdict(self).items():
            if not np.isfinite(value) or value < 0:
                raise ConfigError(f"noise {name} = {value}: must be a finite number >= 0")
        for name in ("correlation_s", "sample_s", "hold_sample_s"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"noise {name} must be > 0")


def ou_noise(t: Array, sd: float, tau_s: float, rng: np.random.Generator) -> Array:
    """Stationary Ornstein-Uhlenbeck samples at (uneven) times ``t`` ``(N,)``, sd ``sd``."""
    x = np.empty(t.size)
    if sd == 0:
        return np.zeros(t.size)
    phi = np.exp(-np.diff(t) / tau_s)
    eps = rng.standard_normal(t.size)
    x[0] = sd * eps[0]
    for i in range(1, t.size):
        x[i] = phi[i - 1] * x[i - 1] + sd * np.sqrt(1.0 - phi[i - 1] ** 2) * eps[i]
    return x


def noisy_force(res: SimulationResult, row: int, noise: NoiseSpec,
                rng: np.random.Generator) -> tuple[Array, Array]:
    """Sampled, disturbed closing force ``(time_s, force_kN)`` of one simulated row."""
    t, f = res.time_s[row], res.force_kN[row]
    ts = float(res.switch_time_s[row]) if np.isfinite(res.switch_time_s[row]) else float(t[-1])
    grid = np.append(np.arange(0.0, ts, noise.sample_s), ts)
    grid = grid[np.append(np.diff(grid) > 1e-9 * noise.sample_s, True)]
    value = np.interp(grid, t, f)
    value = value + noise.white_kN * rng.standard_normal(grid.size)
    value = value + ou_noise(grid, noise.correlated_kN, noise.correlation_s, rng)
    if noise.resolution_s > 0:
        grid = np.round(grid / noise.resolution_s) * noise.resolution_s
        keep = np.append(True, np.diff(grid) > 0)
        grid, value = grid[keep], value[keep]
    if noise.resolution_kN > 0:
        value = np.round(value / noise.resolution_kN) * noise.resolution_kN
    return grid, value


def noisy_hold(res: SimulationResult, row: int, noise: NoiseSpec,
               rng: np.random.Generator) -> tuple[Array, Array]:
    """Sampled hold displacement ``(time_s, displacement_mm)`` since the hold start (closing < 0)."""
    t, d = res.time_s[row], res.displacement_mm[row]
    ts = float(res.switch_time_s[row])
    end = t[-1] - ts
    tau = np.arange(noise.hold_sample_s, end + 1e-9, noise.hold_sample_s)
    if tau.size < 2:
        tau = np.linspace(0.0, end, 3)[1:]
    value = -(np.interp(ts + tau, t, d) - np.interp(ts, t, d))
    return tau, value + noise.white_mm * rng.standard_normal(tau.size)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def to_toml(doc: Mapping[str, Any]) -> str:
    """A project document as TOML: scalars, tables, arrays of tables (one level deep)."""
    def is_table(v: Any) -> bool:
        return isinstance(v, Mapping) or (isinstance(v, list) and bool(v) and isinstance(v[0], Mapping))

    lines = [f"{k} = {_toml_value(v)}" for k, v in doc.items() if not is_table(v)]
    for k, v in doc.items():
        if isinstance(v, Mapping):
            lines += ["", f"[{k}]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in v.items()]
        elif isinstance(v, list) and v and isinstance(v[0], Mapping):
            for item in v:
                lines += ["", f"[[{k}]]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in item.items()]
    return "\n".join(lines) + "\n"


def synthetic_project(project: ProjectConfig, ids: Sequence[str], name: str,
                      part_mm: Mapping[str, float] | None = None) -> dict[str, Any]:
    """The source project's document with data_dir '.' and data files of the synthetic curves.

    The source's measured parts belong to its real trials and are dropped; ``part_mm``
    gives each synthetic trial's own part thickness (mm), the simulated gap at the end of
    its hold, so that its end state is the simulation's."""
    doc = project.model_dump(mode="json", exclude_none=True, exclude={"base_dir"})
    doc["name"], doc["data_dir"] = name, "."
    # the written curves are the measurements now: a calibration of this project must not
    # regenerate noiseless truth data in their place
    doc.get("calibration", {}).pop("truth", None)
    base = Path(project.base_dir)
    for c in doc["configuration"]:
        profile = c["press"].get("profile")
        if profile is not None and not Path(profile).is_absolute():
            c["press"]["profile"] = str((base / profile).resolve())
        c.pop("data", None)
        c.pop("part", None)
        if c["id"] in ids:
            c["data"] = {"force": f"force/{c['id']}.csv", "hold": f"hold/{c['id']}.csv"}
            if part_mm and c["id"] in part_mm:
                c["part"] = {"thickness_mm": round(float(part_mm[c["id"]]), 9)}
    return doc


def write_synthetic(model: ForwardModel, ids: Sequence[str], noise: NoiseSpec, seed: int,
                    out: Path, truth: Mapping[str, float], source: str = "") -> Path:
    """Simulate ``ids`` at the model's fixed values, add noise, write the dataset folder.

    Returns:
        The path of the written project TOML.
    """
    noise.check()
    results = model.simulate(None, ids)
    failed = [cid for cid, r in results.items() if not r.ok[0]]
    if failed:
        raise ConfigError(f"the forward model failed at the truth on {', '.join(failed)} "
                          f"({results[failed[0]].status[0]}); choose other --truth values")
    rng = np.random.default_rng(seed)
    (out / "force").mkdir(parents=True, exist_ok=True)
    (out / "hold").mkdir(parents=True, exist_ok=True)
    for cid in ids:
        t, f = noisy_force(results[cid], 0, noise, rng)
        write_csv(out / "force" / f"{cid}.csv", t, f, "force_kN", digits=9)
        t, d = noisy_hold(results[cid], 0, noise, rng)
        write_csv(out / "hold" / f"{cid}.csv", t, d, "displacement_mm", digits=9)
    parts = {cid: float(results[cid].gap_mm[0, -1]) for cid in ids}
    doc = synthetic_project(model.project, ids, f"{model.project.name}-synthetic", parts)
    header = (f"# Synthetic measurements (truth in {TRUTH_FILE}) generated by smcbayes synth "
              f"from {source or model.project.name}\n")
    (out / PROJECT_FILE).write_text(header + to_toml(doc), encoding="utf-8")
    info = {"parameters": model.space.defaults(), "truth": dict(truth),
            "effects": list(model.effects.names), "noise": asdict(noise), "seed": seed,
            "source": source, "configurations": list(ids)}
    (out / TRUTH_FILE).write_text(json.dumps(info, indent=2) + "\n", encoding="utf-8")
    return out / PROJECT_FILE
