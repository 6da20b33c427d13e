"""``smcbayes calibrate``: Bayesian optimisation of the parameters to the loss minimum."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from smcbayes.commands.common import add_model_options
from smcbayes.config import ProjectConfig, load_project, parse_assignments


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    p = sub.add_parser(
        "calibrate", help="Bayesian optimisation of the parameters against measured curves",
        description="Calibrate the free parameters on the training configurations: a Latin "
                    "hypercube design, then a Gaussian process on log(loss) and (q)LogEI "
                    "candidates until the budget or the tolerance rule stops. Every "
                    "evaluation is logged as it finishes; --resume continues a killed run. "
                    "Defaults come from the config's [calibration] table.")
    p.add_argument("config", help="project TOML file (e.g. configs/thesis.toml)")
    p.add_argument("--out", required=True, metavar="RUN_DIR", help="run directory")
    p.add_argument("--budget", type=int, default=None, help="total evaluations incl. the initial design")
    p.add_argument("--init", type=int, default=None, help="Latin hypercube points")
    p.add_argument("--batch", type=int, default=None, metavar="Q", help="candidates per round (qLogEI if > 1)")
    p.add_argument("--kernel", choices=("rbf", "matern52"), default=None, help="GP kernel")
    p.add_argument("--tolerance", type=float, default=None,
                   help="stop when the best loss improves by less than this fraction over --patience rounds")
    p.add_argument("--patience", type=int, default=None, help="rounds of the tolerance rule")
    p.add_argument("--seed", type=int, default=None, help="random seed (same seed, same run)")
    p.add_argument("--workers", type=int, default=1, help="local worker processes (default 1)")
    p.add_argument("--scheduler", metavar="ADDR", default=None,
                   help="Dask scheduler address (tcp://host:8786): evaluate on a cluster")
    p.add_argument("--resume", action="store_true", help="continue the run in RUN_DIR")
    p.add_argument("--external", metavar="COMMAND", default=None,
                   help="external simulator command template with {params} {output} {config} "
                        "{workdir}, e.g. \"python sim.py {params} {output}\"")
    p.add_argument("--external-timeout", type=float, default=3600.0, metavar="S",
                   help="time limit of one external run (s)")
    p.add_argument("--external-format", choices=("csv", "moldflow"), default="csv",
                   help="what the external command writes to {output}")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    add_model_options(p)
    p.set_defaults(run=run)


def settings_from(project: ProjectConfig, args: argparse.Namespace) -> Any:
    """Loop settings: the config's [calibration] table with command-line overrides."""
    from smcbayes.surrogate.loop import BOSettings

    c = project.calibration
    pick = {k: getattr(args, k) if getattr(args, k) is not None else getattr(c, k)
            for k in ("budget", "init", "batch", "kernel", "tolerance", "patience", "seed")}
    settings = BOSettings(**pick, failed=c.failed, restarts=c.restarts, raw_samples=c.raw_samples,
                          noise=None if c.noise == "fit" else float(c.noise),
                          local_evaluations=c.local_evaluations, local_radius=c.local_radius)
    settings.check()
    return settings


def run(args: argparse.Namespace) -> int:
    """Execute ``calibrate``."""
    from smcbayes.simulation.executors.base import make_executor
    from smcbayes.simulation.problem import ExternalSpec, build_problem
    from smcbayes.surrogate.rundir import calibrate, prepare

    project = load_project(args.config, args.data_dir)
    overrides = parse_assignments(args.set)
    settings = settings_from(project, args)
    external = None
    if args.external:
        external = ExternalSpec(args.external, args.external_timeout, args.external_format)
    run_dir = Path(args.out)
    identity = {"project": project.model_dump(mode="json"), "effects": args.effect,
                "overrides": overrides, "fidelity": args.fidelity,
                "external": None if external is None else vars(external).copy(),
                **{k: v for k, v in vars(settings).items()}}
    prepare(run_dir, identity, args.resume)
    problem = build_problem(project, run_dir, args.effect, overrides, args.fidelity, external)
    executor = make_executor(args.workers, args.scheduler)
    space = problem.model.space
    print(f"calibrating {', '.join(space.free_names)} on {len(problem.train_ids)} configuration(s); "
          f"budget {settings.budget} ({settings.init} initial), batch {settings.batch}, "
          f"kernel {settings.kernel}, seed {settings.seed}")
    info = calibrate(problem, settings, run_dir, executor, figures=not args.no_figures)
    print(f"stopped: {info['stop_reason']}; {info['evaluations']} evaluations, "
          f"{info['failures']} failed, {info['seconds_wall']:.1f} s")
    if info["best_params"]:
        print(f"best loss {info['best_loss_kN2']:.6g} kN^2 at evaluation {info['best_index']}:")
        for name, v in info["best_params"].items():
            print(f"  {name:<14}{v['value']:>14.6g} {v['unit']}{'  (fixed)' if v['fixed'] else ''}")
    print(f"run directory: {run_dir} (summary.json, evaluations.jsonl, figures/)")
    return 0
