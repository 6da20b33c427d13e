"""``smcbayes calibrate``: Bayesian optimisation of the parameters to the loss minimum."""

from __future__ import annotations

import argparse
import json
import re
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

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
                    "(the defaults shown apply when the table does not set them). On --resume the "
                    "settings are the run's own (config.json in RUN_DIR): only --budget, "
                    "--tolerance and --polish change them, e.g. "
                    "`smcbayes calibrate --out RUN --resume --budget 120`. "
                    "With the built-in 1-D model a local search on the model itself (Powell's method, "
                    "--polish evaluations) then refines the best point.")
    p.add_argument("config", nargs="?", default=None,
                   help="project TOML file (e.g. configs/thesis.toml); with --resume it may be left "
                        "out: the run's recorded project and data directory are used")
    p.add_argument("--out", required=True, metavar="RUN_DIR", help="run directory")
    p.add_argument("--budget", type=int, default=None, help=help_of(CalibrationSpec, "budget"))
    p.add_argument("--init", type=int, default=None, help=help_of(CalibrationSpec, "init"))
    p.add_argument("--batch", type=int, default=None, metavar="Q", help=help_of(CalibrationSpec, "batch"))
    p.add_argument("--kernel", choices=("rbf", "matern52"), default=None,
                   help=f"GP kernel (default {CalibrationSpec().kernel})")
    p.add_argument("--tolerance", type=float, default=None, help=help_of(CalibrationSpec, "tolerance"))
    p.add_argument("--patience", type=int, default=None, help=help_of(CalibrationSpec, "patience"))
    p.add_argument("--seed", type=int, default=None, help=help_of(CalibrationSpec, "seed"))
    p.add_argument("--polish", type=int, default=None, metavar="N", help=help_of(CalibrationSpec, "polish"))
    add_executor_options(p)
    p.add_argument("--resume", action="store_true",
                   help="continue the run in RUN_DIR with its own settings (only --budget, "
                        "--tolerance and --polish may change them; any other option "
                        "given must agree with the "
                        "run); CONFIG may then be left out")
    p.add_argument("--external", metavar="COMMAND", default=None,
                   help="external simulator command template with {params} {output} {config} "
                        "{workdir}, e.g. \"python sim.py {params} {output}\"")
    p.add_argument("--external-timeout", type=float, default=ExternalSpec.timeout_s, metavar="S",
                   help="time limit of one external run (s)")
    p.add_argument("--external-format", choices=("csv", "moldflow"), default=ExternalSpec.output_format,
                   help="what the external command writes to {output}")
    p.add_argument("--external-file", action="append", metavar="PATH", default=None,
                   help="a file the external simulator's results depend on (its script, study, "
                        "mesh or material file, not one it writes; repeat for several): the run "
                        "records its absolute path and contents; once they change, the old "
                        "solver's runs are not reused and a --resume is refused (the command "
                        "line alone cannot tell); the file must stay at that path for the "
                        "later stages")
    p.add_argument("--effects-from", metavar="DIAGNOSIS_DIR", default=None,
                   help="switch on the effect set a diagnosis selected (the --out folder of "
                        "`smcbayes diagnose`, or its summary.json); adds to any --effect")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    add_model_options(p)
    p.set_defaults(run=run)


def selected_effects(path: str) -> list[str]:
    """The effect set a diagnosis selected (``selected_effects`` of its summary.json).

    Raises:
        ConfigError: no diagnosis summary there, one written before effect sets were
            selected, or a diagnosis that selected nothing.
    """
    summary_path = Path(path)
    if summary_path.is_dir():
        summary_path = summary_path / "summary.json"
    if not summary_path.is_file():
        raise ConfigError(f"--effects-from {path}: no diagnosis summary.json there; run "
                          "`smcbayes diagnose RUN --out DIR` first and pass DIR")
    try:
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ConfigError(f"--effects-from {path}: {summary_path} "
                          f"is not a diagnosis summary ({err})") from err
    if not isinstance(summary, dict) or "selected_effects" not in summary:
        raise ConfigError(f"--effects-from {path}: {summary_path} records no selected effect set; "
                          "run the diagnosis again with this version")
    chosen = [str(e) for e in summary["selected_effects"] or []]
    if not chosen:
        raise ConfigError(f"--effects-from {path}: the diagnosis selected no effect "
                          f"({(summary.get('decision') or {}).get('statement', 'nothing significant')})")
    return chosen


FIELDS = ("budget", "init", "batch", "kernel", "tolerance", "patience", "seed", "polish")


def settings_from(project: ProjectConfig, args: argparse.Namespace, run_dir: RunDir) -> CalibrationSpec:
    """The calibration's settings, validated: the config's ``[calibration]`` table with the
    command-line overrides, or on ``--resume`` the run's own settings with only ``--budget``
    and ``--tolerance`` changed (any other option given must agree with the run)."""
    given = {k: getattr(args, k) for k in FIELDS}
    if args.resume and run_dir.is_run():
        settings = run_dir.resumed_settings(project.calibration, given)
    else:
        settings = override(project.calibration, given)
    settings.check()
    return settings


