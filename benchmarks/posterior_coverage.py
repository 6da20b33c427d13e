"""Frequentist coverage of the emulated posterior over synthetic datasets.

Truths are drawn from the prior (uniform in the unit cube of the free parameters, i.e.
log-uniform for tau*, B and tau_c; seeded); each dataset is simulated with white +
correlated force noise on training and held-out (validation) configurations, calibrated
(``smcbayes calibrate``) and sampled with the default posterior path (active learning of
the emulator; ``--correct-draws`` adds the importance correction as a second posterior).
Reported per free parameter, for the emulated posterior and, when asked for, the
importance-corrected one: the share of truths inside the central 90 % and 50 % credible intervals (targets
80-97 % and 40-60 %) with its Clopper-Pearson 95 % interval (with 20 datasets even a
perfect method lands outside 40-60 % for the 50 % interval about a third of the time),
the mean width of the 90 % interval as a share of the prior range (its sharpness: the
prior itself covers 90 % at width 0.9), and the share of held-out measured points inside
the 90 % (and 50 %) predictive bands (target 80-97 %) with their mean width (kN).

The parameter space is reduced (default: n, B, tau_c free; tau*, m fixed) so that 20
datasets fit in about half an hour on two shared cores; the forward model is the coarsened
1-D solver of the accuracy benchmark.

    python benchmarks/posterior_coverage.py [--datasets 20] [--quick] [--free n,B_Pa_s,tau_c_MPa]
        [--refine N] [--correct-draws 0] [--emulator auto|curves|loss] [--jobs 2] [--workdir DIR]

With the curve emulator (``auto``, the default, takes it here) and ``--correct-draws 0``
the weighted posterior is the curve emulator's own importance sample (no forward run; the
stage's reported posterior), the raw one its emcee chains.

Prints a table and writes benchmarks/results/posterior_coverage.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _posterior_common import (
    BOUNDS,
    DEFAULTS,
    Timer,
    calibrate_run,
    make_dataset,
    posterior_samples,
    project_doc,
    stage_emulator,
    unit_of,
    write_result,
)

from smcbayes.config import PosteriorSpec, choices_of
from smcbayes.posterior.correct import weighted_quantile
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
    run_dir = folder / "run"
    budget = args.budget or 12 * len(free)
    if (run_dir / "gp.pt").is_file():
        cal = json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))
    else:
        toml = make_dataset(folder, project_doc(free, truth, TRAIN, VALIDATION), truth, seed=10_000 + i)
        cal = calibrate_run(toml, run_dir, budget=budget, init=max(5, 4 * len(free)), seed=i,
                            local_evaluations=budget // 3, local_radius=0.1)
    settings = PosteriorSettings(refine=args.refine, seed=i,
                                 steps=1500 if args.quick else PosteriorSettings().steps,
                                 draws=60 if args.quick else 100, correct_draws=args.correct_draws,
                                 emulator=args.emulator)
    info = run_posterior(run_dir, settings)
    space = load_run(run_dir).space
    samples = posterior_samples(run_dir)
    t = unit_of(space, truth)
    row = {"dataset": i, "truth": {n: truth[n] for n in free}, "truth_unit": t.tolist()}
    kinds = [("raw", samples["emulator"], None)]
    if samples["weighted"] is not None:
        kinds.append(("corrected", *samples["weighted"]))
    for kind, u, w in kinds:
        w = np.full(u.shape[0], 1.0 / u.shape[0]) if w is None else w
        q = np.array([weighted_quantile(u[:, k], w, [0.05, 0.25, 0.75, 0.95]) for k in range(u.shape[1])]).T
        row[kind] = {"in90": ((t >= q[0]) & (t <= q[3])).tolist(),
                     "in50": ((t >= q[1]) & (t <= q[2])).tolist(),
                     "width90_unit": (q[3] - q[0]).tolist(), "width50_unit": (q[2] - q[1]).tolist(),
                     "q05_q25_q75_q95_unit": q.T.tolist()}
    bands = info["bands"]
    row.update({"band_coverage90": {c: b["coverage90"] for c, b in bands.items()},
                "band_width90_kN": {c: b.get("width90_kN", float("nan")) for c, b in bands.items()},
                "reliable": bool(info.get("reliable", False)),
                "emulator": stage_emulator(info),
                "band_coverage50": {c: b["coverage50"] for c, b in bands.items()},
                "emulator_check_nats": info["emulator_check"]["mean_abs_error"],
                "correction": {k: v for k, v in info["correction"].items() if k != "history"},
                "rhat_max": max(p["r_hat"] for p in info["emulator_parameters"]),
                "n_eff": info["effective_points"]["n_eff_total"],
                "evaluations": {"calibration": int(cal["evaluations"]), **info["forward_evaluations"]},
                "seconds": timer()})
    return row


def map_datasets(free: list[str], args: argparse.Namespace, work: Path) -> Iterator[dict[str, Any]]:
    """Rows of every dataset, as they finish; ``--jobs`` processes share the datasets.

    Each dataset depends only on its index (seeds, folder), so the rows are the same
    whatever the number of processes; only their order of completion changes.
    """
    if args.jobs <= 1:
        for i in range(args.datasets):
            yield one_dataset(i, free, args, work)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(args.jobs, mp_context=multiprocessing.get_context("spawn"),
                             initializer=_single_thread) as pool:
        futures = [pool.submit(one_dataset, i, free, args, work) for i in range(args.datasets)]
        for fut in as_completed(futures):
            yield fut.result()


def _single_thread() -> None:
    """One thread per worker process (the workers already share the cores)."""
    import torch

    torch.set_num_threads(1)


def binomial_ci(hits: int, n: int) -> tuple[float, float]:
    """Clopper-Pearson 95 % interval of a share ``hits / n``."""
    from scipy.stats import binomtest

    ci = binomtest(hits, n).proportion_ci(0.95, method="exact")
    return float(ci.low), float(ci.high)


def within(x: float, rng: tuple[float, float]) -> str:
    return "met" if rng[0] <= x <= rng[1] else "MISSED"


def tabulate(free: list[str], rows: list[dict[str, Any]], kind: str) -> list[dict[str, Any]]:
    """Coverage shares per parameter of the ``raw`` or ``corrected`` posterior, with 95 % intervals."""
    rows = [r for r in rows if kind in r]
    if not rows:
        return []
    in90 = np.array([r[kind]["in90"] for r in rows])
    in50 = np.array([r[kind]["in50"] for r in rows])
    w90 = np.array([r[kind]["width90_unit"] for r in rows])
    out = []
    for k, n in enumerate(free):
        c90, c50 = float(in90[:, k].mean()), float(in50[:, k].mean())
        out.append({"name": n, "datasets": len(rows), "coverage90": c90, "coverage50": c50,
                    "ci95_coverage90": binomial_ci(int(in90[:, k].sum()), len(rows)),
                    "ci95_coverage50": binomial_ci(int(in50[:, k].sum()), len(rows)),
                    "width90_unit_mean": float(w90[:, k].mean()),
                    "met90": within(c90, TARGET90), "met50": within(c50, TARGET50)})
    return out


def tabulate_bands(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Share of held-out measured points inside the predictive bands."""
    b90 = np.array([v for r in rows for v in r["band_coverage90"].values() if np.isfinite(v)])
    b50 = np.array([v for r in rows for v in r["band_coverage50"].values() if np.isfinite(v)])
    band = {"coverage90_mean": float(b90.mean()) if b90.size else float("nan"),
            "coverage50_mean": float(b50.mean()) if b50.size else float("nan"),
            "coverage90_median": float(np.median(b90)) if b90.size else float("nan")}
    w = np.array([v for r in rows for v in r.get("band_width90_kN", {}).values() if np.isfinite(v)])
    band["width90_kN_mean"] = float(w.mean()) if w.size else float("nan")
    band["met90"] = within(band["coverage90_mean"], TARGET_BAND)
    return band


