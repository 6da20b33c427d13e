"""The posterior stage of a calibration run directory (``smcbayes posterior``).

Reads the run (its resolved config, GP state and best point), estimates the effective
number of independent points from the residuals at the best point, samples the emulated
posterior (a mixture over GP sample functions), optionally refines the emulator (rounds
of forward evaluations at random, most uncertain and space-filling points of the emulated
posterior's region, stopped early once the out-of-sample error at fresh posterior draws
is below ``refine_tolerance_nats``; see :func:`refine` and :mod:`smcbayes.posterior.refine`),
checks it against the forward model at posterior draws, and writes ``RUN_DIR/posterior/``:
``posterior.nc`` (arviz InferenceData), ``summary.json``, ``summary.csv``, figures
(corner, correlations, predictive bands; PNG and SVG) and, after refinement,
``gp_refined.pt`` and ``refine.jsonl``.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import ProjectConfig
from smcbayes.errors import ConfigError
from smcbayes.posterior.correct import CorrectionSettings
from smcbayes.posterior.likelihood import EmulatedPosterior, effective_points, sandwich_points
from smcbayes.posterior.sampler import SamplerSettings, run_ensemble

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PosteriorSettings:
    """Settings of the posterior stage.

    Attributes:
        walkers, steps: emcee ensemble size and maximum steps per chain.
        functions: GP sample functions in the mixture (0: GP mean only).
        refine: forward evaluations added where the posterior is probable and the GP unsure.
        draws: posterior draws pushed through the forward model (bands and emulator check).
        seed: random seed.
        refine_tolerance_nats: refinement stops early once the emulator's out-of-sample
            error at fresh posterior draws is below this (mean absolute, nats) twice in a row.
        correct_draws: most proposal draws (each inside the prior box costs a forward
            evaluation) of the importance-sampling correction of the emulated posterior
            (:mod:`smcbayes.posterior.correct`); it stops earlier once the weights are good;
            0 reports the emulated posterior uncorrected.
    """

    walkers: int = 32
    steps: int = 4000
    functions: int = 8
    refine: int = 0
    draws: int = 100
    seed: int = 0
    refine_tolerance_nats: float = 1.0
    correct_draws: int = CorrectionSettings.draws


@dataclass
class RunContext:
    """What the posterior needs from a calibration run."""

    run_dir: Path
    problem: Any
    summary: dict[str, Any]
    best_theta: Array

    @property
    def space(self):
        return self.problem.model.space


def load_run(run_dir: Path) -> RunContext:
    """Rebuild the calibration problem of ``run_dir`` from its ``config.json``."""
    from smcbayes.simulation.problem import ExternalSpec, build_problem

    cfg, summ = run_dir / "config.json", run_dir / "summary.json"
    if not cfg.is_file() or not summ.is_file():
        raise ConfigError(f"{run_dir}: not a calibration run directory (config.json and "
                          "summary.json missing); run `smcbayes calibrate` first")
    identity = json.loads(cfg.read_text(encoding="utf-8"))
    summary = json.loads(summ.read_text(encoding="utf-8"))
    project = ProjectConfig.model_validate(identity["project"])
    ext = identity.get("external")
    problem = build_problem(project, run_dir, identity.get("effects"), identity.get("overrides") or {},
                            identity.get("fidelity"), ExternalSpec(**ext) if ext else None)
    if not summary.get("best_params"):
        raise ConfigError(f"{run_dir}: the calibration has no successful evaluation")
    best = summary["best_params"]
    theta = np.array([[best[n]["value"] for n in problem.model.space.free_names]])
    if problem.truth is None:
        problem.truth = synthetic_truth(problem.project, problem.model.space.defaults())
    return RunContext(run_dir, problem, summary, theta)


def synthetic_truth(project: ProjectConfig, defaults: dict[str, float]) -> dict[str, float] | None:
    """True parameters of a dataset written by ``smcbayes synth`` (its truth.json), if any."""
    root = project.data_path()
    path = None if root is None else root / "truth.json"
    if path is None or not path.is_file():
        return None
    params = json.loads(path.read_text(encoding="utf-8")).get("parameters", {})
    return {**defaults, **{k: float(v) for k, v in params.items() if k in defaults}}


def true_log_loss(ctx: RunContext, theta: Array) -> Array:
    """log of the global loss from the forward model at ``theta`` ``(P, d)``; NaN if failed."""
    from smcbayes.data.loss import evaluate_loss

    p = ctx.problem
    results = p.model.simulate(theta, p.train_ids)
    loss = evaluate_loss(results, p.objective.dataset, p.project.loss, ids=p.train_ids)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(loss.total > 0, np.log(loss.total), np.nan)


SENSITIVITY_STEP = 0.02
"""Finite-difference step of the force sensitivities (unit-cube coordinates): well above
the roughness of the discrete solver's loss (about 1e-3)."""


