"""Emulated vs exact posterior on a synthetic 5-parameter problem.

The coarsened 1-D forward model (``[solver]`` of :data:`_posterior_common.COARSE_SOLVER`,
the same for the data, the calibration, the emulator and the exact posterior) is fast
enough to sample the posterior directly: emcee with the walkers batched through
``ForwardModel.simulate`` + ``evaluate_loss``, with the *same* likelihood as the emulator,
-(N_eff / 2) log L(theta), the same N_eff (from the residuals at the calibrated best
point) and the same uniform prior on the unit cube.  The emulated posterior is the
product of ``smcbayes calibrate`` (60 evaluations: 20 Latin hypercube + 40 LogEI) and
``smcbayes posterior --refine R``.

Targets: per-parameter 5/50/95 % quantiles within 10 % of the prior width (unit-cube
coordinates: log10 for tau*, B, tau_c), pairwise correlations within 0.15.

    python benchmarks/posterior_accuracy.py [--cases 2] [--refine 150] [--steps 6000] [--workdir DIR]

Prints a table and writes benchmarks/results/posterior_accuracy.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _posterior_common import (
    BOUNDS,
    Timer,
    calibrate_run,
    emulated_draws,
    make_dataset,
    project_doc,
    unit_of,
    write_result,
)

from smcbayes.posterior.sampler import SamplerSettings, run_ensemble
from smcbayes.posterior.stage import PosteriorSettings, load_run, run_posterior, true_log_loss

TRAIN = ["60-bar-03", "60-bar-11", "60-center-07", "80-bar-07", "80-center-03", "80-center-11"]
CASES: list[dict[str, float]] = [
    # slip active (tau_c well below the wall stresses), shear thinning in the observed range
    {"n": 0.35, "tau_star_Pa": 5.0e3, "B_Pa_s": 2.0e4, "tau_c_MPa": 0.01, "m": 1.4},
    {"n": 0.45, "tau_star_Pa": 2.0e4, "B_Pa_s": 8.0e3, "tau_c_MPa": 0.02, "m": 1.6},
    {"n": 0.30, "tau_star_Pa": 3.0e3, "B_Pa_s": 3.0e4, "tau_c_MPa": 0.008, "m": 1.2},
]
QUANT = (0.05, 0.5, 0.95)
Q_TARGET, R_TARGET = 0.10, 0.15


def exact_posterior(run_dir: Path, n_eff: float, steps: int, seed: int) -> tuple[np.ndarray, int, dict]:
    """emcee on the forward model; returns unit-cube draws ``(N, d)``, evaluations, diagnostics."""
    ctx = load_run(run_dir)
    a = 0.5 * n_eff
    calls = {"n": 0}

    def log_prob(u: np.ndarray) -> np.ndarray:
        u = np.atleast_2d(u)
        out = np.full(u.shape[0], -np.inf)
        inside = np.all((u >= 0) & (u <= 1), axis=1)
        if np.any(inside):
            calls["n"] += int(inside.sum())
            val = true_log_loss(ctx, ctx.space.from_unit(u[inside]))
            out[inside] = np.where(np.isfinite(val), -a * val, -np.inf)
        return out

    rng = np.random.default_rng(seed)
    centre = ctx.space.to_unit(ctx.best_theta)[0]
    ch = run_ensemble(log_prob, ctx.space.dim, SamplerSettings(walkers=32, max_steps=steps, min_steps=500),
                      rng, centre, " (exact)")
    diag = {"steps": ch.steps, "burn": ch.burn, "thin": ch.thin, "converged": ch.converged,
            "tau_max": float(np.max(ch.tau)), "acceptance_median": float(np.median(ch.acceptance))}
    return ch.samples.reshape(-1, ctx.space.dim), calls["n"], diag


def compare(names: list[str], exact: np.ndarray, emul: np.ndarray, truth_unit: np.ndarray) -> dict[str, Any]:
    """Quantiles (unit cube = share of the prior width) and correlations of both posteriors."""
    qe, qm = np.quantile(exact, QUANT, axis=0), np.quantile(emul, QUANT, axis=0)
    diff = np.abs(qm - qe)
    re, rm = np.corrcoef(exact, rowvar=False), np.corrcoef(emul, rowvar=False)
    pairs = [{"a": names[i], "b": names[j], "exact": float(re[i, j]), "emulated": float(rm[i, j]),
              "diff": float(abs(rm[i, j] - re[i, j]))}
             for i in range(len(names)) for j in range(i + 1, len(names))]
    params = [{"name": n, "truth_unit": float(truth_unit[k]),
               "exact_q05_q50_q95_unit": qe[:, k].tolist(), "emulated_q05_q50_q95_unit": qm[:, k].tolist(),
               "diff_share_of_prior_width": diff[:, k].tolist(),
               "met": bool(np.all(diff[:, k] <= Q_TARGET))} for k, n in enumerate(names)]
    return {"parameters": params, "correlations": pairs,
            "max_quantile_diff": float(diff.max()),
            "max_correlation_diff": float(max((p["diff"] for p in pairs), default=0.0)),
            "quantiles_met": bool(diff.max() <= Q_TARGET),
            "correlations_met": bool(all(p["diff"] <= R_TARGET for p in pairs))}


def run_case(k: int, truth: dict[str, float], args: argparse.Namespace, tmp: Path) -> dict[str, Any]:
    timer = Timer()
    folder = tmp / f"case{k}"
    run_dir = folder / "run"
    if not (run_dir / "gp.pt").is_file():
        toml = make_dataset(folder, project_doc(list(BOUNDS), truth, TRAIN), truth, seed=100 + k)
        calibrate_run(toml, run_dir, budget=60, init=20, seed=k)
    cal = json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))
    t_cal = timer()
    info = run_posterior(run_dir, PosteriorSettings(refine=args.refine, seed=k, steps=args.emulator_steps,
                                                        functions=args.functions))
    t_post = timer() - t_cal
    n_eff = float(info["effective_points"]["n_eff_total"])
    cache = folder / f"exact-{args.steps}.npz"
    if cache.is_file():
        z = np.load(cache)
        exact, exact_evals, diag = z["draws"], int(z["evaluations"]), json.loads(str(z["diag"]))
    else:
        exact, exact_evals, diag = exact_posterior(run_dir, n_eff, args.steps, seed=1000 + k)
        np.savez(cache, draws=exact, evaluations=exact_evals, diag=json.dumps(diag))
    t_exact = timer() - t_cal - t_post
    ctx = load_run(run_dir)
    names = ctx.space.free_names
    cmp = compare(names, exact, emulated_draws(run_dir), unit_of(ctx.space, truth))
    refine_evals = sum(1 for _ in (run_dir / "posterior" / "refine.jsonl").open()) if args.refine else 0
    return {"case": k, "truth": truth, "n_eff": n_eff, **cmp,
            "evaluations": {"emulated_calibration": int(cal["evaluations"]), "emulated_refine": refine_evals,
                            "emulated_total": int(cal["evaluations"]) + refine_evals,
                            "emulated_check_draws": int(info["emulator_check"]["points"]),
                            "exact": exact_evals},
            "emulator_check_nats": info["emulator_check"], "emulated_warnings": info["warnings"],
            "emulated_rhat_max": max(p["r_hat"] for p in info["parameters"]),
            "exact_sampler": diag, "exact_draws": int(exact.shape[0]),
            "seconds": {"calibration": t_cal, "posterior": t_post, "exact": t_exact}}


def print_case(r: dict[str, Any]) -> None:
    print(f"\ncase {r['case']}: N_eff {r['n_eff']:.0f}; emulator check MAE "
          f"{r['emulator_check_nats']['mean_abs_error']:.2f} nats, R-hat max {r['emulated_rhat_max']:.3f}; "
          f"forward evaluations: emulated {r['evaluations']['emulated_total']} "
          f"(+{r['evaluations']['emulated_check_draws']} check draws), exact {r['evaluations']['exact']}")
    print(f"{'parameter':<12}{'truth':>7} | {'exact 5/50/95 %':>22} | {'emulated 5/50/95 %':>22} | "
          f"{'max diff':>8}  (unit cube = share of prior width)")
    for p in r["parameters"]:
        e, m = p["exact_q05_q50_q95_unit"], p["emulated_q05_q50_q95_unit"]
        print(f"{p['name']:<12}{p['truth_unit']:>7.3f} | {e[0]:>6.3f} {e[1]:>6.3f} {e[2]:>6.3f}    | "
              f"{m[0]:>6.3f} {m[1]:>6.3f} {m[2]:>6.3f}    | {max(p['diff_share_of_prior_width']):>8.3f} "
              f"{'met' if p['met'] else 'MISSED'}")
    print("correlations (exact / emulated / |diff|):")
    for c in r["correlations"]:
        flag = "" if c["diff"] <= R_TARGET else "  MISSED"
        print(f"  {c['a']:>12} - {c['b']:<12} {c['exact']:>6.2f} {c['emulated']:>6.2f} {c['diff']:>6.2f}{flag}")
    print(f"quantiles within {Q_TARGET:.0%}: {'met' if r['quantiles_met'] else 'MISSED'} "
          f"(max {r['max_quantile_diff']:.3f}); correlations within {R_TARGET}: "
          f"{'met' if r['correlations_met'] else 'MISSED'} (max {r['max_correlation_diff']:.2f})")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=int, default=2, help=f"number of truths (max {len(CASES)})")
    ap.add_argument("--refine", type=int, default=150, help="refinement evaluations of the emulator")
    ap.add_argument("--steps", type=int, default=6000, help="maximum emcee steps of the exact posterior")
    ap.add_argument("--emulator-steps", type=int, default=4000, help="maximum emcee steps per mixture component")
    ap.add_argument("--functions", type=int, default=8, help="GP sample functions of the emulated posterior")
    ap.add_argument("--workdir", default=None,
                    help="keep datasets, calibrations and exact draws here and reuse them when rerun")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.workdir) if args.workdir else Path(tmp)
        for k, truth in enumerate(CASES[: args.cases]):
            rows.append(run_case(k, truth, args, work))
            print_case(rows[-1])
            write_result("posterior_accuracy", {"settings": vars(args), "train": TRAIN, "cases": rows})
    met = all(r["quantiles_met"] and r["correlations_met"] for r in rows)
    print(f"\noverall: {'met' if met else 'MISSED'}")
    payload = {"settings": vars(args), "train": TRAIN, "solver": "coarsened 1-D (see _posterior_common)",
               "targets": {"quantile_share_of_prior_width": Q_TARGET, "correlation": R_TARGET},
               "cases": rows, "all_met": met}
    print(f"wrote {write_result('posterior_accuracy', payload)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
