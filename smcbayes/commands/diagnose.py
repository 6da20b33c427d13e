"""``smcbayes diagnose``: where the sim-to-real gap lies, which effect causes it, how far it
shrinks."""

from __future__ import annotations

import argparse
from pathlib import Path

from smcbayes.commands.common import add_executor_options
from smcbayes.config import DiagnoseSpec, help_of, override
from smcbayes.forward.effects import check_names
from smcbayes.run import RunDir
from smcbayes.simulation.executors.base import make_executor


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
    p.add_argument("--pair", action="store_true", default=None,
                   help="also re-calibrate two effects together: the one the decision names and the "
                        "best-scoring other (the two best when none is named; default: the "
                        "[diagnose] table's pair)")
    for name, kind in (("seed", int), ("population", int), ("generations", int), ("restarts", int),
                       ("min_score", float), ("max_effects", int)):
        p.add_argument("--" + name.replace("_", "-"), type=kind, default=None,
                       help=help_of(DiagnoseSpec, name))
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    add_executor_options(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(run=run)


def candidates(spec: str | None) -> tuple[str, ...] | None:
    """``--effects NAME,...`` parsed and validated (None: all); unknown names raise with the
    closest match."""
    return None if spec is None else check_names(spec.split(","), "--effects")


def settings_from(spec: DiagnoseSpec, args: argparse.Namespace) -> DiagnoseSpec:
    """The project's ``[diagnose]`` table with the command line's overrides."""
    values = {k: getattr(args, k) for k in ("seed", "population", "generations", "restarts", "min_score",
                                            "pair", "max_effects")}
    if args.effects is not None:
        values["effects"] = list(candidates(args.effects) or ())
    if args.holdout is not None:
        values["holdout"] = [s.strip() for s in args.holdout.split(",") if s.strip()]
    return override(spec, values)


def run(args: argparse.Namespace) -> int:
    """Execute ``diagnose``."""
    # the stage loads torch and scipy.optimize: only when it runs, not at start-up
    from smcbayes.diagnose.load import context_from_run
    from smcbayes.diagnose.run import INERT_SHRINK_PCT, diagnose, settings_for

    candidates(args.effects)  # a misspelt effect is reported before the run is read
    run_dir = RunDir(args.run_dir)
    run_dir.require()
    spec = settings_from(run_dir.identity().project_config().diagnose, args)
    ctx = context_from_run(run_dir, lambda: make_executor(args.workers, args.scheduler))
    settings = settings_for(spec, ctx.base_effects, figures=not args.no_figures)
    out = run_dir.begin_stage("diagnose", spec.model_dump(mode="json"), folder=Path(args.out))
    run_dir.record_command("diagnose", args.argv)
    try:
        summary = diagnose(ctx, settings, out)
    finally:
        ctx.close()
    run_dir.complete_stage("diagnose", summary, folder=out)
    print(f"where: {summary['where']['verdict']}")
    print(f"{'rank':>4}  {'effect':<34} {'held-out loss kN2':>18} {'shrink %':>9} {'z':>7} "
          f"{'score':>9}")
    named = summary["decision"].get("best")
    for r in summary["ranking"]:
        print(f"{r['rank']:>4}  {r['effect']:<34} {r['holdout_loss_kN2']:>18.4g} "
              f"{r['holdout_shrink_pct']:>9.1f} {r['dm_z']:>7.2f} {r['score']:>9.3g}"
              f"{'  *' if r['significant'] else ''}{'  <- named' if r['effect'] == named else ''}")
    print(summary["decision"]["statement"])
    left_out = summary["selection"].get("left_out") or []
    if left_out:
        print(f"selection: {', '.join(left_out)} not tried (alone, their parameters could not move the "
              f"curves along the gap and the held-out loss changed by less than {INERT_SHRINK_PCT:g} %)")
    for step in summary["selection"]["steps"]:
        verdict = (f"added {step['added']}" if step["added"]
                   else f"stop ({step['best_candidate']} not significant)")
        if step.get("chosen_over"):
            verdict += (f" (within --min-score of {step['chosen_over']}'s held-out score, larger evidence "
                        "on all trials)")
        print(f"selection: {verdict}: held-out loss {step['holdout_loss_before_kN2']:.4g} -> "
              f"{step['holdout_loss_after_kN2']:.4g} kN^2, score {step['score']:.3g}")
    if summary["selected_effects"]:
        effects = " ".join(f"--effect {e}" for e in summary["selected_effects"])
        print(f"selected: {' + '.join(summary['selected_effects'])}; calibrate it with "
              f"`smcbayes calibrate CONFIG --effects-from {args.out}` (or {effects})")
    print(f"outputs: {args.out}/summary.json, ranking.csv, figures/")
    return 0
