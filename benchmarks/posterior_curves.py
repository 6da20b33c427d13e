"""The curve emulator's posterior against the exact one, by forward runs spent.

Runs on the cases of ``benchmarks/posterior_accuracy.py`` and reuses its work folder: the
calibration run (60 evaluations), the exact reference (adaptive importance sampling on the
forward model, cached there) and, when present, the stage's own posterior of that run (of
whichever emulator that run's settings took, named in the output) for a comparison in the
same run.  The curve emulator (:mod:`smcbayes.posterior.curves`) starts from the
calibration's points, simulated again for their curves (counted as the calibration's), and learns
actively (its stopping rule off, so every budget is spent; each budget's learning starts
afresh from the last one's points); at each budget its posterior is sampled, as the stage
reports it, by importance on the emulator (from 10,000 emcee steps, the stage's chains
stop at 3,000), and compared with the reference: 5/50/95 % quantiles (share of the prior width; target 0.10),
correlations (0.15), MMTV (0.2) and the Gaussianised symmetric KL; the emcee draws alone
are judged too.  Its error at 40 draws of its posterior is measured on the forward model
(runs not counted in the budget).  ``posterior_accuracy.py --emulator curves
--correct-draws 0`` judges the stage's own path, stopping rule included.

    python benchmarks/posterior_accuracy.py --case 0 --workdir W      # first: reference
    python benchmarks/posterior_curves.py --case 0 --workdir W [--budgets 220,380,500,700,1000]
        [--seeds 2] [--first-seed 0]

Prints a table and writes benchmarks/results/posterior_curves_case<K>_seed<S>.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _posterior_common import posterior_samples, stage_emulator, write_result
from posterior_accuracy import Q_TARGET, R_TARGET, compare

from smcbayes.posterior.correct import CorrectionSettings
from smcbayes.posterior.curve_sample import EXPECTED_LOSS, sample_chains, sample_emulator
from smcbayes.posterior.curve_stage import learn
from smcbayes.posterior.curves import CurveFeatures
from smcbayes.posterior.stage import load_run, residual_budget
from smcbayes.surrogate.gp import load_surrogate

NAMES = ["n", "tau_star", "B", "tau_c", "m"]
CHECK_DRAWS = 40


def reference(folder: Path, case: int) -> tuple[np.ndarray, np.ndarray]:
    """The accuracy benchmark's cached reference of ``case``: points ``(M, d)``, weights ``(M,)``."""
    found = sorted(folder.glob(f"pooledref-*-s{4000 + case}-*.npz"))
    if not found:
        raise SystemExit(f"no reference in {folder}: run benchmarks/posterior_accuracy.py --case {case} "
                         "--workdir with the same folder first")
    z = np.load(found[0])
    return z["unit"], z["w"] / z["w"].sum()


def summary(c: dict[str, Any]) -> dict[str, Any]:
    row = {m: c[m] for m in ("max_quantile_diff", "max_correlation_diff", "mmtv", "gskl")}
    row["met"] = bool(c["max_quantile_diff"] <= Q_TARGET and c["max_correlation_diff"] <= R_TARGET
                      and c["mmtv"] < 0.2)
    return row


