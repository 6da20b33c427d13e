"""Models, residuals and the fast warm-started re-calibration of the gap diagnosis.

Why not the Bayesian-optimisation loop: a diagnosis re-calibrates the base model plus each
candidate effect (6-10 parameters) starting from a known good point.  A GP refit per round
costs more than the forward model here, and the start is already close to the optimum, so a
population optimiser that evaluates a whole generation in one batched forward call is both
faster and better suited: scipy's differential evolution (``best1bin``, deferred updating,
vectorised) with a fixed budget of ``restarts * population * (generations + 1)`` parameter
sets, seeded from the caller's generator, then up to ``polish`` Levenberg-Marquardt steps on
the force residuals (batched finite-difference Jacobian, several dampings per step).

The initial population of each evolution holds

* the warm start (base optimum, effect parameters at their defaults);
* the **effect scan**: ``lhs_starts`` Latin-hypercube values of the effect's own parameters
  (uniform in the search cube, i.e. log-spaced where the parameter is searched in log), each
  next to the base optimum;
* ``global_starts`` Latin-hypercube points over all parameters;
* Gaussian perturbations of the warm start (``spread`` in the unit cube) up to ``population``.

Why not only the warm start: the base optimum has bent its parameters to mimic the missing
effect (press compliance: a slip-dominated optimum at the upper bound of the viscosity,
where the truth is viscous), and an evolution from around it stays in that basin.  Why
``crossover`` 0.9 rather than scipy's 0.7: the effect parameters and the rheology form long,
narrow, curved valleys (a stiffer press is mimicked by a lower viscosity and a steeper
shear thinning); with a low crossover rate most trial vectors change one or two coordinates
and cannot follow such a valley, with a high one the search is close to rotation-invariant.
Why not a multi-start Gauss-Newton from the scan: the discrete solver makes the loss rough
on the scale of a few 1e-3 of the unit cube, and local steps stall at 5-20 times the noise
floor even from starts 0.1 away from the truth.  ``restarts`` (default 2) runs independent
evolutions and keeps the one with the lowest training loss: where two sets of parameters
fit the training configurations almost equally well (within ~2 %), one evolution converges
to either, and only the held-out configurations tell them apart.

The base model is re-fitted with the same optimiser (and twice the generations), so that an
effect never wins merely by a longer search.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import differential_evolution
from scipy.stats import qmc

from smcbayes.config import DiagnoseSpec, ProjectConfig
from smcbayes.data.dataset import Dataset, Measurement
from smcbayes.data.loss import (
    contact_offsets_mm,
    displacement_mse,
    given_force_pair,
    interp_rows,
    trial_offsets_mm,
)
from smcbayes.data.preprocess import crossing_time
from smcbayes.errors import ConfigError
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.result import SimulationResult
from smcbayes.progress import Progress
from smcbayes.run import RunDir
from smcbayes.run.cache import ForwardCache
from smcbayes.simulation.executors.base import Executor
from smcbayes.simulation.objective import SimulatorObjective
from smcbayes.simulation.runner import Runner

Array = NDArray[np.float64]

#: Objective value of a failed simulation (the loss is in kN^2; real losses are far below).
FAILED_LOSS = 1e12
#: Forward-difference step (unit cube) and dampings (relative to diag(J^T J)) of the polish.
LM_STEP = 2e-3
LM_DAMPINGS = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)


_DEFAULTS = DiagnoseSpec()
"""The user-facing defaults (the ``[diagnose]`` table) written once, in the config layer."""


@dataclass(frozen=True)
class FitSettings:
    """Budget of one warm-started re-calibration.

    Attributes:
        population: parameter sets per generation (one batched forward call).
        generations: differential-evolution generations after the initial population.
        lhs_starts: effect scan: Latin-hypercube values of the effect's parameters, each
            with the base parameters at the optimum.
        global_starts: Latin-hypercube starts over all parameters.
        spread: standard deviation of the warm start's perturbations (unit cube).
        crossover: crossover probability of the evolution (module docstring).
        restarts: independent evolutions; the lowest training loss is kept.
        polish: Levenberg-Marquardt iterations after the evolution (0: none).
    """

    population: int = _DEFAULTS.population
    generations: int = _DEFAULTS.generations
    lhs_starts: int = 12
    global_starts: int = 24
    spread: float = 0.05
    crossover: float = 0.9
    restarts: int = _DEFAULTS.restarts
    polish: int = 8

    def check(self) -> None:
        """Raise :class:`ConfigError` on a budget the optimiser cannot use."""
        if self.population < 5:
            raise ConfigError(f"population {self.population}: needs at least 5 parameter sets")
        if min(self.generations, self.lhs_starts, self.global_starts, self.polish) < 0 \
                or not 0 < self.spread <= 0.5:
            raise ConfigError("generations, lhs_starts, global_starts and polish must be >= 0 "
                              "and spread in (0, 0.5]")
        if self.restarts < 1 or not 0.0 <= self.crossover <= 1.0:
            raise ConfigError(f"restarts {self.restarts} must be >= 1 and crossover "
                              f"{self.crossover:g} in [0, 1]")



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
        executor: makes the executor of each model's forward batches (default: in process);
            every forward run of the diagnosis goes through a
            :class:`~smcbayes.simulation.runner.Runner` of its model.
        run: the calibration run directory, if the context was read from one: with
            :meth:`keep_runs_in` each model's runner then keeps its forward runs in the
            stage's cache, so a killed diagnosis rerun with the same seed redoes none.
    """

    project: ProjectConfig
    dataset: Dataset
    ids: list[str]
    base_effects: tuple[str, ...]
    overrides: dict[str, float]
    fidelity: str | None
    base_params: dict[str, float]
    truth: dict[str, float] | None = None
    executor: Callable[[], Executor] | None = None
    run: RunDir | None = None
    _cache_folder: Path | None = field(default=None, repr=False)
    _models: dict[tuple[str, ...], ForwardModel] = field(default_factory=dict, repr=False)
    _runners: dict[tuple[str, ...], Runner] = field(default_factory=dict, repr=False)

    def model(self, extra: Sequence[str] = ()) -> ForwardModel:
        """Forward model with the run's effects plus ``extra`` (cached)."""
        key = tuple(extra)
        if key not in self._models:
            effects = list(self.base_effects) + list(key)
            self._models[key] = ForwardModel(self.project, effects=effects,
                                             overrides=self.overrides, fidelity=self.fidelity)
        return self._models[key]

    def runner(self, extra: Sequence[str] = ()) -> Runner:
        """The model with ``extra`` on its own executor (cached; released by :meth:`close`).

        Only the model in use keeps its workers: the others' are released (and started
        again when used), so a pool of N processes is never held once per model."""
        key = tuple(extra)
        for other, r in self._runners.items():
            if other != key:
                r.close()
        if key not in self._runners:
            objective = SimulatorObjective(self.model(key), self.dataset, self.ids, self.project.loss)
            cache = (None if self.run is None or self._cache_folder is None
                     else self.run.forward_cache("diagnose", self._cache_folder, key))
            self._runners[key] = Runner(objective, None if self.executor is None else self.executor(), cache)
        return self._runners[key]

    def keep_runs_in(self, folder: Path) -> None:
        """Keep the forward runs of models made from now on in ``folder``'s cache (the
        diagnosis's output folder; needs :attr:`run`)."""
        self._cache_folder = Path(folder)

    @property
    def forward_runs_reused(self) -> int:
        """Of :attr:`forward_runs`, those taken from the cache of an earlier run."""
        return sum(r.forward_runs_reused for r in self._runners.values())

    @property
    def forward_runs(self) -> int:
        """Parameter sets x configurations simulated so far."""
        return sum(r.forward_runs for r in self._runners.values())

    def close(self) -> None:
        """Release the executors' workers."""
        for r in self._runners.values():
            r.close()
            if isinstance(r.cache, ForwardCache):
                r.cache.close()

    def start(self, extra: Sequence[str], known: Mapping[str, float] | None = None) -> Array:
        """Warm start ``(1, d)`` of a model: known values, else base optimum, else defaults."""
        space = self.model(extra).space
        values = {**space.defaults(), **self.base_params, **(known or {})}
        theta = np.array([[values[n] for n in space.free_names]])
        return space.from_unit(np.clip(space.to_unit(theta), 0.0, 1.0))

    def losses(self, extra: Sequence[str], theta: Array, ids: Sequence[str]) -> Array:
        """Per-configuration force/displacement errors ``(P, K)`` (kN^2); NaN where failed.

        The objective's loss terms, without curves: the evolutions' many rows then cost the
        cache a line each, not their curves."""
        return self.runner(extra).errors(theta, ids)

    def simulate(self, extra: Sequence[str], theta: Array,
                 ids: Sequence[str]) -> dict[str, SimulationResult]:
        """Simulations of ``theta`` ``(P, d)`` on ``ids``."""
        return self.runner(extra).simulate(theta, ids)


