"""Shared helpers of the posterior benchmarks: synthetic project, data, calibration, posterior.

A benchmark problem is a project document (plaque geometry of the thesis, a few press
configurations, a coarsened 1-D solver so that an exact posterior on the forward model is
affordable) written to a temporary folder; ``smcbayes synth``'s writer simulates it at the
truth and adds white + correlated force noise; the calibration and the posterior stage then
run exactly as the CLI runs them, on the same (coarsened) model.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from smcbayes.config import load_project
from smcbayes.data.synth import NoiseSpec, to_toml, write_synthetic
from smcbayes.forward.model import ForwardModel

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

BOUNDS: dict[str, tuple[float, float]] = {
    "n": (0.2, 0.6), "tau_star_Pa": (1.0e3, 1.0e5), "B_Pa_s": (1.0e3, 1.0e5),
    "tau_c_MPa": (0.005, 1.0), "m": (1.0, 1.9),
}
DEFAULTS: dict[str, float] = {"n": 0.4, "tau_star_Pa": 1.0e4, "B_Pa_s": 1.0e4, "tau_c_MPa": 0.05, "m": 1.5}
CONFIGS: dict[str, tuple[str, float, float, float]] = {
    # id: (shape, coverage %, mass g, speed mm/s)
    "60-bar-03": ("bar", 60.0, 388.0, 0.3),
    "60-bar-11": ("bar", 60.0, 414.0, 1.1),
    "60-center-07": ("center", 60.0, 398.0, 0.7),
    "80-bar-07": ("bar", 80.0, 520.0, 0.7),
    "80-center-03": ("center", 80.0, 500.0, 0.3),
    "80-center-11": ("center", 80.0, 510.0, 1.1),
}
NOISE = NoiseSpec(white_kN=5.0, correlated_kN=3.0, correlation_s=0.5)
COARSE_SOLVER = {"closing_steps": 120, "hold_steps": 20, "stress_points_per_decade": 6,
                 "output_closing_points": 120, "output_hold_points": 20}


def project_doc(free: Sequence[str], values: Mapping[str, float], train: Sequence[str],
                validation: Sequence[str] = (), solver: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A project document: ``free`` parameters searched in :data:`BOUNDS`, the rest fixed."""
    params = {}
    for name, (lo, hi) in BOUNDS.items():
        v = float(values.get(name, DEFAULTS[name]))
        params[name] = {"value": v, "bounds": [lo, hi]} if name in free else {"value": v, "fixed": True}
    configs = []
    for role, ids in (("train", train), ("validation", validation)):
        for cid in ids:
            shape, cov, mass, speed = CONFIGS[cid]
            configs.append({"id": cid, "role": role,
                            "charge": {"shape": shape, "coverage_pct": cov, "mass_g": mass},
                            "press": {"speed_mm_s": speed}})
    return {"name": "posterior-benchmark",
            "defaults": {"mould": {"length_mm": 305.0, "width_mm": 305.0, "temperature_C": 135.0},
                         "charge": {"stack_height_mm": 8.0},
                         "press": {"force_limit_kN": 1400.0, "hold_s": 500.0}},
            "parameters": params, "solver": dict(solver or COARSE_SOLVER), "configuration": configs}


def make_dataset(folder: Path, doc: Mapping[str, Any], truth: Mapping[str, float], seed: int,
                 noise: NoiseSpec = NOISE) -> Path:
    """Write the source project and its noisy synthetic data; returns the data project TOML."""
    folder.mkdir(parents=True, exist_ok=True)
    source = folder / "source.toml"
    source.write_text(to_toml(doc), encoding="utf-8")
    project = load_project(source)
    model = ForwardModel(project, overrides=dict(truth))
    ids = [c["id"] for c in doc["configuration"]]
    return write_synthetic(model, ids, noise, seed, folder / "data", truth, source=str(source))


def calibrate_run(project_toml: Path, run_dir: Path, budget: int, init: int, seed: int,
                  local_evaluations: int = 0, local_radius: float = 0.1) -> dict[str, Any]:
    """``smcbayes calibrate`` in Python (no figures, quiet); returns its summary."""
    from smcbayes.run import RunDir, RunIdentity
    from smcbayes.simulation.executors.base import make_executor
    from smcbayes.simulation.problem import build_problem
    from smcbayes.surrogate.calibration import calibrate
    from smcbayes.surrogate.loop import BOSettings

    project = load_project(project_toml)
    # the emulator path stands for an expensive simulator here: no local search on the model,
    # so the calibration's evaluations are the GP's training data and the count is theirs
    settings = BOSettings(budget=budget, init=init, seed=seed, local_evaluations=local_evaluations,
                          local_radius=local_radius, polish=0)
    settings.check()
    identity = RunIdentity(project.model_dump(mode="json"), None, {}, None, None,
                           settings.model_dump(mode="json", exclude={"truth"}))
    RunDir(run_dir).prepare(identity, False)
    problem = build_problem(project, run_dir, None, {}, None, None)
    return calibrate(problem, settings, run_dir, make_executor(1, None), figures=False,
                     progress=lambda _p: None)


def unit_of(space: Any, params: Mapping[str, float]) -> np.ndarray:
    """Unit-cube coordinates ``(d,)`` of a parameter dictionary (free parameters)."""
    return space.to_unit(np.array([[params[n] for n in space.free_names]]))[0]


def emulated_draws(run_dir: Path) -> np.ndarray:
    """Unit-cube draws ``(N, d)`` of the reported posterior (``posterior`` group of posterior.nc)."""
    return posterior_samples(run_dir)["reported"]


def stage_emulator(info: dict[str, Any]) -> str:
    """The emulator a posterior stage ran, from its ``summary.json`` ``info``: ``curves`` or
    ``loss`` (``auto`` resolves to one of them)."""
    return "curves" if (info.get("active_learning") or {}).get("kind") == "curves" else "loss"


def posterior_samples(run_dir: Path) -> dict[str, Any]:
    """Samples of ``posterior/posterior.nc`` in the unit cube.

    Returns:
        ``reported`` ``(N, d)`` (the ``posterior`` group), ``emulator`` ``(M, d)`` (the emcee
        chains of the emulated posterior) and, when the correction ran, ``weighted``:
        ``(unit (K, d), normalised weights (K,))`` of the importance sample, else None.
    """
    import arviz as az

    from smcbayes.posterior.stage import load_run

    space = load_run(run_dir).space
    idata = az.from_netcdf(str(run_dir / "posterior" / "posterior.nc"))

    def unit(group: Any) -> np.ndarray:
        return space.to_unit(np.column_stack([group[n].values.reshape(-1) for n in space.free_names]))

    reported = unit(idata.posterior)
    if "importance" not in idata.groups():
        return {"reported": reported, "emulator": reported, "weighted": None}
    imp = idata.importance
    w = np.exp(imp["log_weight"].values.reshape(-1))
    keep = w > 0
    return {"reported": reported, "emulator": unit(idata.emulator_posterior),
            "weighted": (unit(imp)[keep], w[keep] / w[keep].sum())}


def write_result(name: str, payload: Mapping[str, Any]) -> Path:
    """Write ``benchmarks/results/<name>.json``."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps(payload, indent=2, default=float) + "\n", encoding="utf-8")
    return path


class Timer:
    """Wall-clock seconds since creation."""

    def __init__(self) -> None:
        self.start = time.perf_counter()

    def __call__(self) -> float:
        return time.perf_counter() - self.start