def residual_budget(ctx: RunContext) -> dict[str, Any]:
    """Effective points from the force residuals and sensitivities at the best point.

    Two estimates: ``n_eff_residual`` = sum_k N_k / tau_k from the residuals' integrated
    autocorrelation times, and the sandwich estimate of
    :func:`~smcbayes.posterior.likelihood.sandwich_points`, which also uses the force
    sensitivities (central differences: 2 d + 1 parameter rows, each simulated on every
    training configuration; the perturbed forces are read on the best point's grid).  The
    likelihood uses the smaller of the two (``n_eff_total``), the residual one alone where
    a perturbed run fails or the data inform no direction.  Each can overstate N_eff: the
    residual estimate when the misfit concentrates where a parameter acts, the sandwich
    when the residuals are correlated over a whole curve (a systematic model error), as
    its lag sums then span the record and the score sums nearly cancel at the optimum.
    """
    from smcbayes.data.loss import force_pair
    from smcbayes.forward.nodes import interp_rows

    p, space = ctx.problem, ctx.space
    u0 = space.to_unit(ctx.best_theta)[0]
    d = u0.size
    up, down = np.minimum(u0 + SENSITIVITY_STEP, 1.0), np.maximum(u0 - SENSITIVITY_STEP, 0.0)
    rows = np.repeat(u0[None, :], 2 * d + 1, axis=0)
    rows[1 + np.arange(d), np.arange(d)] = up
    rows[1 + d + np.arange(d), np.arange(d)] = down
    results = p.model.simulate(space.from_unit(rows), p.train_ids)
    residuals, sensitivities, mse, usable = [], [], {}, True
    for cid in p.train_ids:
        pair = force_pair(results[cid], p.objective.dataset.measurements[cid], p.project.loss)
        grid = np.broadcast_to(pair.time_s[:1], pair.time_s.shape)
        sim = interp_rows(grid, pair.time_s, pair.sim_kN)
        r = pair.meas_kN[0] - sim[0]
        residuals.append(r)
        sensitivities.append(((sim[1:1 + d] - sim[1 + d:]) / (up - down)[:, None]).T)
        usable &= bool(np.all(pair.ok))
        mse[cid] = float(np.mean(r**2))
    tau, n_eff = effective_points(residuals, centred=False)
    sandwich = sandwich_points(residuals, sensitivities) if usable else float("nan")
    total = min(sandwich, float(n_eff.sum())) if np.isfinite(sandwich) and sandwich > 0 else float(n_eff.sum())
    return {"config_ids": list(p.train_ids), "tau": tau.tolist(), "n_eff": n_eff.tolist(),
            "n_eff_residual": float(n_eff.sum()), "n_eff_sandwich": sandwich,
            "n_eff_total": total, "mse_kN2": mse}


