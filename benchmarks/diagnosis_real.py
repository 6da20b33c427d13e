"""Gap diagnosis on the 9 real training configurations of the thesis press trials.

The base model is calibrated on all 9 configurations (batched differential evolution from a
Latin hypercube, ``smcbayes.diagnose.synthetic.calibrate_base``), then diagnosed with the 5
candidate effects.  Held out: one speed per group, the middle one (0.7 mm/s) of each of the
three groups (60 % bar, 60 % centre, 80 % bar), i.e. ``60-bar-07``, ``60-center-07``,
``80-bar-07``; the effects are re-calibrated on the 0.3 and 1.1 mm/s trials.  With
``--pair`` the best two effects are also re-calibrated together.

Printed: the where-verdict, the ranking, the decision, the shrink on fitting and held-out
configurations, and the runtime of the diagnosis (target: <= 15 min for 5 candidates on 9
configurations).  Written: ``benchmarks/results/diagnosis_real.json`` and the figures in
``benchmarks/results/diagnosis_real/figures/``.

Run: ``python benchmarks/diagnosis_real.py [--data-dir DIR] [--pair]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from smcbayes.config import load_project  # noqa: E402
from smcbayes.diagnose.fit import FitSettings  # noqa: E402
from smcbayes.diagnose.run import DiagnoseSettings, diagnose  # noqa: E402
from smcbayes.diagnose.synthetic import calibrate_base  # noqa: E402

HOLDOUT = ("60-bar-07", "60-center-07", "80-bar-07")
CANDIDATES = ("compressibility", "heating", "curing", "press_compliance", "speed_ramp")


def main() -> int:
    """Calibrate, diagnose, print and write the results."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data-dir", default=str(ROOT / ".." / "shared" / "data" / "thesis-press"))
    ap.add_argument("--pair", action="store_true", help="also fit the best two effects together")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--population", type=int, default=FitSettings.population)
    ap.add_argument("--generations", type=int, default=FitSettings.generations)
    ap.add_argument("--restarts", type=int, default=FitSettings.restarts)
    ap.add_argument("--calib-population", type=int, default=40)
    ap.add_argument("--calib-generations", type=int, default=30)
    args = ap.parse_args()
    if not Path(args.data_dir).is_dir():
        print(f"no measured data at {args.data_dir}; pass --data-dir", file=sys.stderr)
        return 2
    project = load_project(ROOT / "configs" / "thesis.toml", args.data_dir)
    t0 = time.perf_counter()
    ctx = calibrate_base(project, args.calib_population, args.calib_generations,
                         np.random.default_rng(args.seed))
    t_cal = time.perf_counter() - t0
    print(f"base calibration on {len(ctx.ids)} configurations: {t_cal:.0f} s; "
          + ", ".join(f"{k}={v:.4g}" for k, v in ctx.base_params.items()), flush=True)
    settings = DiagnoseSettings(candidates=CANDIDATES, holdout=HOLDOUT, pair=args.pair, seed=args.seed,
                                fit=FitSettings(population=args.population,
                                                generations=args.generations,
                                                restarts=args.restarts))
    out = ROOT / "benchmarks" / "results" / "diagnosis_real"
    t1 = time.perf_counter()
    summary = diagnose(ctx, settings, out, log=lambda m: print("  ", m, flush=True))
    t_diag = time.perf_counter() - t1
    print(f"\nwhere: {summary['where']['verdict']}")
    print(f"\n{'rank':>4} {'effect':<34} {'fit loss':>10} {'held-out':>10} {'shrink %':>9} {'z':>6} "
          f"{'score':>8} {'absorb %':>9}")
    for r in summary["ranking"]:
        absorb = r["absorbable_share"]
        print(f"{r['rank']:>4} {r['effect']:<34} {r['fit_loss_kN2']:>10.4g} {r['holdout_loss_kN2']:>10.4g} "
              f"{r['holdout_shrink_pct']:>9.1f} {r['dm_z']:>6.2f} {r['score']:>8.3g} "
              f"{'' if absorb is None else f'{100 * absorb:.0f}':>9}{'  *' if r['significant'] else ''}")
    print(f"\n{summary['decision']['statement']}")
    shrink = summary["shrink"]
    for label, entry in shrink["models"].items():
        extra = "".join(f", {s} shrink {entry[s]['shrink_pct']:.1f} %" for s in ("fit", "holdout")
                        if "shrink_pct" in entry[s])
        print(f"{label:<34} fit loss {entry['fit']['loss_kN2']:.4g} kN^2, held-out loss "
              f"{entry['holdout']['loss_kN2']:.4g} kN^2{extra}")
        per = {**entry["fit"]["per_config"], **entry["holdout"]["per_config"]}
        print("   RMSE kN: " + ", ".join(f"{c} {v['rmse_kN']:.0f}" for c, v in per.items()))
    print(f"\ndiagnosis runtime: {t_diag:.0f} s ({t_diag / 60:.1f} min) for {len(CANDIDATES)} candidates "
          f"on {len(ctx.ids)} configurations (target <= 15 min); base calibration {t_cal:.0f} s")
    result = {"holdout": list(HOLDOUT), "settings": vars(args), "calibration_s": t_cal,
              "diagnosis_s": t_diag, "base_params": ctx.base_params, "summary": summary,
              "figures": str(out / "figures")}
    path = ROOT / "benchmarks" / "results" / "diagnosis_real.json"
    path.write_text(json.dumps(result, indent=2, default=float) + "\n", encoding="utf-8")
    print(f"written {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
