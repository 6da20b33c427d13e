"""How noisy the reported posterior's spread is, by the number of supports it is drawn on.

The curve emulator's spread (how far its GP sample functions move a 5/50/95 % quantile of
the posterior, :mod:`smcbayes.posterior.curve_spread`) decides the stage's verdict against
0.10 of a parameter's range, and it is a Monte Carlo reading: each support is a fresh draw
of points from the reported importance sample and of 32 functions on them.  This benchmark
calibrates as ``real_posterior.py`` does (in its own work directory, reused there while its
settings are the same), runs the posterior stage on all nine measured thesis trials
(curve emulator, no correction), keeps the stage's final emulator and importance sample,
and draws the spread again ``--draws`` times for each count of ``--supports``, with BLAS
and torch on one thread as in the stage.  The importance sample stays fixed, so its own
noise is not in these figures; reading k of every count starts from the seed 1000 + k, so
the counts are paired (a larger count's first supports are a smaller one's).  Per count:
mean, standard deviation, range, the share of readings above 0.10, each reading's own
bootstrap standard error over its supports (which the standard deviation checks) and the
seconds a reading takes; with the stage's verdict, runs and own reading and the load
average.

    python benchmarks/spread_noise.py [--seed 0] [--draws 10] [--supports 4,12]
        [--workdir DIR] [--data-dir DIR] [--name spread_noise]

Writes ``benchmarks/results/NAME.json``.  Needs ../shared/data/thesis-press next to the
repository (``--data-dir``); without it, prints why and exits 0.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from real_posterior import DATA, PROJECT, RESULTS, calibrated, seed_list  # noqa: E402


def final_state(run: Path, seed: int) -> dict[str, Any]:
    """The posterior stage on ``run`` (curve emulator, no correction, the other settings the
    stage's defaults) and what its reported posterior's spread is drawn from: the emulator,
    N_eff, the importance sample, the parameters' names, the stage's own spread record and
    its summary (``info``)."""
    import smcbayes.posterior.stage as stage
    from smcbayes.posterior.stage import PosteriorSettings

    kept: dict[str, Any] = {}
    original = stage.curve_posterior

    def keeping(ctx: Any, *args: Any, **kwargs: Any) -> Any:
        emulation, active, data, posterior = original(ctx, *args, **kwargs)
        if posterior is None:
            raise RuntimeError("the stage drew no reported posterior of the curve emulator")
        kept.update(emulator=emulation.emulator, n_eff=emulation.n_eff, sample=posterior.sample,
                    names=list(ctx.space.free_names), stage_spread=posterior.spread)
        return emulation, active, data, posterior

    stage.curve_posterior = keeping
    try:
        kept["info"] = stage.run_posterior(run, PosteriorSettings(emulator="curves",
                                                                  correct_draws=0, seed=seed))
    finally:
        stage.curve_posterior = original
    return kept


def readings(state: dict[str, Any], supports: int, draws: int) -> dict[str, Any]:
    """``draws`` readings of the spread on ``supports`` supports (seeds 1000, 1001, ...)."""
    from smcbayes.posterior.curve_spread import curve_spread
    from smcbayes.surrogate.gp import gp_session

    values: list[float] = []
    errors: list[float | None] = []
    t0 = time.perf_counter()
    with gp_session():  # one BLAS and torch thread, as in the stage
        for k in range(draws):
            spread, _ = curve_spread(state["emulator"], state["n_eff"], state["sample"], state["names"],
                                     np.random.default_rng(1000 + k), supports=supports)
            values.append(float(spread["max_quantile_shift"]))
            errors.append(spread.get("max_quantile_shift_se"))
    v = np.array(values)
    known = [e for e in errors if e is not None]
    return {"supports": supports, "readings": values, "mean": float(v.mean()),
            "sd": float(v.std(ddof=1)), "min": float(v.min()), "max": float(v.max()),
            "standard_errors": errors, "mean_standard_error": float(np.mean(known)) if known else None,
            "share_above_0.10": float(np.mean(v > 0.10)),
            "seconds_per_reading": (time.perf_counter() - t0) / draws}


def main() -> int:
    """Run the stage once, read its spread again and again, print and write the figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="the posterior stage's seed")
    ap.add_argument("--draws", type=int, default=10, help="readings per count of supports")
    ap.add_argument("--supports", type=seed_list, default=[4, 12], help="counts of supports, comma-separated")
    ap.add_argument("--workdir", default=None, help="default: benchmarks/results/NAME/work")
    ap.add_argument("--data-dir", default=str(DATA))
    ap.add_argument("--name", default="spread_noise")
    args = ap.parse_args()
    if not Path(args.data_dir).is_dir():
        print(f"skipped: no measured data at {args.data_dir} (pass --data-dir)")
        return 0
    if args.draws < 2 or min(args.supports) < 1:
        ap.error("--draws must be at least 2 and each count of --supports at least 1")
    workdir = Path(args.workdir or RESULTS / args.name / "work")
    calibration, _ = calibrated(workdir, PROJECT, Path(args.data_dir), 0)
    run = workdir / f"spread-seed-{args.seed}"
    shutil.rmtree(run, ignore_errors=True)
    shutil.copytree(calibration, run,
                    ignore=lambda folder, names: ["posterior"] if Path(folder) == calibration else [])
    load = os.getloadavg()[0]
    state = final_state(run, args.seed)
    info = state["info"]
    stage_reading = state["stage_spread"]["max_quantile_shift"] if state["stage_spread"] else None
    stage = {"reliable": bool(info.get("reliable")), "spread": stage_reading,
             "active_learning_runs": (info.get("active_learning") or {}).get("evaluations")}
    print(f"seed {args.seed}: {'reliable' if stage['reliable'] else 'unreliable'} after "
          f"{stage['active_learning_runs']} runs, the stage's own reading {stage_reading}")
    rows = [readings(state, n, args.draws) for n in args.supports]
    for r in rows:
        se = r["mean_standard_error"]
        print(f"{r['supports']:3d} supports: mean {r['mean']:.4f}, sd {r['sd']:.4f}, "
              f"{r['min']:.3f}-{r['max']:.3f}, above 0.10 in {r['share_above_0.10']:.0%}, "
              f"each reading's own standard error {'n/a' if se is None else f'{se:.4f}'} on average, "
              f"{r['seconds_per_reading']:.1f} s a reading")
    out = {"settings": vars(args), "stage": stage, "cpu_count": os.cpu_count(),
           "load_average_before_after": [load, os.getloadavg()[0]], "counts": rows}
    path = RESULTS / f"{args.name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2) + "\n", encoding="utf-8")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