def sample(ctx: RunContext, surrogate: Any, n_eff: float, settings: PosteriorSettings,
           rng: np.random.Generator) -> tuple[EmulatedPosterior, list]:
    """Run one emcee ensemble per mixture component."""
    emul = EmulatedPosterior(surrogate, n_eff, settings.functions, settings.seed)
    centre = ctx.space.to_unit(ctx.best_theta)[0]
    sampler = SamplerSettings(walkers=settings.walkers, max_steps=settings.steps,
                              min_steps=min(500, settings.steps))
    chains = []
    for c in range(emul.components):
        comp = c if settings.functions > 0 else None
        label = f" (function {c + 1}/{emul.components})"
        chains.append(run_ensemble(emul.log_prob_fn(comp), ctx.space.dim, sampler, rng, centre, label))
    return emul, chains


CAP_NATS = 30.0
"""Targets more than this many nats of log-likelihood above the best are capped."""


def fit_local(x: Array, y: Array, n_eff: float, kernel: str, seed: int) -> Any:
    """GP of log(loss) with targets capped at min + CAP_NATS / (N_eff / 2).

    Where the true log-likelihood is CAP_NATS below the best the posterior density is
    below e^-30 of its peak whatever the emulator says, so capping loses nothing and lets
    the GP spend its flexibility where the posterior lives instead of on the far landscape.
    """
    from smcbayes.surrogate.gp import fit_surrogate

    cap = float(np.min(y)) + CAP_NATS / (0.5 * n_eff)
    return fit_surrogate(x, np.minimum(y, cap), kernel, seed)


def exact_log_posterior(ctx: RunContext, n_eff: float) -> Callable[[Array], Array]:
    """Exact unnormalised log posterior on the unit cube, ``(P, d) -> (P,)``: one batched
    forward run of the training configurations, -(N_eff / 2) log L (NaN where it failed)."""
    a = 0.5 * n_eff

    def log_post(u: Array) -> Array:
        return -a * true_log_loss(ctx, ctx.space.from_unit(np.atleast_2d(u)))

    return log_post


def correct_posterior(ctx: RunContext, chains: list, n_eff: float, settings: PosteriorSettings,
                      rng: np.random.Generator, data: tuple[Array, Array]) -> Any:
    """Importance-sampling correction of the emulated posterior (see :mod:`smcbayes.posterior.correct`).

    ``data`` are the GP's training points ``(x_unit (K, d), log_loss (K,))``: their exact
    log posterior is known and helps shape the first proposal.
    """
    from smcbayes.posterior.correct import correct
    from smcbayes.posterior.summary import stack_components

    unit, _ = stack_components(chains)
    cs = CorrectionSettings(draws=settings.correct_draws)
    known = (data[0], -0.5 * n_eff * np.asarray(data[1], dtype=float))
    return correct(exact_log_posterior(ctx, n_eff), unit.reshape(-1, ctx.space.dim), cs, rng, known)