def _model_of_run(args: argparse.Namespace, run_dir: RunDir) -> tuple[
        ProjectConfig, list[str] | None, dict[str, float], str | None, ExternalSpec | None]:
    """Project, effects, fixed values, fidelity and external simulator of a bare ``--resume``
    (no CONFIG): the run's recorded ones, with what the command line gives instead (which
    :meth:`RunDir.prepare` then checks against the run)."""
    if not args.resume:
        raise ConfigError("CONFIG (the project TOML file) is missing, e.g. smcbayes calibrate "
                          "configs/thesis.toml --out RUN; only --resume may leave it out")
    recorded = run_dir.require_resumable()
    project = recorded.project_config()
    if args.data_dir is not None:
        project = project.model_copy(update={"data_dir": str(Path(args.data_dir).resolve())})
    # --external-file alone is refused by _external_spec, not dropped
    external = (_external_spec(args) if args.external or args.external_file
                else ExternalSpec(**recorded.external) if recorded.external else None)
    return (project, recorded.effects if args.effect is None else args.effect,
            parse_assignments(args.set) if args.set else dict(recorded.overrides),
            recorded.fidelity if args.fidelity is None else args.fidelity, external)


def _external_spec(args: argparse.Namespace) -> ExternalSpec | None:
    """The external simulator the command line gives (``None`` without ``--external``).

    Raises:
        ConfigError: ``--external-file`` without ``--external``, or naming no file.
    """
    if not args.external:
        if args.external_file:
            raise ConfigError("--external-file names a file of the external simulator: give "
                              "--external COMMAND too")
        return None
    spec = ExternalSpec(args.external, args.external_timeout, args.external_format,
                        tuple(args.external_file or ()))
    if spec.missing():
        raise ConfigError(f"--external-file {', '.join(spec.missing())}: no such file")
    return spec


def most_frequent_failure(info: Mapping[str, Any]) -> str:
    """`` (most often, N of M configuration runs: REASON)`` from a calibration summary, or ``""``.

    An evaluation's reason joins one ``"<config id>: <reason>"`` per failed configuration
    with ``"; "``; the reasons are counted without the ids, so that the same failure on
    several configurations counts as one kind."""
    ids = sorted(map(str, info.get("config_ids") or []), key=len, reverse=True)
    # split before "<id>: " only, since a reason itself may hold "; " (an external stderr)
    split = re.compile("; (?=(?:" + "|".join(map(re.escape, ids)) + "): )") if ids else re.compile("; ")
    strip = re.compile("^(?:" + "|".join(map(re.escape, ids)) + "): ") if ids else re.compile("^$")
    parts = [strip.sub("", part) for r in info.get("failure_reasons") or [] if r.get("reason")
             for part in split.split(str(r["reason"]))]
    if not parts:
        return ""
    reason, count = Counter(parts).most_common(1)[0]
    return f" (most often, {count} of {len(parts)} configuration runs: {reason})"


def run(args: argparse.Namespace) -> int:
    """Execute ``calibrate``."""
    # torch loads here, not at start-up: `smcbayes --help` and `simulate` stay quick
    from smcbayes.surrogate.calibration import calibrate

    run_dir = RunDir(args.out)
    if args.config is None:
        project, effects, overrides, fidelity, external = _model_of_run(args, run_dir)
    else:
        project = load_project(args.config, args.data_dir)
        effects, overrides, fidelity = args.effect, parse_assignments(args.set), args.fidelity
        if args.effects_from is not None:
            effects = list(dict.fromkeys([*(effects or []), *selected_effects(args.effects_from)]))
        external = _external_spec(args)
    settings = settings_from(project, args, run_dir)
    identity = RunIdentity(project.model_dump(mode="json"), effects, overrides, fidelity,
                           None if external is None else external.to_json(),
                           settings.model_dump(mode="json", exclude={"truth"}))
    run_dir.prepare(identity, args.resume)
    run_dir.record_command("calibrate", args.argv)
    problem = build_problem(project, run_dir.root, effects, overrides, fidelity, external,
                            reuse_truth=args.resume)
    executor = make_executor(args.workers, args.scheduler)
    space = problem.space
    polish = settings.polish_evaluations(problem.fast)
    local = f", then a local search of up to {polish} evaluations" if polish else ""
    print(f"calibrating {', '.join(space.free_names)} on {len(problem.train_ids)} configuration(s); "
          f"budget {settings.budget} ({settings.init} initial), batch {settings.batch}, "
          f"kernel {settings.kernel}, seed {settings.seed}{local}")
    info = calibrate(problem, settings, run_dir, executor, figures=not args.no_figures)
    print(f"stopped: {info['stop_reason']}; {info['evaluations']} evaluations, "
          f"{info['failures']} failed, {info['seconds_wall']:.1f} s")
    if not info["best_params"]:
        raise SolverError(f"every evaluation failed{most_frequent_failure(info)}; the reason of each "
                          f"is in {run_dir.log_path}")
    if info["best_params"]:
        print(f"best loss {info['best_loss_kN2']:.6g} kN^2 at evaluation {info['best_index']}:")
        for name, v in info["best_params"].items():
            print(f"  {name:<14}{v['value']:>14.6g} {v['unit']}{'  (fixed)' if v['fixed'] else ''}")
    print(f"run directory: {run_dir.root} (summary.json, evaluations.jsonl, figures/)")
    return 0
