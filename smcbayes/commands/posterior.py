"""``smcbayes posterior``: sample the emulated posterior of a calibration run."""

from __future__ import annotations

import argparse
import warnings
from typing import Any

from smcbayes.commands.common import add_executor_options
from smcbayes.config import PosteriorSpec, choices_of, help_of, override
from smcbayes.errors import UnreliablePosteriorWarning
from smcbayes.posterior.spread import pooled_words, spread_words
from smcbayes.run import RunDir
from smcbayes.simulation.executors.base import make_executor


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    p = sub.add_parser(
        "posterior", help="posterior of the parameters from a calibration run (actively learned GP emulator)",
        description="Start from the calibration's GP as an emulator, train it by active "
                    "learning with the run's simulator (fresh posterior draws as the out-of-sample "
                    "check, and exploring points: where the GP is unsure and a tempered posterior "
                    "could be large with the log-loss emulator, draws of the posterior "
                    "mass the expected loss's variance hides with the curve one; "
                    "stops once validated and GP sample functions no longer move the posterior), "
                    "and report its posterior; without a correction, pooled with those of GP "
                    "sample functions, so the emulator's uncertainty widens the posterior.  By "
                    "default (--emulator auto) the GP emulates each training configuration's force "
                    "curve where the project's loss and data allow it, the likelihood computed "
                    "from the emulated curves and its posterior sampled by importance on the "
                    "emulator; otherwise (and on noise-free curves) it emulates the log loss, "
                    "sampled with emcee and, with the built-in 1-D model, corrected by adaptive "
                    "importance sampling with the exact forward model (Pareto k-hat reported).  "
                    "--correct-draws D runs that correction after either emulator, 0 skips it.  "
                    "Writes RUN_DIR/posterior/: posterior.nc (arviz), summary table, "
                    "correlations, corner plot, and predictive bands with coverage on the "
                    "validation configurations (figure, and bands/<id>.csv with the predictive "
                    "mean, the point prediction).  summary.json says whether the posterior is "
                    "reliable, with the reasons.  Settings come from the project's [posterior] "
                    "table; the options override it.")
    p.add_argument("run_dir", help="directory of a `smcbayes calibrate` run")
    for name, kind, metavar in (("walkers", int, None), ("steps", int, None), ("functions", int, None),
                                ("refine", int, "N"), ("round_runs", int, "N"), ("draws", int, None),
                                ("correct_draws", int, "D"), ("seed", int, None), ("threads", int, "T")):
        p.add_argument("--" + name.replace("_", "-"), type=kind, default=None, metavar=metavar,
                       help=help_of(PosteriorSpec, name))
    p.add_argument("--pool-functions", action=argparse.BooleanOptionalAction, default=None,
                   help=help_of(PosteriorSpec, "pool_functions"))
    p.add_argument("--emulator", choices=choices_of(PosteriorSpec, "emulator"), default=None,
                   help=help_of(PosteriorSpec, "emulator"))
    add_executor_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``posterior``."""
    from smcbayes.posterior.stage import run_posterior  # torch: loaded only when needed

    run_dir = RunDir(args.run_dir)
    run_dir.require()
    project = run_dir.identity().project_config()
    fields = ("emulator", "walkers", "steps", "functions", "pool_functions", "refine", "round_runs", "draws",
              "correct_draws", "seed", "threads")
    settings = override(project.posterior, {k: getattr(args, k) for k in fields})
    run_dir.record_command("posterior", args.argv)
    with warnings.catch_warnings():
        # the verdict is printed once, with its reasons, at the end of the summary
        warnings.simplefilter("ignore", UnreliablePosteriorWarning)
        info = run_posterior(run_dir, settings, make_executor(args.workers, args.scheduler))
    print_summary(info)
    print(f"posterior: {run_dir.root / 'posterior'} (posterior.nc, summary.csv, bands/, figures/)")
    return 0


def _r_hat_cell(r_hat: float | None) -> str:
    """R-hat in three decimals (the column's fixed width; the report's ``fmt`` gives
    significant digits), '-' where there is none: in an importance-weighted table (NaN, or
    null once read from ``summary.json``) no chain made the sample."""
    return "-" if r_hat is None or r_hat != r_hat else f"{r_hat:.3f}"


def print_summary(info: dict[str, Any]) -> None:
    """The summary table, strongest correlations, emulator check, coverage and warnings."""
    print(f"{'parameter':<24}{'mean':>11}{'sd':>11}{'5%':>11}{'50%':>11}{'95%':>11}{'R-hat':>8}{'ESS':>8}")
    for s in info["parameters"]:
        name = f"{s['name']} ({s['unit']})" if s["unit"] != "-" else s["name"]
        print(f"{name:<24}" + "".join(f"{s[k]:>11.4g}" for k in ("mean", "sd", "q05", "q50", "q95"))
              + f"{_r_hat_cell(s.get('r_hat')):>8}{s['ess']:>8.0f}")
    for pair in info["correlation"]["strongest"]:
        print(f"correlated: {pair['a']} - {pair['b']}: r = {pair['r']:+.2f}")
    corr = info.get("correction") or {}
    if corr.get("enabled") and corr.get("target") == "emulator":
        print(f"the emulated posterior sampled by importance: {corr['draws']} "
              "emulator evaluations (no forward "
              f"run), Pareto k-hat {corr['k_hat']:.2f}, "
              f"importance ESS {corr['ess']:.0f} (emcee chains' table "
              "in summary_emulator.csv)")
    elif corr.get("enabled"):
        print(f"importance correction: {corr['evaluations']} forward evaluations, Pareto k-hat "
              f"{corr['k_hat']:.2f}, importance ESS {corr['ess']:.0f} (table above: corrected posterior; "
              "emulator-only table in summary_emulator.csv)")
    ec = info["emulator_check"]
    print(f"emulator check at {ec['points']} posterior draws: log-likelihood error "
          f"mean |e| {ec['mean_abs_error']:.3g} nats, max {ec['max_abs_error']:.3g} nats")
    active = info.get("active_learning") or {}
    if active.get("kind") == "curves":
        error = active["error_nats"] if active["error_nats"] is not None else float("nan")
        failed = sum(1 for c in active.get("confirmations") or [] if not c.get("passed"))
        unconfirmed = (f", {failed} validation(s) not confirmed by the reported posterior's spread"
                       if failed else "")
        verdict = ("validated" if active.get("converged") else "not validated (budget spent)") + unconfirmed
        reused = active.get("start_runs_from_calibration") or 0
        kept = f", the calibration's curves of {reused} more reused" if reused else ""
        print(f"curve emulator: {active['evaluations']} forward runs ({active['start_runs']} at the "
              f"calibration's points{kept}), {active['components']} principal components, worst "
              f"out-of-sample error of its last rounds {error:.2g} nats, {verdict}")
    spread = info.get("emulator_spread")
    if spread:
        pooled = ""
        if spread.get("pooled"):
            by = pooled_words(spread)
            pooled = f" (their posteriors are pooled into the table above{', ' + by if by else ''})"
        print(f"emulator spread: {spread_words(spread)}{pooled}")
    for cid, b in info["bands"].items():
        if b["coverage90"] == b["coverage90"]:
            scores = "".join(f", {label} {b[key]:.3g} kN" for key, label in
                             (("width90_kN", "90 % width"), ("crps_kN", "CRPS"),
                              ("rmse_mean_kN", "predictive mean RMSE"))
                             if isinstance(b.get(key), (int, float)) and b[key] == b[key])
            print(f"coverage {cid}: 50 % band {b['coverage50']:.0%}, 90 % band {b['coverage90']:.0%}{scores}")
    # the warnings themselves were shown as the library emitted them
    rel = info.get("reliability") or {}
    verdict = "yes" if rel.get("reliable") else "no: " + "; ".join(rel.get("reasons") or [])
    print(f"reliable: {verdict}")
    for note in rel.get("notes") or []:
        print(f"note: {note}")
