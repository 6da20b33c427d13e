"""Models, residuals and the fast warm-started re-calibration of the gap diagnosis.

Why not the Bayesian-optimisation loop: a diagnosis re-calibrates the base model plus each
candidate effect (6-10 parameters) starting from a known good point.  A GP refit per round
costs more than the forward model here, and the start is already close to the optimum, so a
population optimiser that evaluates a whole generation in one batched forward call is both
faster and better suited: scipy's differential evolution (``best1bin``, deferred updating,
vectorised) with a fixed budget of ``population * (generations + 1)`` parameter sets, seeded
from the caller's generator.  Its initial population holds the warm start (base optimum,
effect parameters at their defaults), ``lhs_starts`` Latin-hypercube points in the effect's
parameters with the base parameters at the optimum, and Gaussian perturbations of the warm
start (``spread`` in the unit cube) in all parameters.  The base model is re-fitted with the
same optimiser and budget, so that an effect never wins merely by a longer search.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import differential_evolution
from scipy.stats import qmc

from smcbayes.config import ProjectConfig
from smcbayes.data.dataset import Dataset, Measurement
from smcbayes.data.loss import evaluate_loss, interp_rows
from smcbayes.data.preprocess import crossing_time
from smcbayes.errors import ConfigError
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.result import SimulationResult

Array = NDArray[np.float64]

#: Objective value of a failed simulation (the loss is in kN^2; real losses are far below).
FAILED_LOSS = 1e12


@dataclass(frozen=True)
class FitSettings:
    """Budget of one warm-started re-calibration.

    Attributes:
        population: parameter sets per generation (one batched forward call).
        generations: differential-evolution generations after the initial population.
        lhs_starts: Latin-hypercube starts in the effect's parameters.
        spread: standard deviation of the warm start's perturbations (unit cube).
    """

    population: int = 24
    generations: int = 12
    lhs_starts: int = 6
    spread: float = 0.05

    def check(self) -> None:
        """Raise :class:`ConfigError` on a budget the optimiser cannot use."""
        if self.population < 5:
            raise ConfigError(f"population {self.population}: needs at least 5 parameter sets")
        if self.generations < 0 or self.lhs_starts < 0 or not 0 < self.spread <= 0.5:
            raise ConfigError("generations and lhs_starts must be >= 0 and spread in (0, 0.5]")

    @property
    def evaluations(self) -> int:
        """Parameter sets evaluated by one re-calibration."""
        return self.population * (self.generations + 1)


@dataclass(frozen=True)
class Fit:
    """Result of a (re-)calibration of one model.

    Attributes:
        effects: the candidate effects on top of the run's own effects.
        params: best values of every parameter (user units).
        theta: best free-parameter vector, shape ``(1, d)``.
        loss: global loss on the fitting configurations (kN^2).
        evaluations: parameter sets evaluated.
    """

    effects: tuple[str, ...]
    params: dict[str, float]
    theta: Array
    loss: float
    evaluations: int


@dataclass
class DiagnosisContext:
    """What a diagnosis needs from a calibration: project, data and the base optimum.

    Attributes:
        project: the validated project (data directory resolved).
        dataset: measured curves of ``ids``.
        ids: configurations with measurements (the calibration's training set).
        base_effects: effects the calibration already had on.
        overrides: fixed parameter values of the calibration (user units).
        fidelity: forward solver fidelity.
        base_params: the calibrated values of every base parameter (user units).
        truth: true parameters of synthetic data, if known.
    """

    project: ProjectConfig
    dataset: Dataset
    ids: list[str]
    base_effects: tuple[str, ...]
    overrides: dict[str, float]
    fidelity: str | None
    base_params: dict[str, float]
    truth: dict[str, float] | None = None
    _models: dict[tuple[str, ...], ForwardModel] = field(default_factory=dict, repr=False)

    def model(self, extra: Sequence[str] = ()) -> ForwardModel:
        """Forward model with the run's effects plus ``extra`` (cached)."""
        key = tuple(extra)
        if key not in self._models:
            self._models[key] = ForwardModel(self.project, effects=list(self.base_effects) + list(key),
                                             overrides=self.overrides, fidelity=self.fidelity)
        return self._models[key]

    def start(self, extra: Sequence[str], known: Mapping[str, float] | None = None) -> Array:
        """Warm start ``(1, d)`` of a model: known values, else base optimum, else defaults."""
        space = self.model(extra).space
        values = {**space.defaults(), **self.base_params, **(known or {})}
        theta = np.array([[values[n] for n in space.free_names]])
        return space.from_unit(np.clip(space.to_unit(theta), 0.0, 1.0))

    def losses(self, extra: Sequence[str], theta: Array, ids: Sequence[str]) -> Array:
        """Per-configuration force/displacement errors ``(P, K)`` (kN^2); NaN where failed."""
        results = self.model(extra).simulate(theta, ids)
        loss = evaluate_loss(results, self.dataset, self.project.loss, ids)
        per = loss.per_config()
        return np.column_stack([per[cid] for cid in ids])

    def simulate(self, extra: Sequence[str], theta: Array, ids: Sequence[str]) -> dict[str, SimulationResult]:
        """Simulations of ``theta`` ``(P, d)`` on ``ids``."""
        return self.model(extra).simulate(theta, ids)


def window_end(res: SimulationResult, m: Measurement, clip: str) -> Array:
    """End (s) of the loss's comparison window per row, shape ``(P,)``; NaN where failed."""
    if clip == "flow_stop" and m.flow_stop_s is not None:
        return np.where(res.ok, m.flow_stop_s, np.nan)
    ts = np.where(np.isfinite(res.switch_time_s) & (res.switch_time_s > 0),
                  res.switch_time_s, res.time_s[:, -1])
    return np.where(res.ok, np.maximum(ts, m.force.time_s[-1]), np.nan)


def residuals_on(res: SimulationResult, m: Measurement, clip: str, end_s: float,
                 points: int) -> tuple[Array, Array]:
    """Measured minus simulated force on the grid ``[0, end_s]`` like the loss compares them.

    Returns:
        ``(grid_s (N,), residual_kN (P, N))``; rows of failed simulations are NaN.
    """
    grid = np.linspace(0.0, end_s, points)
    ok = res.ok & np.all(np.isfinite(res.force_kN), axis=1)
    t = np.where(ok[:, None], res.time_s, np.arange(res.time_s.shape[1])[None, :])
    f = np.where(ok[:, None], res.force_kN, 0.0)
    ts = np.where(np.isfinite(res.switch_time_s) & (res.switch_time_s > 0), res.switch_time_s, t[:, -1])
    sim = interp_rows(np.minimum(grid[None, :], ts[:, None]), t, f)
    tm, fm = m.force.time_s, m.force.values
    if clip == "force_limit":
        sim = np.minimum(sim, m.force_limit_kN)
        t_lim = crossing_time(m.force, m.force_limit_kN)
        if t_lim is not None:
            tm, fm = np.append(tm[tm < t_lim], t_lim), np.append(fm[tm < t_lim], m.force_limit_kN)
    resid = np.interp(grid, tm, fm)[None, :] - sim
    return grid, np.where(ok[:, None], resid, np.nan)


def initial_population(start_unit: Array, effect_cols: Sequence[int], settings: FitSettings,
                       rng: np.random.Generator) -> Array:
    """Initial population ``(S, d)`` in the unit cube around a warm start ``(d,)``."""
    d = start_unit.size
    rows = [start_unit]
    if effect_cols and settings.lhs_starts > 0:
        lhs = qmc.LatinHypercube(d=len(effect_cols), seed=rng).random(settings.lhs_starts)
        for u in lhs:
            row = start_unit.copy()
            row[list(effect_cols)] = u
            rows.append(row)
    while len(rows) < settings.population:
        rows.append(np.clip(start_unit + settings.spread * rng.standard_normal(d), 0.0, 1.0))
    return np.array(rows[: settings.population])


def refit(ctx: DiagnosisContext, extra: Sequence[str], ids: Sequence[str], start: Array,
          settings: FitSettings, rng: np.random.Generator) -> Fit:
    """Re-calibrate base + ``extra`` on ``ids`` from the warm start ``start`` ``(1, d)``.

    Args:
        ctx: the diagnosis context.
        extra: candidate effects switched on in addition to the run's own.
        ids: fitting configurations.
        start: warm start in user units.
        settings: the optimiser's budget.
        rng: random generator (seeds the population and the optimiser).
    """
    settings.check()
    model = ctx.model(extra)
    space = model.space
    effect_names = {p.name for p in model.effects.parameters} - {
        p.name for p in ctx.model(()).effects.parameters}
    cols = [i for i, n in enumerate(space.free_names) if n in effect_names]
    u0 = np.clip(space.to_unit(start)[0], 0.0, 1.0)
    init = initial_population(u0, cols, settings, rng)
    count = [0]

    def objective(u: Array) -> Array:  # u: (d, S), the vectorised convention of scipy
        theta = space.from_unit(np.clip(u.T, 0.0, 1.0))
        per = ctx.losses(extra, theta, ids)
        count[0] += theta.shape[0]
        total = np.mean(per, axis=1)
        return np.where(np.isfinite(total), total, FAILED_LOSS)

    out = differential_evolution(objective, [(0.0, 1.0)] * space.dim, init=init,
                                 maxiter=settings.generations, tol=0.0, atol=0.0, polish=False,
                                 vectorized=True, updating="deferred",
                                 rng=int(rng.integers(2**31 - 1)))
    theta = space.from_unit(np.clip(out.x, 0.0, 1.0)[None, :])
    batch = space.batch(theta)
    params = {k: float(v[0]) for k, v in batch.items()}
    return Fit(tuple(extra), params, theta, float(out.fun), count[0])
