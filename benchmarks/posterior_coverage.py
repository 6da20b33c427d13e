"""Frequentist coverage of the emulated posterior over synthetic datasets.

Truths are drawn from the prior (uniform in the unit cube of the free parameters, i.e.
log-uniform for tau*, B and tau_c; seeded); each dataset is simulated with white +
correlated force noise on training and held-out (validation) configurations, calibrated
(``smcbayes calibrate``) and sampled (``smcbayes posterior --refine``).  Reported per free
parameter: the share of truths inside the central 90 % and 50 % credible intervals
(targets 80-97 % and 40-60 %), and the share of held-out measured points inside the 90 %
(and 50 %) predictive bands (target 80-97 %).

The parameter space is reduced (default: n, B, tau_c free; tau*, m fixed) so that 20
datasets fit in about half an hour on two shared cores; the forward model is the coarsened
1-D solver of the accuracy benchmark.

    python benchmarks/posterior_coverage.py [--datasets 20] [--quick] [--free n,B_Pa_s,tau_c_MPa]

Prints a table and writes benchmarks/results/posterior_coverage.json.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _posterior_common import (
    BOUNDS,
    DEFAULTS,
    Timer,
    calibrate_run,
    emulated_draws,
    make_dataset,
    project_doc,
    unit_of,
    write_result,
)

from smcbayes.posterior.stage import PosteriorSettings, load_run, run_posterior

TRAIN = ["60-bar-03", "60-bar-11", "60-center-07"]
VALIDATION = ["80-center-03", "80-center-11"]
TARGET90, TARGET50, TARGET_BAND = (0.80, 0.97), (0.40, 0.60), (0.80, 0.97)


def draw_truth(free: list[str], rng: np.random.Generator) -> dict[str, float]:
    """A truth from the uniform prior on the unit cube of ``free`` (others at their defaults)."""
    truth = dict(DEFAULTS)
    for name in free:
        lo, hi = BOUNDS[name]
        u = float(rng.random())
        log = name in ("tau_star_Pa", "B_Pa_s", "tau_c_MPa")
        truth[name] = float(10 ** (np.log10(lo) + u * np.log10(hi / lo))) if log else lo + u * (hi - lo)
    return truth


def one_dataset(i: int, free: list[str], args: argparse.Namespace, tmp: Path) -> dict[str, Any]:
    timer = Timer()
    truth = draw_truth(free, np.random.default_rng([args.seed, i]))
    folder = tmp / f"ds{i}"
    doc = project_doc(free, truth, TRAIN, VALIDATION)
    toml = make_dataset(folder, doc, truth, seed=10_000 + i)
    run_dir = folder / "run"
    budget = args.budget or 12 * len(free)
    cal = calibrate_run(toml, run_dir, budget=budget, init=max(5, 4 * len(free)), seed=i,
                        local_evaluations=budget // 3, local_radius=0.1)
    settings = PosteriorSettings(refine=args.refine, seed=i, steps=1500 if args.quick else 4000,
                                 draws=60 if args.quick else 100, functions=4 if args.quick else 8)
    info = run_posterior(run_dir, settings)
    space = load_run(run_dir).space
    u = emulated_draws(run_dir)
    t = unit_of(space, truth)
    q = np.quantile(u, [0.05, 0.25, 0.75, 0.95], axis=0)
    bands = info["bands"]
    return {"dataset": i, "truth": {n: truth[n] for n in free}, "truth_unit": t.tolist(),
            "in90": ((t >= q[0]) & (t <= q[3])).tolist(), "in50": ((t >= q[1]) & (t <= q[2])).tolist(),
            "q05_q25_q75_q95_unit": q.T.tolist(),
            "band_coverage90": {c: b["coverage90"] for c, b in bands.items()},
            "band_coverage50": {c: b["coverage50"] for c, b in bands.items()},
            "emulator_check_nats": info["emulator_check"]["mean_abs_error"],
            "rhat_max": max(p["r_hat"] for p in info["parameters"]), "n_eff": info["effective_points"]["n_eff_total"],
            "evaluations": int(cal["evaluations"]) + args.refine, "seconds": timer()}


def within(x: float, rng: tuple[float, float]) -> str:
    return "met" if rng[0] <= x <= rng[1] else "MISSED"


def tabulate(free: list[str], rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Coverage shares per parameter and of the predictive bands, with met/MISSED flags."""
    in90, in50 = np.array([r["in90"] for r in rows]), np.array([r["in50"] for r in rows])
    b90 = np.array([v for r in rows for v in r["band_coverage90"].values() if np.isfinite(v)])
    b50 = np.array([v for r in rows for v in r["band_coverage50"].values() if np.isfinite(v)])
    per = [{"name": n, "coverage90": float(in90[:, k].mean()), "coverage50": float(in50[:, k].mean()),
            "met90": within(float(in90[:, k].mean()), TARGET90), "met50": within(float(in50[:, k].mean()), TARGET50)}
           for k, n in enumerate(free)]
    band = {"coverage90_mean": float(b90.mean()) if b90.size else float("nan"),
            "coverage50_mean": float(b50.mean()) if b50.size else float("nan"),
            "coverage90_median": float(np.median(b90)) if b90.size else float("nan")}
    band["met90"] = within(band["coverage90_mean"], TARGET_BAND)
    return {"parameters": per, "bands": band}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--datasets", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="shorter chains, 4 sample functions, 60 draws")
    ap.add_argument("--free", default="n,B_Pa_s,tau_c_MPa", help="free parameters (comma-separated)")
    ap.add_argument("--budget", type=int, default=0, help="calibration evaluations (0: 12 per parameter)")
    ap.add_argument("--refine", type=int, default=20, help="refinement evaluations")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    free = [f.strip() for f in args.free.split(",") if f.strip()]
    timer = Timer()
    rows: list[dict[str, Any]] = []
    print(f"coverage over {args.datasets} datasets; free: {', '.join(free)} ({len(free)}-parameter space; "
          f"the others fixed at {', '.join(f'{k}={v:g}' for k, v in DEFAULTS.items() if k not in free)})")
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.datasets):
            rows.append(one_dataset(i, free, args, Path(tmp)))
            r = rows[-1]
            print(f"  dataset {i:>2}: truth unit {np.round(r['truth_unit'], 3).tolist()} in90 {r['in90']} "
                  f"in50 {r['in50']} band90 {np.nanmean(list(r['band_coverage90'].values())):.2f} "
                  f"check {r['emulator_check_nats']:.2f} nats, R-hat {r['rhat_max']:.3f}, {r['seconds']:.0f} s",
                  flush=True)
            write_result("posterior_coverage", {"settings": vars(args), "free": free, "datasets": rows})
    table = tabulate(free, rows)
    print(f"\n{'parameter':<14}{'in 90 % CI':>12}{'':>8}{'in 50 % CI':>12}")
    for p in table["parameters"]:
        print(f"{p['name']:<14}{p['coverage90']:>12.0%}{p['met90']:>8}{p['coverage50']:>12.0%}{p['met50']:>8}")
    b = table["bands"]
    print(f"held-out predictive bands ({', '.join(VALIDATION)}): 90 % band covers {b['coverage90_mean']:.0%} "
          f"of points (median {b['coverage90_median']:.0%}) {b['met90']}; 50 % band {b['coverage50_mean']:.0%}")
    print(f"targets: 90 % CI {TARGET90[0]:.0%}-{TARGET90[1]:.0%}, 50 % CI {TARGET50[0]:.0%}-{TARGET50[1]:.0%}, "
          f"bands {TARGET_BAND[0]:.0%}-{TARGET_BAND[1]:.0%}; {len(rows)} datasets, {timer() / 60:.1f} min")
    payload = {"settings": vars(args), "free": free, "train": TRAIN, "validation": VALIDATION,
               "targets": {"ci90": TARGET90, "ci50": TARGET50, "band90": TARGET_BAND},
               **table, "datasets": rows, "minutes": timer() / 60}
    print(f"wrote {write_result('posterior_coverage', payload)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