def refine(ctx: RunContext, data: tuple[Array, Array], surrogate: Any, n_eff: float,
           settings: PosteriorSettings, rng: np.random.Generator, out_dir: Path) -> tuple[Any, tuple[Array, Array]]:
    """Rounds of: sample the emulated posterior of the GP mean (shorter chains), evaluate the
    forward model (random, uncertain and space-filling points of its region), check the
    emulator out of sample, refit.

    Stops when ``settings.refine`` evaluations are spent or, after at least two rounds,
    when the out-of-sample error at the round's random posterior draws is below
    ``settings.refine_tolerance_nats`` in two consecutive rounds.

    Returns the refitted surrogate and the enlarged training data ``(x_unit, log_loss)``.
    """
    from smcbayes.posterior.refine import check_values, round_design

    x, y = data
    remaining, rounds, below = settings.refine, 0, 0
    per_round = max(9, min(30, settings.refine // 4))
    quick = PosteriorSettings(walkers=settings.walkers, steps=min(settings.steps, 1000), functions=0,
                              seed=int(rng.integers(2**31 - 1)))
    while remaining > 0:
        _, chains = sample(ctx, surrogate, n_eff, quick, rng)
        pooled = np.concatenate([c.samples.reshape(-1, ctx.space.dim) for c in chains])
        pts, n_rand = round_design(pooled, surrogate, min(per_round, remaining), rng)
        remaining -= max(len(pts), 1)
        theta = ctx.space.from_unit(pts)
        vals = true_log_loss(ctx, theta)
        cap = float(np.min(y)) + CAP_NATS / (0.5 * n_eff)
        err = check_values(surrogate.predict(pts[:n_rand])[0], np.minimum(vals[:n_rand], cap), n_eff)
        with (out_dir / "refine.jsonl").open("a", encoding="utf-8") as fh:
            for k, (row, val) in enumerate(zip(theta, vals, strict=True)):
                rec = {"round": rounds, "kind": "draw" if k < n_rand else "design",
                       "params": dict(zip(ctx.space.free_names, row.tolist(), strict=True)),
                       "log_loss": None if not np.isfinite(val) else float(val)}
                fh.write(json.dumps(rec) + "\n")
        ok = np.isfinite(vals)
        x, y = np.vstack([x, pts[ok]]), np.concatenate([y, vals[ok]])
        surrogate = fit_local(x, y, n_eff, surrogate.kernel, int(rng.integers(2**31 - 1)))
        rounds += 1
        below = below + 1 if err < settings.refine_tolerance_nats else 0
        print(f"  refined: {x.shape[0]} training points, best log-loss {np.min(y):.4f}, "
              f"out-of-sample error {err:.2f} nats", file=sys.stderr)
        if rounds >= 2 and below >= 2:
            break
    return surrogate, (x, y)


def run_posterior(run_dir: Path, settings: PosteriorSettings) -> dict[str, Any]:
    """The whole stage; returns the content of ``posterior/summary.json``."""
    from smcbayes.surrogate.gp import load_surrogate

    start = time.perf_counter()
    ctx = load_run(run_dir)
    out_dir = run_dir / "posterior"
    out_dir.mkdir(exist_ok=True)
    rng = np.random.default_rng(settings.seed)
    calibration_gp, _ = load_surrogate(run_dir / "gp.pt")
    budget = residual_budget(ctx)
    n_eff = budget["n_eff_total"]
    data = (calibration_gp.x_unit, calibration_gp.log_loss)
    surrogate = fit_local(*data, n_eff, calibration_gp.kernel, settings.seed)
    if settings.refine > 0:
        (out_dir / "refine.jsonl").unlink(missing_ok=True)
        surrogate, data = refine(ctx, data, surrogate, n_eff, settings, rng, out_dir)
        from smcbayes.surrogate.gp import save_surrogate

        save_surrogate(out_dir / "gp_refined.pt", surrogate, {"training_points": int(data[0].shape[0])})
    t_sample = time.perf_counter()
    emul, chains = sample(ctx, surrogate, n_eff, settings, rng)
    t_correct = time.perf_counter()
    corrected = correct_posterior(ctx, chains, n_eff, settings, rng, data) if settings.correct_draws > 0 else None
    t_outputs = time.perf_counter()
    from smcbayes.posterior.report import write_outputs

    info = write_outputs(ctx, emul, chains, budget, settings, rng, out_dir, corrected)
    info["stage_seconds"] = {"setup_and_refine": t_sample - start, "emulator_sampling": t_correct - t_sample,
                             "correction": t_outputs - t_correct, "outputs": time.perf_counter() - t_outputs}
    log = out_dir / "refine.jsonl"
    refined = sum(1 for _ in log.open(encoding="utf-8")) if settings.refine > 0 and log.is_file() else 0
    info["forward_evaluations"].update(refine=refined, residual_budget=2 * ctx.space.dim + 1)
    info["forward_evaluations"]["total"] = sum(info["forward_evaluations"].values())
    info["seconds"] = time.perf_counter() - start
    info["settings"] = asdict(settings)
    from smcbayes.surrogate.runlog import write_json

    write_json(out_dir / "summary.json", info)
    return info
