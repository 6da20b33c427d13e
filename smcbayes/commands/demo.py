"""``smcbayes demo``: the whole loop on an embedded synthetic case, ending with a report.

The embedded project (``smcbayes/resources/demo.toml``) holds thesis-like press trials
and a ``[demo]`` table: the true parameters, an effect that is on in the truth but
withheld from the calibrated base model, the noise, and the budgets of the full and the
quick demo.  The demo closes the loop a user would follow on a press: calibrate the base
model (``OUT/run-base``), sample its posterior, diagnose the gap, calibrate again with the
effect the diagnosis names switched on (``OUT/run-effect``; read from the diagnosis'
summary, not from the ``[demo]`` table), sample that posterior, and write the reports,
the second with a before-and-after comparison of the two runs.

Each stage runs in this process through the same library calls as the command line, so
the command lines recorded in the report reproduce the run exactly; each stage's own
output goes to ``OUT/logs/<stage>.log`` and the terminal shows one line per stage with
its time.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import shlex
import time
import tomllib
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from smcbayes import api, progress
from smcbayes.config import build_project, load_project
from smcbayes.data.synth import NoiseSpec, to_toml, write_synthetic
from smcbayes.errors import ConfigError, SmcBayesError, SmcBayesWarning
from smcbayes.forward.model import ForwardModel
from smcbayes.report.document import fmt, pct
from smcbayes.run import read_json

DEMO_FILE = "demo.toml"
BASE_RUN, EFFECT_RUN = "run-base", "run-effect"
"""Run directories (inside the demo's output) of the base model and of the model with the
effect the diagnosis named."""
STAGES = ("synth", "calibrate", "posterior", "diagnose", "calibrate-effect", "posterior-effect",
          "report")


def embedded_text(name: str = DEMO_FILE) -> str:
    """Text of a project file shipped inside the package (works from a wheel)."""
    return resources.files("smcbayes.resources").joinpath(name).read_text(encoding="utf-8")


@dataclass(frozen=True)
class DemoPlan:
    """What one demo runs: the source project and the settings of each stage.

    Attributes:
        project: the project document (TOML as a dict, only the chosen configurations).
        effect: the effect on in the synthetic truth, off in the base model.
        truth: true parameter values in their named units (base and effect parameters).
        noise: ``synth`` noise options (``white_kN``, ``correlated_kN``, ``correlation_s``).
        seed: seed of the synthetic noise.
        stage: budgets (``budget``, ``init``, ``walkers``, ``steps``, ``functions``,
            ``draws``, ``population``, ``generations``, optional ``candidates``,
            ``emulator``, ``refine`` and ``correct_draws``, and ``effect_budget``,
            ``effect_init`` of the second calibration).
    """

    project: dict[str, Any]
    effect: str
    truth: dict[str, float]
    noise: dict[str, float]
    seed: int
    stage: dict[str, Any]


def load_plan(quick: bool) -> DemoPlan:
    """The embedded demo, full or quick."""
    raw = tomllib.loads(embedded_text(DEMO_FILE))
    demo = raw.pop("demo")
    stage = dict(demo["quick" if quick else "full"])
    ids = stage.pop("configurations")
    raw["configuration"] = [c for c in raw["configuration"] if c["id"] in ids]
    build_project(raw, f"<embedded {DEMO_FILE}>", Path.cwd())  # validate before any work
    return DemoPlan(
        raw,
        str(demo["effect"]),
        {k: float(v) for k, v in demo["truth"].items()},
        dict(demo["noise"]),
        int(demo["seed"]),
        stage,
    )


def named_effect(out: Path) -> str | None:
    """The effect the base run's diagnosis names (``None``: none, or no diagnosis yet)."""
    summary = read_json(out / BASE_RUN / "diagnose" / "summary.json")
    best = ((summary or {}).get("decision") or {}).get("best")
    return str(best) if best else None


def command_lines(plan: DemoPlan, out: Path, effect: str | None) -> dict[str, list[str]]:
    """The argument lists of every stage (``smcbayes`` omitted).

    Args:
        plan: the demo's plan.
        out: the demo's output folder.
        effect: the effect the diagnosis named; ``None`` leaves out the second calibration
            and its posterior.
    """
    s, n, q = plan.stage, plan.noise, shlex.quote
    data, base, eff = (q(str(out / name)) for name in ("data", BASE_RUN, EFFECT_RUN))
    project = q(str(out / "data" / "project.toml"))
    truth = " ".join(f"--truth {k}={v:g}" for k, v in plan.truth.items())
    posterior = (f"--walkers {s['walkers']} --steps {s['steps']} --functions {s['functions']} "
                 f"--draws {s['draws']} --seed 0")
    for key in ("emulator", "refine", "correct_draws"):
        if s.get(key) is not None:
            posterior += f" --{key.replace('_', '-')} {s[key]}"
    lines = {
        "synth": f"synth {q(str(out / 'demo-project.toml'))} --effect {plan.effect} "
        f"--seed {plan.seed} --noise-kN {n.get('white_kN', 0.0)} "
        f"--correlated-kN {n.get('correlated_kN', 0.0)} "
        f"--correlation-s {n.get('correlation_s', 1.0)} {truth} --out {data}",
        "calibrate": f"calibrate {project} --out {base} --budget {s['budget']} "
        f"--init {s['init']} --seed 0",
        "posterior": f"posterior {base} {posterior}",
        "diagnose": f"diagnose {base} --seed 0 --population {s['population']} "
        f"--generations {s['generations']} --out {q(str(out / BASE_RUN / 'diagnose'))}",
    }
    if s.get("candidates"):
        lines["diagnose"] += f" --effects {','.join(s['candidates'])}"
    if effect is not None:
        lines["calibrate-effect"] = (
            f"calibrate {project} --out {eff} --effect {q(effect)} "
            f"--budget {s['effect_budget']} --init {s['effect_init']} --seed 0"
        )
        lines["posterior-effect"] = f"posterior {eff} {posterior}"
    lines["report"] = f"report {base}"
    if effect is not None:
        lines["report-effect"] = f"report {eff}"
    return {stage: shlex.split(line) for stage, line in lines.items()}


@contextlib.contextmanager
def stage_log(path: Path) -> Iterator[None]:
    """Log records of a stage to its file, the terminal keeping one line per stage."""
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s: %(message)s"))
    root = logging.getLogger("smcbayes")
    quiet = [(h, h.level) for h in root.handlers]
    for h, _ in quiet:
        # one line per stage on the terminal (it counts the warnings); they are in the log
        h.setLevel(logging.ERROR)
    # also on the top logger, so that libraries logging through the module-level functions
    # (the corner plot's contour notes) write to the stage's log, not to the terminal; the
    # package's logger once more only if it does not pass its records up (the CLI's)
    loggers = [logging.getLogger()] + ([] if root.propagate else [root])
    for lg in loggers:
        lg.addHandler(handler)
    was_on = progress.enabled()
    progress.enable(True, interval_s=5.0)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", SmcBayesWarning)
            yield
        for w in caught:
            root.warning("warning: %s", w.message)
    finally:
        progress.enable(was_on)
        for lg in loggers:
            lg.removeHandler(handler)
        handler.close()
        for h, level in quiet:
            h.setLevel(level)


def run_stage(plan: DemoPlan, stage: str, out: Path) -> None:
    """Run one stage through the library, its log in ``out/logs/<stage>.log``.

    ``calibrate-effect`` switches on the effect named by the diagnosis of the base run;
    ``report`` writes the report of the base run and, if it exists, of the effect run.

    Raises:
        ConfigError: ``calibrate-effect`` without a named effect.
        SmcBayesError: the stage failed (message names the stage and its log).
    """
    s, base, eff = plan.stage, out / BASE_RUN, out / EFFECT_RUN
    log = out / "logs" / f"{stage}.log"
    posterior = {"walkers": s["walkers"], "steps": s["steps"], "functions": s["functions"],
                 "draws": s["draws"], "seed": 0}
    for key in ("emulator", "refine", "correct_draws"):
        if s.get(key) is not None:
            posterior[key] = s[key]
    try:
        with stage_log(log):
            if stage == "synth":
                synthesise(plan, out)
            elif stage == "calibrate":
                api.calibrate(out / "data" / "project.toml", base, budget=s["budget"],
                              init=s["init"], seed=0)
            elif stage == "posterior":
                api.sample_posterior(base, **posterior)
            elif stage == "diagnose":
                api.diagnose_gap(base, base / "diagnose", seed=0, population=s["population"],
                                 generations=s["generations"],
                                 effects=s.get("candidates") or None)
            elif stage == "calibrate-effect":
                effect = named_effect(out)
                if effect is None:
                    raise ConfigError("the diagnosis of the base run names no effect to switch on")
                api.calibrate(out / "data" / "project.toml", eff, effects=[effect],
                              budget=s["effect_budget"], init=s["effect_init"], seed=0)
            elif stage == "posterior-effect":
                api.sample_posterior(eff, **posterior)
            else:
                api.write_report(base)
                if (eff / "summary.json").is_file():
                    api.write_report(eff)
    except SmcBayesError as err:  # same class (exit code), with the stage and its log named
        raise type(err)(f"demo stage '{stage}': {err} (log: {log})") from err


def synthesise(plan: DemoPlan, out: Path) -> None:
    """The synthetic measured data (as ``smcbayes synth`` with the demo's truth and noise)."""
    project = load_project(out / "demo-project.toml")
    model = ForwardModel(project, effects=[plan.effect], overrides=plan.truth)
    n = plan.noise
    noise = NoiseSpec(white_kN=n.get("white_kN", 0.0), correlated_kN=n.get("correlated_kN", 0.0),
                      correlation_s=n.get("correlation_s", 1.0))
    write_synthetic(model, model.config_ids, noise, plan.seed, out / "data", plan.truth,
                    source=str(out / "demo-project.toml"))


def write_source(plan: DemoPlan, out: Path) -> None:
    """The demo's project file, so that ``synth`` can be re-run from the command line."""
    header = (
        "# Project of `smcbayes demo` (from the embedded demo.toml); the synthetic truth is\n"
        f"# given on the synth command line recorded in {BASE_RUN}/demo.json.\n"
    )
    (out / "demo-project.toml").write_text(header + to_toml(plan.project), encoding="utf-8")


def _write_records(out: Path, record: dict[str, Any]) -> None:
    """``demo.json`` in each run directory; the effect run's also names the base run (the
    report's before-and-after section reads it, by a path relative to the run)."""
    for name in (BASE_RUN, EFFECT_RUN):
        if (out / name).is_dir():
            rec = dict(record, compare_with=f"../{BASE_RUN}") if name == EFFECT_RUN else record
            (out / name / "demo.json").write_text(json.dumps(rec, indent=2) + "\n",
                                                  encoding="utf-8")


def run_demo(out: Path, quick: bool, echo: Callable[[str], None] = print) -> Path:
    """Run every stage into ``out``; returns the path of the final HTML report.

    The final report is that of the effect run (``OUT/run-effect/report.html``), or of the
    base run when the diagnosis names no effect.

    Raises:
        ConfigError: ``out`` is not empty, or a stage fails (its log is named).
    """
    if out.exists() and any(out.iterdir()):
        raise ConfigError(f"{out}: exists and is not empty; choose another --out or remove it")
    plan = load_plan(quick)
    (out / "logs").mkdir(parents=True, exist_ok=True)
    write_source(plan, out)
    ids = [c["id"] for c in plan.project["configuration"]]
    echo(
        f"smcbayes demo ({'quick' if quick else 'full'}): {len(ids)} configurations, truth with "
        f"{plan.effect} on, base model without it; output in {out}"
    )
    timings: dict[str, float] = {}
    record: dict[str, Any] = {
        "mode": "quick" if quick else "full",
        "effect_withheld": plan.effect,
        "effect_named": None,
        "runs": {"before": BASE_RUN, "after": None},
        "commands": [],
        "timings_s": timings,
    }
    start = time.perf_counter()
    for k, stage in enumerate(STAGES, 1):
        effect = named_effect(out)
        if stage in ("calibrate-effect", "posterior-effect") and effect is None:
            echo(f"[{k}/{len(STAGES)}] {stage:<16} skipped: the diagnosis names no effect")
            continue
        if stage == "report":  # the report shows the commands and the times of the stages
            record["effect_named"] = effect
            record["runs"]["after"] = EFFECT_RUN if effect is not None else None
            commands = command_lines(plan, out, effect)
            record["commands"] = ["smcbayes " + shlex.join(c) for c in commands.values()]
            _write_records(out, record)
        t0 = time.perf_counter()
        echo(f"[{k}/{len(STAGES)}] {stage:<16} ...")
        run_stage(plan, stage, out)
        timings[stage] = time.perf_counter() - t0
        note = _stage_note(stage, out)
        echo(f"[{k}/{len(STAGES)}] {stage:<16} done in {timings[stage]:.1f} s{note}")
    timings["total"] = time.perf_counter() - start
    _write_records(out, record)
    final = out / (EFFECT_RUN if (out / EFFECT_RUN / "report.html").is_file() else BASE_RUN)
    return final / "report.html"


def _stage_note(stage: str, out: Path) -> str:
    """A short result of the stage for the progress line."""
    run = out / (EFFECT_RUN if stage.endswith("-effect") else BASE_RUN)
    if stage.startswith("calibrate") and (s := read_json(run / "summary.json")):
        on = ", ".join(s.get("effects") or []) or "no effect"
        return f": {on} on, best loss {fmt(s.get('best_loss_kN2'))} kN^2"
    if stage.startswith("posterior") and (s := read_json(run / "posterior" / "summary.json")):
        cov = ", ".join(pct(b.get("coverage90")) for b in (s.get("bands") or {}).values())
        return f": {len(s.get('warnings') or [])} warning(s), 90 % band coverage {cov or '-'}"
    if stage == "diagnose" and (s := read_json(run / "diagnose" / "summary.json")):
        best = (s.get("decision") or {}).get("best")
        return f": names {best or 'no effect'}"
    return ""


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    p = sub.add_parser(
        "demo",
        help="run the whole loop on an embedded synthetic case and write a report",
        description="Write synthetic press data from the embedded demo project (thesis-like "
        "bar and centre charges at 0.3/0.7/1.1 mm/s, an effect on in the truth and "
        "withheld from the base model), then calibrate the base model (OUT/run-base), "
        "sample its posterior with predictive bands on the held-out configurations, "
        "diagnose the gap, calibrate again with the effect the diagnosis names "
        "(OUT/run-effect), sample that posterior and write the reports; "
        "OUT/run-effect/report.html compares before and after. About 3 minutes; --quick "
        "under a minute.",
    )
    p.add_argument(
        "--out",
        default="smcbayes-demo",
        metavar="DIR",
        help="output directory, new or empty (default: ./smcbayes-demo)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="7 configurations and small budgets (a smoke test of the loop)",
    )
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``demo``."""
    start = time.perf_counter()
    report = run_demo(Path(args.out), args.quick)
    print(
        f"report: {report} (Markdown twin: {report.with_suffix('.md')}); "
        f"total {time.perf_counter() - start:.1f} s"
    )
    return 0
