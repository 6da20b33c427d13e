"""``smcbayes calibrate``: Bayesian optimisation of the parameters to the loss minimum."""

from __future__ import annotations

import argparse
from collections import Counter

from smcbayes.commands.common import add_executor_options, add_model_options
from smcbayes.config import CalibrationSpec, ProjectConfig, help_of, load_project, override, parse_assignments
from smcbayes.errors import ConfigError, SolverError
from smcbayes.run import RunDir, RunIdentity
from smcbayes.simulation.executors.base import make_executor
from smcbayes.simulation.problem import ExternalSpec, build_problem


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    p = sub.add_parser(
        "calibrate", help="Bayesian optimisation of the parameters against measured curves",
        description="Calibrate the free parameters on the training configurations: a Latin "
                    "hypercube design, then a Gaussian process on log(loss) and (q)LogEI "
                    "candidates until the budget or the tolerance rule stops. Every "
                    "evaluation is logged as it finishes; --resume continues a killed run. "
                    "Settings come from the config's [calibration] table; the options below override it "
                    "(the defaults shown apply when the table does not set them).")
    p.add_argument("config", help="project TOML file (e.g. configs/thesis.toml)")
    p.add_argument("--out", required=True, metavar="RUN_DIR", help="run directory")
    p.add_argument("--budget", type=int, default=None, help=help_of(CalibrationSpec, "budget"))
    p.add_argument("--init", type=int, default=None, help=help_of(CalibrationSpec, "init"))
    p.add_argument("--batch", type=int, default=None, metavar="Q", help=help_of(CalibrationSpec, "batch"))
    p.add_argument("--kernel", choices=("rbf", "matern52"), default=None,
                   help=f"GP kernel (default {CalibrationSpec().kernel})")
    p.add_argument("--tolerance", type=float, default=None, help=help_of(CalibrationSpec, "tolerance"))
    p.add_argument("--patience", type=int, default=None, help=help_of(CalibrationSpec, "patience"))
    p.add_argument("--seed", type=int, default=None, help=help_of(CalibrationSpec, "seed"))
    add_executor_options(p)
    p.add_argument("--resume", action="store_true",
                   help="continue the run in RUN_DIR with its own settings (only --budget and "
                        "--tolerance may change them)")
    p.add_argument("--external", metavar="COMMAND", default=None,
                   help="external simulator command template with {params} {output} {config} "
                        "{workdir}, e.g. \"python sim.py {params} {output}\"")
    p.add_argument("--external-timeout", type=float, default=ExternalSpec.timeout_s, metavar="S",
                   help="time limit of one external run (s)")
    p.add_argument("--external-format", choices=("csv", "moldflow"), default=ExternalSpec.output_format,
                   help="what the external command writes to {output}")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    add_model_options(p)
    p.set_defaults(run=run)


FIELDS = ("budget", "init", "batch", "kernel", "tolerance", "patience", "seed")
RESUME_FIELDS = ("budget", "tolerance")
"""What ``--resume`` may change: the run's other settings are its own."""


def settings_from(project: ProjectConfig, args: argparse.Namespace, run_dir: RunDir) -> CalibrationSpec:
    """The calibration's settings, validated: the config's ``[calibration]`` table with the
    command-line overrides, or on ``--resume`` the run's own settings with only ``--budget``
    and ``--tolerance`` changed (any other option given must agree with the run)."""
    given = {k: getattr(args, k) for k in FIELDS}
    if args.resume and run_dir.is_run():
        recorded = {k: v for k, v in run_dir.identity().settings.items() if k in CalibrationSpec.model_fields}
        base = override(project.calibration, recorded, source=str(run_dir.root / "config.json"))
        for key in FIELDS:
            if key not in RESUME_FIELDS and given[key] is not None and given[key] != getattr(base, key):
                raise ConfigError(f"--{key} {given[key]}: the run in {run_dir.root} was started with "
                                  f"{key} = {getattr(base, key)}; --resume changes only --budget and "
                                  "--tolerance (drop the option, or start a new run with another --out)")
        settings = override(base, {k: given[k] for k in RESUME_FIELDS})
    else:
        settings = override(project.calibration, given)
    settings.check()
    return settings


def run(args: argparse.Namespace) -> int:
    """Execute ``calibrate``."""
    # torch loads here, not at start-up: `smcbayes --help` and `simulate` stay quick
    from smcbayes.surrogate.calibration import calibrate

    project = load_project(args.config, args.data_dir)
    overrides = parse_assignments(args.set)
    run_dir = RunDir(args.out)
    settings = settings_from(project, args, run_dir)
    external = None
    if args.external:
        external = ExternalSpec(args.external, args.external_timeout, args.external_format)
    identity = RunIdentity(project.model_dump(mode="json"), args.effect, overrides, args.fidelity,
                           None if external is None else vars(external).copy(),
                           settings.model_dump(mode="json", exclude={"truth"}))
    run_dir.prepare(identity, args.resume)
    run_dir.record_command("calibrate", args.argv)
    problem = build_problem(project, run_dir.root, args.effect, overrides, args.fidelity, external,
                            reuse_truth=args.resume)
    executor = make_executor(args.workers, args.scheduler)
    space = problem.space
    print(f"calibrating {', '.join(space.free_names)} on {len(problem.train_ids)} configuration(s); "
          f"budget {settings.budget} ({settings.init} initial), batch {settings.batch}, "
          f"kernel {settings.kernel}, seed {settings.seed}")
    info = calibrate(problem, settings, run_dir, executor, figures=not args.no_figures)
    print(f"stopped: {info['stop_reason']}; {info['evaluations']} evaluations, "
          f"{info['failures']} failed, {info['seconds_wall']:.1f} s")
    if not info["best_params"]:
        reasons = Counter(r["reason"] for r in info.get("failure_reasons") or [])
        common = f" (most often: {reasons.most_common(1)[0][0]})" if reasons else ""
        raise SolverError(f"every evaluation failed{common}; reasons per evaluation in "
                          f"{run_dir.log_path}")
    if info["best_params"]:
        print(f"best loss {info['best_loss_kN2']:.6g} kN^2 at evaluation {info['best_index']}:")
        for name, v in info["best_params"].items():
            print(f"  {name:<14}{v['value']:>14.6g} {v['unit']}{'  (fixed)' if v['fixed'] else ''}")
    print(f"run directory: {run_dir.root} (summary.json, evaluations.jsonl, figures/)")
    return 0