def run_seed(run_dir: Path, ref: tuple[np.ndarray, np.ndarray], budgets: list[int], seed: int) -> list[dict]:
    """The curve emulator's accuracy at each budget (forward runs, calibration included) for
    one seed: the stage's active learning without its stopping rule, resumed budget after
    budget."""
    ctx = load_run(run_dir)
    features = CurveFeatures(ctx.problem)
    post = run_dir / "posterior" / "summary.json"
    n_eff = (json.loads(post.read_text(encoding="utf-8"))["effective_points"]["n_eff_total"]
             if post.is_file() else residual_budget(ctx)["n_eff_total"])

    def simulate(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return features.of(ctx.runner.simulate(ctx.space.from_unit(u), features.ids))

    gp, _ = load_surrogate(ctx.run.gp_path)
    x0 = np.asarray(gp.x_unit, dtype=float)
    y0, ok = simulate(x0)
    x, y, spent = x0[ok], y0[ok], len(x0)
    rng = np.random.default_rng(seed)
    rows: list[dict] = []
    start = time.perf_counter()
    for budget in sorted(budgets):
        # a tolerance of 0 never validates a round: every budget is spent
        learned = learn(simulate, features, x, y, n_eff, budget - spent, 0.0, rng)
        emulator, x, y = learned.emulator, learned.x, learned.y
        spent += learned.record["evaluations"]
        centre = x[np.argmin(features.loss(y))]
        row: dict[str, Any] = {"seed": seed, "budget": spent, "rows": len(x), "n_eff": n_eff,
                               "components": emulator.components,
                               "lengthscales": emulator.corr.lengthscales.tolist()}
        draws = sample_chains(emulator, n_eff, rng, centre, steps=10000).samples.reshape(-1, x.shape[1])
        row["emcee"] = summary(compare(NAMES, ref, draws, np.zeros(len(NAMES))))
        sample = sample_emulator(emulator, n_eff, draws, CorrectionSettings(), rng)
        row["importance"] = summary(compare(NAMES, ref, sample.unit, np.zeros(len(NAMES)), sample.weights))
        row["importance_ess"], row["importance_k_hat"] = sample.ess, sample.k_hat
        # the error at the stage's posterior, on the forward model
        check = sample.resample(CHECK_DRAWS, rng)
        exact = -0.5 * n_eff * np.log(ctx.runner.loss(ctx.space.from_unit(check)))
        emulated = -0.5 * n_eff * np.log(emulator.loss(check, variance=EXPECTED_LOSS))
        row["check_mae_nats"] = float(np.nanmean(np.abs(exact - emulated)))
        row["seconds"] = time.perf_counter() - start
        rows.append(row)
        m, v = row["importance"], row["emcee"]
        print(f"  seed {seed}, {spent:>5} forward runs ({len(x)} rows, {emulator.components} components): "
              f"quantiles {m['max_quantile_diff']:.3f} correlations {m['max_correlation_diff']:.2f} "
              f"MMTV {m['mmtv']:.3f} gsKL {m['gskl']:.2f} {'met' if m['met'] else 'MISSED'} (importance ESS "
              f"{sample.ess:.0f}); emcee chains {v['max_quantile_diff']:.3f} / "
              f"{v['max_correlation_diff']:.2f} / {v['mmtv']:.3f}; check {row['check_mae_nats']:.2f} nats; "
              f"{row['seconds']:.0f} s", flush=True)
    return rows


def baseline(run_dir: Path, ref: tuple[np.ndarray, np.ndarray]) -> dict[str, Any] | None:
    """The stage's own posterior of the run (if the accuracy benchmark left one)."""
    post = run_dir / "posterior" / "summary.json"
    if not post.is_file():
        return None
    info = json.loads(post.read_text(encoding="utf-8"))
    c = summary(compare(NAMES, ref, posterior_samples(run_dir)["emulator"], np.zeros(len(NAMES))))
    cal = json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))
    kind = {"curves": "curve", "loss": "log-loss"}[stage_emulator(info)]
    return {**c, "forward_runs": int(cal["evaluations"]) + info["forward_evaluations"]["inference"],
            "reliable": info["reliable"], "emulator": kind}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", type=int, default=0, help="case of posterior_accuracy.py")
    ap.add_argument("--workdir", required=True, help="posterior_accuracy.py's --workdir")
    ap.add_argument("--budgets", default="220,380,500,700,1000",
                    help="forward runs in all (calibration included)")
    ap.add_argument("--seeds", type=int, default=1, help="number of seeds")
    ap.add_argument("--first-seed", type=int, default=0, help="seeds first-seed, first-seed + 1, ...")
    args = ap.parse_args()
    folder = Path(args.workdir) / f"case{args.case}"
    ref = reference(folder, args.case)
    base = baseline(folder / "run", ref)
    if base is not None:
        print(f"case {args.case}: the stage's {base['emulator']} emulator, "
              f"{base['forward_runs']} forward runs: "
              f"quantiles {base['max_quantile_diff']:.3f} correlations {base['max_correlation_diff']:.2f} "
              f"MMTV {base['mmtv']:.3f} gsKL {base['gskl']:.2f} (reliable: {base['reliable']})")
    budgets = [int(b) for b in args.budgets.split(",")]
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    rows = [r for seed in seeds for r in run_seed(folder / "run", ref, budgets, seed)]
    path = write_result(f"posterior_curves_case{args.case}_seed{args.first_seed}",
                        {"settings": vars(args), "baseline": base, "rows": rows})
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