def window_end(res: SimulationResult, m: Measurement, clip: str, delay_s: float = 0.0) -> Array:
    """End (s) of the loss's comparison window per row, shape ``(P,)``, with the simulated
    closing delayed by ``delay_s`` (a contact offset); NaN where failed."""
    if clip == "flow_stop" and m.flow_stop_s is not None:
        return np.where(res.ok, m.flow_stop_s, np.nan)
    ts = np.where(np.isfinite(res.switch_time_s) & (res.switch_time_s > 0),
                  res.switch_time_s, res.time_s[:, -1]) + delay_s
    return np.where(res.ok, np.maximum(ts, m.force.time_s[-1]), np.nan)


def residuals_on(res: SimulationResult, m: Measurement, clip: str, end_s: float,
                 points: int, delay_s: float = 0.0) -> tuple[Array, Array]:
    """Measured minus simulated force on the grid ``[0, end_s]`` like the loss compares them,
    the simulated closing delayed by ``delay_s`` (s).

    Returns:
        ``(grid_s (N,), residual_kN (P, N))``; rows of failed simulations are NaN.
    """
    grid = np.linspace(0.0, end_s, points)
    ok = res.ok & np.all(np.isfinite(res.force_kN), axis=1)
    t = np.where(ok[:, None], res.time_s, np.arange(res.time_s.shape[1])[None, :]) + delay_s
    f = np.where(ok[:, None], res.force_kN, 0.0)
    switched = np.isfinite(res.switch_time_s) & (res.switch_time_s > 0)
    ts = np.where(switched, res.switch_time_s, t[:, -1] - delay_s) + delay_s
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
                       rng: np.random.Generator, share: bool = True) -> Array:
    """Initial population ``(S, d)`` in the unit cube: warm start ``(d,)``, effect scan,
    global starts, perturbations (module docstring), ``settings.population`` rows.

    With ``share`` the scan takes at most a quarter and the global starts at most half of
    the rest, so that a small population keeps perturbations of the base parameters (the
    scan rows all hold the base optimum, and an evolution moves no parameter its population
    does not vary).  Without, the scan and global starts come first and the rows are cut.
    """
    d, pop = start_unit.size, settings.population
    n_scan = min(settings.lhs_starts, (pop - 1) // 4) if share else settings.lhs_starts
    n_glob = (min(settings.global_starts, (pop - 1 - n_scan) // 2) if share
              else settings.global_starts)
    rows = [start_unit]
    if effect_cols and n_scan > 0:
        lhs = qmc.LatinHypercube(d=len(effect_cols), seed=rng).random(n_scan)
        for u in lhs:
            row = start_unit.copy()
            row[list(effect_cols)] = u
            rows.append(row)
    if n_glob > 0:
        rows.extend(qmc.LatinHypercube(d=d, seed=rng).random(n_glob))
    while len(rows) < settings.population:
        rows.append(np.clip(start_unit + settings.spread * rng.standard_normal(d), 0.0, 1.0))
    return np.array(rows[: settings.population])


def refit(ctx: DiagnosisContext, extra: Sequence[str], ids: Sequence[str], start: Array,
          settings: FitSettings, rng: np.random.Generator, desc: str | None = None) -> Fit:
    """Re-calibrate base + ``extra`` on ``ids`` from the warm start ``start`` ``(1, d)``.

    Progress is reported per batched forward call (one generation of an evolution, or one
    of the two calls of a polish step) through :class:`smcbayes.progress.Progress`, with
    the restart, generation and best loss so far (kN^2) as its note.

    Args:
        ctx: the diagnosis context.
        extra: candidate effects switched on in addition to the run's own.
        ids: fitting configurations.
        start: warm start in user units.
        settings: the optimiser's budget.
        rng: random generator (seeds the population and the optimiser).
        desc: what the progress names, e.g. ``"diagnosis: heating (2/5)"`` (default: the
            effects re-fitted).
    """
    settings.check()
    model = ctx.model(extra)
    space = model.space
    effect_names = {p.name for p in model.effects.parameters} - {
        p.name for p in ctx.model(()).effects.parameters}
    cols = [i for i, n in enumerate(space.free_names) if n in effect_names]
    u0 = np.clip(space.to_unit(start)[0], 0.0, 1.0)
    total = settings.restarts * (settings.generations + 1) + 2 * settings.polish
    if desc is None:
        desc = "re-calibration of base" + (f" + {'+'.join(extra)}" if extra else "")
    with Progress(total, desc, "batch") as bar:
        u, loss, count = _evolve(ctx, extra, ids, u0, cols, settings, rng, bar)
        for step in range(settings.polish):
            u_new, loss_new, used = lm_step(ctx, extra, ids, u)
            count += used
            bar.update(2, note=f"polish step {step + 1}/{settings.polish}, "
                               f"loss {min(loss, loss_new):.4g} kN^2")
            if not loss_new < loss * (1.0 - 1e-6):
                break
            u, loss = u_new, loss_new
    theta = space.from_unit(u[None, :])
    params = {k: float(v[0]) for k, v in space.batch(theta).items()}
    return Fit(tuple(extra), params, theta, loss, count)


def _evolve(ctx: DiagnosisContext, extra: Sequence[str], ids: Sequence[str], u0: Array,
            cols: Sequence[int], settings: FitSettings, rng: np.random.Generator,
            bar: Progress) -> tuple[Array, float, int]:
    """``settings.restarts`` differential evolutions from ``u0`` ``(d,)`` (effect columns
    ``cols``); returns the best point ``(d,)`` in the unit cube, its training loss (kN^2)
    and the parameter sets evaluated."""
    space = ctx.model(extra).space
    tally = _Tally()

    def objective(u: Array) -> Array:  # u: (d, S), the vectorised convention of scipy
        theta = space.from_unit(np.clip(u.T, 0.0, 1.0))
        per = ctx.losses(extra, theta, ids)
        tally.count += theta.shape[0]
        total = np.mean(per, axis=1)
        out = np.where(np.isfinite(total), total, FAILED_LOSS)
        tally.best = min(tally.best, float(np.min(out)))
        bar.update(1, note=(f"restart {tally.restart + 1}/{settings.restarts}, generation "
                            f"{tally.calls}/{settings.generations}, best {tally.best:.4g} kN^2"))
        tally.calls += 1
        return out

    u, loss = u0, np.inf
    for restart in range(settings.restarts):
        tally.restart, tally.calls = restart, 0
        init = initial_population(u0, cols, settings, rng)
        out = differential_evolution(objective, [(0.0, 1.0)] * space.dim, init=init,
                                     maxiter=settings.generations, tol=0.0, atol=0.0,
                                     polish=False, vectorized=True, updating="deferred",
                                     recombination=settings.crossover,
                                     rng=int(rng.integers(2**31 - 1)))
        if float(out.fun) < loss:
            u, loss = np.clip(out.x, 0.0, 1.0), float(out.fun)
    return u, loss, tally.count


@dataclass
class _Tally:
    """What the objective of :func:`_evolve` has seen: parameter sets evaluated, batched
    calls in the current restart (0: its initial population), the restart, the best loss
    (kN^2)."""

    count: int = 0
    calls: int = 0
    restart: int = 0
    best: float = float("inf")


def held_out_offsets(ctx: DiagnosisContext, extra: Sequence[str], theta: Array,
                     held_out: Sequence[str]) -> dict[str, tuple[float, ...]] | None:
    """The contact offsets (mm) each held-out trial's curve is averaged over: the fitting
    trials' own at ``theta``'s first row (profiled or measured from their end states: a
    held-out trial's own is not known before it is pressed;
    :func:`smcbayes.data.loss.mixed_force_pair`); None at the nominal contact."""
    spec = ctx.project.loss
    if not spec.per_trial_contact:
        return None
    fit_ids = [c for c in ctx.ids if c not in held_out]
    offsets = contact_offsets_mm(ctx.simulate(extra, theta[:1], fit_ids), ctx.dataset, spec, fit_ids)
    return {c: tuple(offsets.values()) for c in held_out}


def fixed_offset_losses(ctx: DiagnosisContext, extra: Sequence[str], theta: Array, ids: Sequence[str],
                        offsets_mm: Mapping[str, Sequence[float]]) -> Array:
    """Per-configuration loss terms ``(P, K)`` (kN^2) with each configuration's curve
    averaged over given contact offsets (mm) instead of taken at its own; NaN where a run
    failed."""
    spec = ctx.project.loss
    results = ctx.simulate(extra, theta, ids)
    out = np.full((np.atleast_2d(theta).shape[0], len(ids)), np.nan)
    for k, cid in enumerate(ids):
        m = ctx.dataset[cid]
        pair = given_force_pair(results[cid], m, spec, tuple(offsets_mm[cid]))
        term = spec.w_force * np.mean((pair.sim_kN - pair.meas_kN) ** 2, axis=1)
        if spec.w_displacement > 0:
            term = term + spec.w_displacement * displacement_mse(results[cid], m, spec)
        out[:, k] = np.where(pair.ok, term, np.nan)
    return out


def residual_stack(ctx: DiagnosisContext, extra: Sequence[str], theta: Array, ids: Sequence[str],
                   ends: Mapping[str, float] | None = None,
                   offsets_mm: Mapping[str, Sequence[float]] | None = None
                   ) -> tuple[dict[str, Array], dict[str, float]]:
    """Residuals ``(P, N)`` per configuration on fixed windows (row 0's window by default,
    sized for the latest contact).

    Where each trial has a contact offset of its own, every row is taken at row 0's
    (profiled or measured), or, for a configuration in ``offsets_mm`` (a held-out trial,
    :func:`held_out_offsets`), its curve is averaged over those offsets (the mean of the
    residuals at each).  Residuals at fixed offsets give the Jacobian in the parameters
    alone; the steps built from it are judged by the loss itself."""
    results = ctx.simulate(extra, theta, ids)
    spec = ctx.project.loss
    clip, points = spec.clip, spec.grid_points
    out, used = {}, {}
    for cid in ids:
        m = ctx.dataset[cid]
        delays = np.zeros(1)  # given no offsets (none measured): the nominal contact, as in the loss
        if offsets_mm is not None and cid in offsets_mm:
            if m.speed_mm_s and len(offsets_mm[cid]):
                delays = np.asarray(offsets_mm[cid], dtype=float) / m.speed_mm_s
        elif spec.per_trial_contact and m.speed_mm_s and bool(results[cid].ok[0]):
            delays = trial_offsets_mm(results[cid], m, spec)[:1] / m.speed_mm_s
        end = ends[cid] if ends else float(window_end(results[cid], m, clip, float(np.max(delays)))[0])
        if not np.isfinite(end):
            end = float(m.force.time_s[-1])
        out[cid] = np.mean([residuals_on(results[cid], m, clip, end, points, d)[1] for d in delays], axis=0)
        used[cid] = end
    return out, used


def lm_step(ctx: DiagnosisContext, extra: Sequence[str], ids: Sequence[str],
            u: Array) -> tuple[Array, float, int]:
    """One Levenberg-Marquardt step in the unit cube from ``u`` ``(d,)``, several dampings at once.

    The force loss is a mean of squared residuals, so near an optimum a Gauss-Newton model
    converges in a few steps where an evolution needs hundreds of points.  The Jacobian is a
    forward difference (one batched call of ``d + 1`` rows) on the windows of ``u``; the
    trial steps for all dampings run in a second batched call, scored by the true loss.

    Returns:
        ``(u_best, loss_best, evaluations)``; ``u_best`` is the best trial step.
    """
    space = ctx.model(extra).space
    d = u.size
    h = np.where(u + LM_STEP <= 1.0, LM_STEP, -LM_STEP)
    res, _ = residual_stack(ctx, extra, space.from_unit(np.vstack([u, u + np.diag(h)])), ids)
    w = [1.0 / np.sqrt(res[c].shape[1] * len(ids)) for c in ids]
    r0 = np.concatenate([res[c][0] * wk for c, wk in zip(ids, w, strict=True)])
    jac = np.column_stack([
        np.concatenate([(res[c][j + 1] - res[c][0]) * wk / h[j]
                        for c, wk in zip(ids, w, strict=True)])
        for j in range(d)])
    if not (np.all(np.isfinite(jac)) and np.all(np.isfinite(r0))):
        return u, np.inf, d + 1
    jtj, jtr = jac.T @ jac, jac.T @ r0
    scale = np.maximum(np.diag(jtj), 1e-12 * max(np.max(np.diag(jtj)), 1e-300))
    trials = [np.clip(u - np.linalg.solve(jtj + lam * np.diag(scale), jtr), 0.0, 1.0)
              for lam in LM_DAMPINGS]
    loss = np.mean(ctx.losses(extra, space.from_unit(np.array(trials)), ids), axis=1)
    loss = np.where(np.isfinite(loss), loss, np.inf)
    k = int(np.argmin(loss))
    return trials[k], float(loss[k]), d + 1 + len(trials)
