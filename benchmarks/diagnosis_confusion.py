"""Confusion matrix of the gap diagnosis on synthetic data with a known, withheld effect.

For each effect of the library (values: ``smcbayes.diagnose.synthetic.EFFECT_TRUTH``, each
clearly present and physically plausible) and for no effect, synthetic "measured" curves of
the nine thesis training configurations (60 % bar, 60 % centre, 80 % bar at 0.3 / 0.7 /
1.1 mm/s) are generated with noise (white 2 kN + correlated 3 kN over 0.5 s) for several
noise seeds.  The base model is calibrated on all nine (batched differential evolution from
a Latin hypercube, see ``smcbayes.diagnose.synthetic``), then diagnosed with all five
candidates; the held-out configurations are the three 0.7 mm/s ones (the diagnosis's
default: the middle speed per group), the effects are re-fitted on the other six.

Printed: the confusion matrix (true effect vs top-ranked effect, "none" when no effect is
significant), the held-out shrink per case and the held-out loss of the named effect
against the noise floor (the held-out loss of the true model on the same data).
Written: ``benchmarks/results/diagnosis_confusion.json``.

Run: ``python benchmarks/diagnosis_confusion.py [--seeds 2] [--none-seeds 3] [--restarts 2]
[--effects NAME,...] [--name diagnosis_confusion]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from smcbayes.config import load_project  # noqa: E402
from smcbayes.data.synth import NoiseSpec  # noqa: E402
from smcbayes.diagnose.fit import FitSettings  # noqa: E402
from smcbayes.diagnose.run import DiagnoseSettings, diagnose  # noqa: E402
from smcbayes.diagnose.synthetic import (  # noqa: E402
    BASE_TRUTH,
    EFFECT_TRUTH,
    calibrate_base,
    make_case,
)

IDS = ["60-bar-03", "60-bar-07", "60-bar-11", "60-center-03", "60-center-07", "60-center-11",
       "80-bar-03", "80-bar-07", "80-bar-11"]
NOISE = NoiseSpec(white_kN=2.0, correlated_kN=3.0, correlation_s=0.5)
EFFECTS = tuple(EFFECT_TRUTH)


def noise_floor(ctx, effect: str | None, ids: list[str]) -> float:
    """Held-out loss (kN^2) of the true model (true effect and values) on the noisy data."""
    extra = (effect,) if effect else ()
    truth = {**BASE_TRUTH, **(EFFECT_TRUTH[effect] if effect else {})}
    space = ctx.model(extra).space
    theta = np.array([[truth[n] for n in space.free_names]])
    return float(np.mean(ctx.losses(extra, theta, ids)[0]))


def run_case(project, effect: str | None, seed: int, args: argparse.Namespace, work: Path) -> dict:
    """Synthetic data, base calibration and diagnosis of one case."""
    t0 = time.perf_counter()
    synth = make_case(project, IDS, effect, NOISE, seed, work / f"{effect or 'none'}-{seed}")
    rng = np.random.default_rng(1000 + seed)
    ctx = calibrate_base(synth, args.calib_population, args.calib_generations, rng)
    fit = FitSettings(population=args.population, generations=args.generations,
                      restarts=args.restarts)
    settings = DiagnoseSettings(candidates=EFFECTS, seed=seed, fit=fit, figures=False)
    summary = diagnose(ctx, settings, None, log=lambda m: print("   ", m, flush=True))
    top = summary["decision"]["best"]
    named = top or summary["ranking"][0]["effect"]
    holdout = summary["holdout"]
    floor = noise_floor(ctx, effect, holdout)
    row = next(r for r in summary["ranking"] if r["effect"] == named)
    return {"true": effect or "none", "seed": seed, "top": top or "none",
            "top_ranked": summary["ranking"][0]["effect"], "statement": summary["decision"]["statement"],
            "holdout_loss_base_kN2": row["holdout_loss_base_kN2"],
            "holdout_loss_named_kN2": row["holdout_loss_kN2"],
            "holdout_shrink_pct": row["holdout_shrink_pct"], "noise_floor_kN2": floor,
            "ratio_to_floor": row["holdout_loss_kN2"] / floor,
            "ranking": [{k: r[k] for k in ("effect", "holdout_loss_kN2", "dm_z", "score", "significant")}
                        for r in summary["ranking"]],
            "verdict": summary["where"]["verdict"], "seconds": time.perf_counter() - t0}


def main() -> int:
    """Run every case and print the confusion matrix."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=2, help="noise seeds per effect")
    ap.add_argument("--none-seeds", type=int, default=3, help="noise seeds without an effect")
    ap.add_argument("--population", type=int, default=FitSettings.population)
    ap.add_argument("--generations", type=int, default=FitSettings.generations)
    ap.add_argument("--restarts", type=int, default=FitSettings.restarts)
    ap.add_argument("--calib-population", type=int, default=40)
    ap.add_argument("--calib-generations", type=int, default=30)
    ap.add_argument("--effects", default=",".join(EFFECTS), help="effect cases to run")
    ap.add_argument("--name", default="diagnosis_confusion",
                    help="results file benchmarks/results/NAME.json")
    args = ap.parse_args()
    project = load_project(ROOT / "configs" / "thesis.toml")
    cases = [(e, s) for e in args.effects.split(",") if e for s in range(args.seeds)]
    cases += [(None, s) for s in range(args.none_seeds)]
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for effect, seed in cases:
            print(f"case {effect or 'none'} seed {seed}", flush=True)
            out.append(run_case(project, effect, seed, args, Path(tmp)))
            write(out, args, partial=True)
            r = out[-1]
            print(f"  -> {r['top']} (held-out shrink {r['holdout_shrink_pct']:.1f} %, "
                  f"{r['ratio_to_floor']:.2f} x noise floor, {r['seconds']:.0f} s)", flush=True)
    labels = list(EFFECTS) + ["none"]
    matrix = {t: {p: sum(1 for r in out if r["true"] == t and r["top"] == p) for p in labels}
              for t in labels}
    print("\nconfusion matrix (rows: true effect, columns: named effect)")
    print(f"{'':>17}" + "".join(f"{p[:10]:>11}" for p in labels))
    for t in labels:
        print(f"{t:>17}" + "".join(f"{matrix[t][p]:>11}" for p in labels))
    eff_cases = [r for r in out if r["true"] != "none"]
    none_cases = [r for r in out if r["true"] == "none"]
    hit = sum(r["top"] == r["true"] for r in eff_cases)
    within = sum(r["ratio_to_floor"] <= 2.0 for r in eff_cases if r["top"] == r["true"])
    print(f"\ntrue effect named first: {hit}/{len(eff_cases)}; 'none' on no-effect data: "
          f"{sum(r['top'] == 'none' for r in none_cases)}/{len(none_cases)}; named effect within 2x "
          f"noise floor on held-out data: {within}/{hit}")
    print(f"{'case':>22} {'named':>17} {'shrink %':>9} {'loss/floor':>11}")
    for r in out:
        print(f"{r['true'] + ' #' + str(r['seed']):>22} {r['top']:>17} {r['holdout_shrink_pct']:>9.1f} "
              f"{r['ratio_to_floor']:>11.2f}")
    summary = {"matrix": matrix, "effect_hits": hit, "effect_cases": len(eff_cases),
               "none_hits": sum(r["top"] == "none" for r in none_cases),
               "none_cases": len(none_cases), "within_2x_floor": within}
    print(f"written {write(out, args, partial=False, **summary)}")
    return 0


def write(cases: list[dict], args: argparse.Namespace, partial: bool, **summary: object) -> Path:
    """Write the results so far (``partial``) or the final ones to the results folder."""
    result = {"configurations": IDS, "noise": asdict(NOISE), "effect_truth": EFFECT_TRUTH,
              "base_truth": BASE_TRUTH, "settings": vars(args), "partial": partial,
              "cases": cases, **summary}
    path = ROOT / "benchmarks" / "results" / f"{args.name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2, default=float) + "\n", encoding="utf-8")
    return path


if __name__ == "__main__":
    raise SystemExit(main())
