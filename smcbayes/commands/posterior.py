"""``smcbayes posterior``: sample the emulated posterior of a calibration run."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    # the correction module is light (numpy, scipy); the stage would pull in torch
    from smcbayes.posterior.correct import CorrectionSettings

    p = sub.add_parser(
        "posterior", help="posterior of the parameters from a calibration run (GP emulator + emcee)",
        description="Reuse the calibration's GP as an emulator of the likelihood, sample it with "
                    "emcee (a mixture over GP sample functions, so the emulator's uncertainty "
                    "widens the posterior), correct it by adaptive importance sampling with the "
                    "forward model (Pareto-smoothed weights, k-hat reported), and write RUN_DIR/posterior/: posterior.nc (arviz), "
                    "summary table, correlations, corner plot, and predictive bands with coverage "
                    "on the validation configurations.")
    p.add_argument("run_dir", help="directory of a `smcbayes calibrate` run")
    p.add_argument("--walkers", type=int, default=32, help="emcee walkers (default 32)")
    p.add_argument("--steps", type=int, default=4000, help="maximum steps per chain (default 4000)")
    p.add_argument("--functions", type=int, default=8,
                   help="GP sample functions in the mixture (default 8; 0 = GP mean only)")
    p.add_argument("--refine", type=int, default=0, metavar="N",
                   help="forward evaluations where the posterior is probable and the GP unsure")
    p.add_argument("--draws", type=int, default=100,
                   help="posterior draws through the forward model for bands and checks")
    p.add_argument("--correct-draws", type=int, default=CorrectionSettings.draws, metavar="D",
                   help="most proposal draws (each inside the prior box costs a forward evaluation) of the "
                        "importance-sampling correction of the emulated posterior; it stops earlier once "
                        f"the importance ESS >= {CorrectionSettings.ess_target:.0f} and the Pareto k-hat "
                        f"<= {CorrectionSettings.k_target} (default {CorrectionSettings.draws}; "
                        "0 reports the emulated posterior uncorrected)")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``posterior``."""
    from smcbayes.errors import ConfigError
    from smcbayes.posterior.stage import PosteriorSettings, run_posterior

    for name in ("walkers", "steps", "draws"):
        if getattr(args, name) < 1:
            raise ConfigError(f"--{name} must be >= 1, got {getattr(args, name)}")
    if args.refine < 0 or args.functions < 0 or args.correct_draws < 0:
        raise ConfigError("--refine, --functions and --correct-draws must be >= 0")
    settings = PosteriorSettings(args.walkers, args.steps, args.functions, args.refine,
                                 args.draws, args.seed, correct_draws=args.correct_draws)
    info = run_posterior(Path(args.run_dir), settings)
    print_summary(info)
    print(f"posterior: {Path(args.run_dir) / 'posterior'} (posterior.nc, summary.csv, figures/)")
    return 0


def print_summary(info: dict) -> None:
    """The summary table, strongest correlations, emulator check, coverage and warnings."""
    print(f"{'parameter':<24}{'mean':>11}{'sd':>11}{'5%':>11}{'50%':>11}{'95%':>11}{'R-hat':>8}{'ESS':>8}")
    for s in info["parameters"]:
        name = f"{s['name']} ({s['unit']})" if s["unit"] != "-" else s["name"]
        print(f"{name:<24}" + "".join(f"{s[k]:>11.4g}" for k in ("mean", "sd", "q05", "q50", "q95"))
              + f"{s['r_hat']:>8.3f}{s['ess']:>8.0f}")
    for pair in info["correlation"]["strongest"]:
        print(f"correlated: {pair['a']} - {pair['b']}: r = {pair['r']:+.2f}")
    corr = info.get("correction") or {}
    if corr.get("enabled"):
        print(f"importance correction: {corr['evaluations']} forward evaluations, Pareto k-hat "
              f"{corr['k_hat']:.2f}, importance ESS {corr['ess']:.0f} (table above: corrected posterior; "
              "emulator-only table in summary_emulator.csv)")
    ec = info["emulator_check"]
    print(f"emulator check at {ec['points']} posterior draws: log-likelihood error "
          f"mean |e| {ec['mean_abs_error']:.3g} nats, max {ec['max_abs_error']:.3g} nats")
    for cid, b in info["bands"].items():
        if b["coverage90"] == b["coverage90"]:
            print(f"coverage {cid}: 50 % band {b['coverage50']:.0%}, 90 % band {b['coverage90']:.0%}")
    for w in info["warnings"]:
        print(f"warning: {w}")
