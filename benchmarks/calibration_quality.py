"""Calibration quality on synthetic problems with a known truth.

Part ``slip2d``: the thesis's 2-D check (configs/verify-slip-2d.toml): 5 Latin hypercube
points + 25 BO evaluations per seed; success when the best point lies within 2 % of the
search-range width of the truth in log10 tau_c and in m.

Part ``five``: all 5 parameters free on synthetic data from 5 configurations, equal budgets
of 60 evaluations per seed for BO (20 LHS + 40 LogEI), random Latin hypercube search and
scipy's differential evolution; median best loss and median parameter error (largest
absolute error in unit-cube coordinates, i.e. as a share of each search range, log10 for
scale parameters).

    python benchmarks/calibration_quality.py [--part slip2d|five|all] [--seeds 5]

Prints a table and writes benchmarks/results/calibration_quality.json.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.optimize import differential_evolution

from smcbayes.config import load_project
from smcbayes.run.runlog import RunLog
from smcbayes.simulation.executors.local import LocalExecutor
from smcbayes.simulation.objective import Task, combine
from smcbayes.simulation.problem import build_problem
from smcbayes.surrogate.design import latin_hypercube, round_rng
from smcbayes.surrogate.loop import BayesOpt, BOSettings

ROOT = Path(__file__).resolve().parents[1]
FIVE_TRUTH = {"n": 0.35, "tau_star_Pa": 5.0e3, "B_Pa_s": 2.0e4, "tau_c_MPa": 0.03, "m": 1.4}


def loss_of(problem, theta: np.ndarray) -> np.ndarray:
    """Loss of each row of ``theta`` ``(P, d)`` (NaN where failed)."""
    obj = problem.objective
    idx = tuple(range(theta.shape[0]))
    res = {c: obj.evaluate(Task(idx, theta, c)) for c in obj.config_ids}
    return np.array([combine({c: float(res[c].error[i]) for c in obj.config_ids}, obj.config_ids)
                     for i in idx])


def unit_error(problem, params: dict[str, float], truth: dict[str, float]) -> np.ndarray:
    """Absolute error per free parameter as a share of its (log) search range."""
    space = problem.model.space
    names = space.free_names
    a = space.to_unit(np.array([[params[n] for n in names]]))[0]
    b = space.to_unit(np.array([[truth[n] for n in names]]))[0]
    return np.abs(a - b)


def run_bo(problem, settings: BOSettings) -> tuple[float, dict[str, float], float]:
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        bo = BayesOpt(problem.objective, settings, RunLog(Path(tmp) / "log.jsonl"), LocalExecutor(1)).run()
        best = bo.best()
        return best["loss"], best["params"], time.perf_counter() - start


def part_slip2d(seeds: int) -> dict:
    project = load_project(ROOT / "configs" / "verify-slip-2d.toml")
    with tempfile.TemporaryDirectory() as tmp:
        problem = build_problem(project, Path(tmp))
    rows = []
    for seed in range(seeds):
        c = project.calibration
        settings = BOSettings(budget=30, init=5, batch=1, kernel=c.kernel, seed=seed,
                              local_evaluations=c.local_evaluations, local_radius=c.local_radius)
        loss, params, seconds = run_bo(problem, settings)
        err = unit_error(problem, params, problem.truth)
        ok = bool(np.all(err <= 0.02))
        rows.append({"seed": seed, "best_loss_kN2": loss, "tau_c_MPa": params["tau_c_MPa"],
                     "m": params["m"], "error_share_log10_tau_c": float(err[0]),
                     "error_share_m": float(err[1]), "within_2pct": ok, "seconds": seconds})
        print(f"slip2d seed {seed}: loss {loss:.4g} kN^2, tau_c {params['tau_c_MPa']:.5g} MPa, "
              f"m {params['m']:.4f}, errors {err[0]:.4f} / {err[1]:.4f} of range, "
              f"{'ok' if ok else 'MISS'}, {seconds:.1f} s")
    hits = sum(r["within_2pct"] for r in rows)
    print(f"slip2d: {hits}/{seeds} seeds within 2 % of the range (target >= 4 of 5)")
    return {"seeds": rows, "hits": hits, "truth": problem.truth}


def five_problem(tmp: Path):
    project = load_project(ROOT / "configs" / "verify-slip-2d.toml")
    params = {k: v.model_copy(update={"fixed": False}) for k, v in project.parameters.items()}
    bounds = {"n": (0.2, 0.6), "tau_star_Pa": (1e3, 1e5), "B_Pa_s": (1e3, 1e5)}
    params = {k: v.model_copy(update={"bounds": bounds.get(k, v.bounds)}) for k, v in params.items()}
    cal = project.calibration.model_copy(update={"truth": FIVE_TRUTH})
    project = project.model_copy(update={"parameters": params, "calibration": cal})
    return build_problem(project, tmp)


def run_random(problem, budget: int, seed: int) -> tuple[float, dict[str, float]]:
    space = problem.model.space
    theta = space.from_unit(latin_hypercube(budget, space.dim, round_rng(seed, 0)))
    losses = loss_of(problem, theta)
    i = int(np.nanargmin(losses))
    return float(losses[i]), {k: float(v[0]) for k, v in space.batch(theta[i:i + 1]).items()}


class _Budget(Exception):
    pass


def run_de(problem, budget: int, seed: int) -> tuple[float, dict[str, float]]:
    space = problem.model.space
    seen: list[tuple[float, np.ndarray]] = []

    def f(u: np.ndarray) -> float:
        if len(seen) >= budget:
            raise _Budget
        theta = space.from_unit(u[None, :])
        value = float(loss_of(problem, theta)[0])
        seen.append((value if np.isfinite(value) else np.inf, theta[0]))
        return value if np.isfinite(value) else 1e12

    try:
        differential_evolution(f, [(0.0, 1.0)] * space.dim, popsize=2, maxiter=1000, polish=False,
                               init="latinhypercube", rng=np.random.default_rng(seed), tol=0)
    except _Budget:
        pass
    value, theta = min(seen[:budget], key=lambda s: s[0])
    return value, {k: float(v[0]) for k, v in space.batch(theta[None, :]).items()}


def part_five(seeds: int, budget: int = 60) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        problem = five_problem(Path(tmp))
    truth = problem.truth
    out: dict[str, list] = {"bo": [], "random": [], "de": []}
    for seed in range(seeds):
        settings = BOSettings(budget=budget, init=20, batch=1, kernel="matern52", seed=seed,
                              local_evaluations=15, local_radius=0.1)
        start = time.perf_counter()
        loss, params, _ = run_bo(problem, settings)
        out["bo"].append((loss, float(unit_error(problem, params, truth).max()), time.perf_counter() - start))
        for name, fn in (("random", run_random), ("de", run_de)):
            start = time.perf_counter()
            loss, params = fn(problem, budget, seed)
            out[name].append((loss, float(unit_error(problem, params, truth).max()),
                              time.perf_counter() - start))
        print(f"five seed {seed}: " + ", ".join(f"{k} loss {v[-1][0]:.4g} err {v[-1][1]:.3f}"
                                                for k, v in out.items()))
    table = {}
    for name, rows in out.items():
        arr = np.array(rows)
        table[name] = {"median_best_loss_kN2": float(np.median(arr[:, 0])),
                       "median_max_param_error_share": float(np.median(arr[:, 1])),
                       "median_seconds": float(np.median(arr[:, 2])),
                       "best_loss_kN2": arr[:, 0].tolist(), "max_param_error_share": arr[:, 1].tolist()}
        print(f"{name:<7} median best loss {table[name]['median_best_loss_kN2']:10.4g} kN^2   "
              f"median max parameter error {table[name]['median_max_param_error_share']:.3f} of range   "
              f"{table[name]['median_seconds']:.1f} s")
    ratio = table["bo"]["median_best_loss_kN2"] / table["random"]["median_best_loss_kN2"]
    below = table["bo"]["median_best_loss_kN2"] < table["de"]["median_best_loss_kN2"]
    print(f"BO / random median best loss = {ratio:.3f} (target <= 0.25); BO below DE: {below}")
    return {"budget": budget, "truth": truth, "methods": table, "bo_over_random": ratio, "bo_below_de": below}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("slip2d", "five", "all"), default="all")
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()
    out_path = ROOT / "benchmarks" / "results" / "calibration_quality.json"
    result = json.loads(out_path.read_text()) if out_path.exists() else {}
    if args.part in ("slip2d", "all"):
        result["slip2d"] = part_slip2d(args.seeds)
    if args.part in ("five", "all"):
        result["five"] = part_five(args.seeds)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(result, indent=2, default=float) + "\n")
    print(f"wrote {out_path}")


if __name__ == "__main__":
    main()
