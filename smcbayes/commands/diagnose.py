"""``smcbayes diagnose``: where the sim-to-real gap lies, which effect causes it, how far it
shrinks."""

from __future__ import annotations

import argparse
from pathlib import Path

from smcbayes.errors import ConfigError


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    p = sub.add_parser(
        "diagnose", help="diagnose the sim-to-real gap of a calibration run",
        description="Where the calibrated model misses the measurements (per configuration, "
                    "phase and normalised time, with a text verdict), which unmodelled effect "
                    "explains the gap (signature score, warm-started re-calibration of base + "
                    "effect scored on held-out configurations with a penalty for its extra "
                    "parameters), and how far the gap shrinks. Writes summary.json, "
                    "ranking.csv and figures to --out.")
    p.add_argument("run_dir", metavar="RUN_DIR", help="run directory of `smcbayes calibrate`")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--effects", metavar="NAME,...", default=None,
                       help="candidate effects, comma-separated (default: all not already on)")
    which.add_argument("--all", action="store_true", help="try every available effect (default)")
    p.add_argument("--holdout", metavar="ID,...", default=None,
                   help="held-out configurations, comma-separated (default: the middle speed of "
                        "each charge group)")
    p.add_argument("--pair", action="store_true",
                   help="also re-calibrate the best two effects together")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed, same ranking)")
    p.add_argument("--population", type=int, default=64,
                   help="parameter sets per generation (default 64)")
    p.add_argument("--generations", type=int, default=50,
                   help="optimiser generations per re-calibration (default 50)")
    p.add_argument("--restarts", type=int, default=2,
                   help="independent evolutions per re-calibration, the best kept (default 2)")
    p.add_argument("--min-score", type=float, default=3.0,
                   help="penalised held-out score (log Bayes factor) needed to name an effect "
                        "(default 3)")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(run=run)


def candidates(spec: str | None) -> tuple[str, ...] | None:
    """Validated candidate names (None: all); unknown names raise with the closest match."""
    from smcbayes.errors import closest
    from smcbayes.forward.effects import available

    if spec is None:
        return None
    names = sorted(available())
    chosen = [s.strip() for s in spec.split(",") if s.strip()]
    if not chosen:
        raise ConfigError(f"--effects: no effect named; available: {', '.join(names)}")
    for name in chosen:
        if name not in names:
            raise ConfigError(f"--effects: unknown effect '{name}'{closest(name, names)}; "
                              f"available: {', '.join(names)}")
    if len(set(chosen)) != len(chosen):
        raise ConfigError("--effects: an effect is listed twice")
    return tuple(chosen)


def not_on(chosen: tuple[str, ...] | None, already_on: tuple[str, ...]) -> tuple[str, ...]:
    """Candidates that the calibration did not already have on."""
    from smcbayes.forward.effects import available

    if chosen is None:
        chosen = tuple(n for n in sorted(available()) if n not in already_on)
    on = [n for n in chosen if n in already_on]
    if on:
        raise ConfigError(f"--effects: '{on[0]}' is already on in the calibration; drop it")
    if not chosen:
        raise ConfigError("no candidate effect to try: every available effect is already on")
    return chosen


def run(args: argparse.Namespace) -> int:
    """Execute ``diagnose``."""
    from smcbayes.diagnose.fit import FitSettings
    from smcbayes.diagnose.load import context_from_run
    from smcbayes.diagnose.run import DiagnoseSettings, diagnose

    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        raise ConfigError(f"{run_dir}: run directory not found; pass the --out folder of "
                          "`smcbayes calibrate`")
    chosen = candidates(args.effects)
    fit = FitSettings(population=args.population, generations=args.generations,
                      restarts=args.restarts)
    fit.check()
    holdout = None
    if args.holdout is not None:
        holdout = tuple(s.strip() for s in args.holdout.split(",") if s.strip())
    ctx = context_from_run(run_dir)
    settings = DiagnoseSettings(candidates=not_on(chosen, ctx.base_effects), holdout=holdout,
                                pair=args.pair, seed=args.seed, fit=fit, min_score=args.min_score,
                                figures=not args.no_figures)
    summary = diagnose(ctx, settings, Path(args.out))
    print(f"where: {summary['where']['verdict']}")
    print(f"{'rank':>4}  {'effect':<34} {'held-out loss kN2':>18} {'shrink %':>9} {'z':>7} "
          f"{'score':>9}")
    for r in summary["ranking"]:
        print(f"{r['rank']:>4}  {r['effect']:<34} {r['holdout_loss_kN2']:>18.4g} "
              f"{r['holdout_shrink_pct']:>9.1f} {r['dm_z']:>7.2f} {r['score']:>9.3g}"
              f"{'  *' if r['significant'] else ''}")
    print(summary["decision"]["statement"])
    print(f"outputs: {args.out}/summary.json, ranking.csv, figures/")
    return 0