def print_table(label: str, table: list[dict[str, Any]]) -> None:
    print(f"\n{label}:")
    print(f"  {'parameter':<14}{'in 90 % CI':>12}{'95 % interval':>16}{'':>8}"
          f"{'in 50 % CI':>12}{'95 % interval':>16}"
          f"{'90 % width':>12}")
    for p in table:
        a, b = p["ci95_coverage90"], p["ci95_coverage50"]
        print(f"  {p['name']:<14}{p['coverage90']:>12.0%}{f'{a[0]:.0%}-{a[1]:.0%}':>16}{p['met90']:>8}"
              f"{p['coverage50']:>12.0%}{f'{b[0]:.0%}-{b[1]:.0%}':>16}{p['met50']:>8}"
              f"{p['width90_unit_mean']:>12.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--datasets", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="shorter chains, 4 sample functions, 60 draws")
    ap.add_argument("--free", default="n,B_Pa_s,tau_c_MPa", help="free parameters (comma-separated)")
    ap.add_argument("--budget", type=int, default=0, help="calibration evaluations (0: 12 per parameter)")
    ap.add_argument("--refine", type=int, default=PosteriorSettings().refine,
                    help="active-learning evaluations (default: the posterior stage's default)")
    ap.add_argument("--correct-draws", type=int, default=0,
                    help="most proposal draws of the importance correction (0: none, the default path)")
    ap.add_argument("--emulator", choices=choices_of(PosteriorSpec, "emulator"),
                    default=PosteriorSettings().emulator,
                    help="what the stage's GP emulates (default: the stage's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1, help="datasets run in parallel processes")
    ap.add_argument("--workdir", default=None,
                    help="keep datasets and calibrations here and reuse them when rerun (same --seed/--free)")
    args = ap.parse_args()
    free = [f.strip() for f in args.free.split(",") if f.strip()]
    timer = Timer()
    rows: list[dict[str, Any]] = []
    print(f"coverage over {args.datasets} datasets; free: {', '.join(free)} ({len(free)}-parameter space; "
          f"the others fixed at {', '.join(f'{k}={v:g}' for k, v in DEFAULTS.items() if k not in free)})")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.workdir) if args.workdir else Path(tmp)
        for r in map_datasets(free, args, work):
            rows.append(r)
            rep = r.get("corrected", r["raw"])
            print(f"  dataset {r['dataset']:>2}: truth unit {np.round(r['truth_unit'], 3).tolist()} "
                  f"in90 raw {r['raw']['in90']} "
                  f"corrected {rep['in90']}, in50 corrected {rep['in50']}, "
                  f"band90 {np.nanmean(list(r['band_coverage90'].values())):.2f}, "
                  f"k-hat {r['correction'].get('k_hat', float('nan')):.2f}, "
                  f"check {r['emulator_check_nats']:.2f} nats, {r['seconds']:.0f} s", flush=True)
            write_result("posterior_coverage", {"settings": vars(args), "free": free, "datasets": rows})
    rows.sort(key=lambda r: r["dataset"])
    raw, corrected, b = tabulate(free, rows, "raw"), tabulate(free, rows, "corrected"), tabulate_bands(rows)
    print_table("emulated posterior (emcee on the actively learnt GP)", raw)
    if corrected:
        own = args.correct_draws == 0 and all(r["emulator"] == "curves" for r in rows)
        print_table("the curve emulator's importance sample (the reported posterior)" if own
                    else "importance-corrected posterior", corrected)
    k_hat = [r["correction"].get("k_hat", float("nan")) for r in rows]
    ev = {k: float(np.mean([r["evaluations"].get(k, 0) for r in rows]))
          for k in ("calibration", "refine", "correction", "emulator_check", "bands")}
    print("\nforward evaluations per dataset (mean): "
          f"calibration {ev['calibration']:.0f}, refine {ev['refine']:.0f}, "
          f"correction {ev['correction']:.0f}, "
          f"emulator check {ev['emulator_check']:.0f}, bands {ev['bands']:.0f}; "
          f"Pareto k-hat median {np.nanmedian(k_hat):.2f}, "
          f"> 0.7 in {int(np.sum(np.array(k_hat) > 0.7))} datasets")
    print(f"held-out predictive bands ({', '.join(VALIDATION)}; "
          "from the reported posterior): 90 % band covers "
          f"{b['coverage90_mean']:.0%} of points (median {b['coverage90_median']:.0%}) {b['met90']}, "
          f"mean width {b['width90_kN_mean']:.0f} kN; 50 % band {b['coverage50_mean']:.0%}")
    print(f"posterior reported reliable in {sum(r['reliable'] for r in rows)} of {len(rows)} datasets")
    print(f"targets: 90 % CI {TARGET90[0]:.0%}-{TARGET90[1]:.0%}, "
          f"50 % CI {TARGET50[0]:.0%}-{TARGET50[1]:.0%}, "
          f"bands {TARGET_BAND[0]:.0%}-{TARGET_BAND[1]:.0%}; {len(rows)} datasets, {timer() / 60:.1f} min")
    payload = {"settings": vars(args), "free": free, "train": TRAIN, "validation": VALIDATION,
               "targets": {"ci90": TARGET90, "ci50": TARGET50, "band90": TARGET_BAND},
               "raw": raw, "corrected": corrected, "parameters": corrected or raw, "bands": b,
               "evaluations_mean": ev, "datasets": rows, "minutes": timer() / 60}
    print(f"wrote {write_result('posterior_coverage', payload)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
