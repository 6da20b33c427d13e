"""Synthetic checks of the diagnosis: data with a known effect, calibrated with the base model.

Used by the confusion benchmark and the tests.  The measured data come from
:func:`smcbayes.data.synth.write_synthetic` (forward model with the effect on, white plus
slowly varying correlated noise).  The base calibration uses the same batched differential
evolution as the diagnosis, started from a Latin hypercube over the whole base space: the
Bayesian-optimisation loop would give an equivalent optimum at a higher cost per point.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from scipy.optimize import differential_evolution
from scipy.stats import qmc

from smcbayes.config import ProjectConfig, load_project
from smcbayes.data.dataset import load_dataset
from smcbayes.data.synth import NoiseSpec, write_synthetic
from smcbayes.diagnose.fit import FAILED_LOSS, DiagnosisContext
from smcbayes.forward.model import ForwardModel

#: Effect parameter values of the checks: each effect clearly present, physically plausible.
#: compressibility: consolidated density 1.6 g/cm3 against the ~1.2 g/cm3 apparent density of
#: the thesis charges (initial solid fraction ~0.75), compaction modulus 1 MPa, Toll-Manson
#: exponent 5; heating: a charge laid in at room temperature (25 C) into the 135 C mould,
#: diffusivity 0.3 mm2/s (time constant H^2/(pi^2 kappa) = 22 s at 8 mm), activation 5000 K;
#: curing: a fast-curing SMC, k1 = 0.02 1/s, k2 = 0.2 1/s, c1 = 3, c2 = 5, gelation at 0.5;
#: press_compliance: a 300 kN/mm frame (4.7 mm deflection at 1400 kN); speed_ramp: 1 s
#: to reach the set speed, 30 % slower at the force limit.
EFFECT_TRUTH: dict[str, dict[str, float]] = {
    "compressibility": {"rho_solid_g_cm3": 1.6, "compaction_modulus_MPa": 1.0,
                        "compaction_exponent": 5.0, "bulk_viscosity_MPa_s": 0.0},
    "heating": {"T_start_C": 25.0, "diffusivity_mm2_s": 0.3, "T_b_K": 5000.0},
    "curing": {"k1_1_s": 2e-2, "k2_1_s": 0.2, "c1": 3.0, "c2": 5.0, "alpha_g": 0.5},
    "press_compliance": {"k_press_kN_mm": 300.0},
    "speed_ramp": {"ramp_time_s": 1.0, "load_slowdown": 0.3},
}

#: Base parameters of the checks (user units).
#: The wall-slip threshold is high enough (0.5 MPa) for the viscosity to matter: with
#: slip-dominated flow, heating and curing (which act on the viscosity) would be invisible.
BASE_TRUTH: dict[str, float] = {"n": 0.35, "tau_star_Pa": 2.0e4, "B_Pa_s": 2.0e4,
                                "tau_c_MPa": 0.5, "m": 1.4}


def subset_project(project: ProjectConfig, ids: Sequence[str]) -> ProjectConfig:
    """Copy of ``project`` with only the configurations ``ids`` (all as training data)."""
    configs = [c.model_copy(update={"role": "train"}) for c in project.configuration if c.id in ids]
    return project.model_copy(update={"configuration": configs})


def make_case(project: ProjectConfig, ids: Sequence[str], effect: str | None,
              noise: NoiseSpec, seed: int, folder: Path,
              effect_values: Mapping[str, float] | None = None) -> ProjectConfig:
    """Write synthetic data of ``ids`` with ``effect`` on (None: base model) to ``folder``.

    Returns:
        The synthetic project reading its data from ``folder``.
    """
    source = subset_project(project, ids)
    truth = dict(BASE_TRUTH)
    if effect is not None:
        truth.update(effect_values if effect_values is not None else EFFECT_TRUTH[effect])
    model = ForwardModel(source, effects=[effect] if effect else [], overrides=truth)
    path = write_synthetic(model, list(ids), noise, seed, folder, truth, source="diagnosis check")
    return load_project(path)


def calibrate_base(project: ProjectConfig, population: int, generations: int,
                   rng: np.random.Generator,
                   truth: Mapping[str, float] | None = None) -> DiagnosisContext:
    """Calibrate the base model on every configuration of ``project``; the diagnosis context."""
    ids = [c.id for c in project.configuration if c.role == "train"]
    dataset = load_dataset(project, ids=ids, preprocess=project.preprocess)
    ctx = DiagnosisContext(project, dataset, ids, tuple(project.effects), {}, None, {},
                           dict(truth) if truth else None)
    space = ctx.model(()).space
    init = qmc.LatinHypercube(d=space.dim, seed=rng).random(population)

    def objective(u: np.ndarray) -> np.ndarray:
        total = np.mean(ctx.losses((), space.from_unit(np.clip(u.T, 0.0, 1.0)), ids), axis=1)
        return np.where(np.isfinite(total), total, FAILED_LOSS)

    out = differential_evolution(objective, [(0.0, 1.0)] * space.dim, init=init,
                                 maxiter=generations, tol=0.0, atol=0.0, polish=False,
                                 vectorized=True, updating="deferred",
                                 rng=int(rng.integers(2**31 - 1)))
    batch = space.batch(space.from_unit(np.clip(out.x, 0.0, 1.0)[None, :]))
    ctx.base_params = {k: float(v[0]) for k, v in batch.items()}
    return ctx
