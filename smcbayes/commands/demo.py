"""``smcbayes demo``: the whole chain on an embedded synthetic case, ending with a report.

The embedded project (``smcbayes/resources/demo.toml``) holds thesis-like press trials
and a ``[demo]`` table: the true parameters, an effect that is on in the truth but
withheld from the calibrated base model, the noise, and the budgets of the full and the
quick demo.  Each stage runs in this process through the same command-line parser a user
types, so the command lines recorded in the report reproduce the run exactly; each
stage's own output goes to ``OUT/logs/<stage>.log`` and the terminal shows one line per
stage with its time.
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
STAGES = ("synth", "calibrate", "posterior", "diagnose", "report")


def embedded_text(name: str = DEMO_FILE) -> str:
    """Text of a project file shipped inside the package (works from a wheel)."""
    return resources.files("smcbayes.resources").joinpath(name).read_text(encoding="utf-8")


@dataclass(frozen=True)
class DemoPlan:
    """What one demo runs: the source project and the settings of each stage.

    Attributes:
        project: the project document (TOML as a dict, only the chosen configurations).
        effect: the effect on in the synthetic truth, off in the calibrated model.
        truth: true parameter values in their named units (base and effect parameters).
        noise: ``synth`` noise options (``white_kN``, ``correlated_kN``, ``correlation_s``).
        seed: seed of the synthetic noise.
        stage: budgets (``budget``, ``init``, ``walkers``, ``steps``, ``functions``,
            ``draws``, ``population``, ``generations`` and optional ``candidates``).
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


def command_lines(plan: DemoPlan, out: Path) -> dict[str, list[str]]:
    """The argument lists of every stage (``smcbayes`` omitted)."""
    s, n, q = plan.stage, plan.noise, shlex.quote
    data, run = q(str(out / "data")), q(str(out / "run"))
    truth = " ".join(f"--truth {k}={v:g}" for k, v in plan.truth.items())
    lines = {
        "synth": f"synth {q(str(out / 'demo-project.toml'))} --effect {plan.effect} "
        f"--seed {plan.seed} --noise-kN {n.get('white_kN', 0.0)} "
        f"--correlated-kN {n.get('correlated_kN', 0.0)} "
        f"--correlation-s {n.get('correlation_s', 1.0)} {truth} --out {data}",
        "calibrate": f"calibrate {q(str(out / 'data' / 'project.toml'))} --out {run} "
        f"--budget {s['budget']} --init {s['init']} --seed 0",
        "posterior": f"posterior {run} --walkers {s['walkers']} --steps {s['steps']} "
        f"--functions {s['functions']} --draws {s['draws']} --seed 0",
        "diagnose": f"diagnose {run} --seed 0 --population {s['population']} "
        f"--generations {s['generations']} --out {q(str(out / 'run' / 'diagnose'))}",
        "report": f"report {run}",
    }
    if s.get("candidates"):
        lines["diagnose"] += f" --effects {','.join(s['candidates'])}"
    return {stage: shlex.split(line) for stage, line in lines.items()}


@contextlib.contextmanager
def stage_log(path: Path) -> Iterator[None]:
    """Log records of a stage to its file, the terminal keeping one line per stage."""
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s: %(message)s"))
    root = logging.getLogger("smcbayes")
    quiet = [(h, h.level) for h in root.handlers]
    for h, _ in quiet:
        h.setLevel(logging.WARNING)
    root.addHandler(handler)
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
        root.removeHandler(handler)
        handler.close()
        for h, level in quiet:
            h.setLevel(level)


def run_stage(plan: DemoPlan, stage: str, out: Path) -> None:
    """Run one stage through the library, its log in ``out/logs/<stage>.log``."""
    s, run = plan.stage, out / "run"
    log = out / "logs" / f"{stage}.log"
    try:
        with stage_log(log):
            if stage == "synth":
                synthesise(plan, out)
            elif stage == "calibrate":
                api.calibrate(out / "data" / "project.toml", run, budget=s["budget"], init=s["init"], seed=0)
            elif stage == "posterior":
                api.sample_posterior(run, walkers=s["walkers"], steps=s["steps"], functions=s["functions"],
                              draws=s["draws"], seed=0)
            elif stage == "diagnose":
                api.diagnose_gap(run, run / "diagnose", seed=0, population=s["population"],
                             generations=s["generations"], effects=s.get("candidates") or None)
            else:
                api.write_report(run)
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
        "# given on the synth command line recorded in run/demo.json.\n"
    )
    (out / "demo-project.toml").write_text(header + to_toml(plan.project), encoding="utf-8")


def run_demo(out: Path, quick: bool, echo: Callable[[str], None] = print) -> Path:
    """Run every stage into ``out``; returns the path of the HTML report.

    Raises:
        ConfigError: ``out`` is not empty, or a stage fails (its log is named).
    """
    if out.exists() and any(out.iterdir()):
        raise ConfigError(f"{out}: exists and is not empty; choose another --out or remove it")
    plan = load_plan(quick)
    (out / "logs").mkdir(parents=True, exist_ok=True)
    write_source(plan, out)
    commands = command_lines(plan, out)
    ids = [c["id"] for c in plan.project["configuration"]]
    echo(
        f"smcbayes demo ({'quick' if quick else 'full'}): {len(ids)} configurations, truth with "
        f"{plan.effect} on, calibrated model without it; output in {out}"
    )
    timings: dict[str, float] = {}
    record = {
        "mode": "quick" if quick else "full",
        "effect_withheld": plan.effect,
        "commands": ["smcbayes " + shlex.join(c) for c in commands.values()],
        "timings_s": timings,
    }
    start = time.perf_counter()
    for k, stage in enumerate(STAGES, 1):
        if stage == "report":  # the report shows the commands and the times of the stages
            (out / "run" / "demo.json").write_text(
                json.dumps(record, indent=2) + "\n", encoding="utf-8"
            )
        t0 = time.perf_counter()
        echo(f"[{k}/{len(STAGES)}] {stage:<9} ...")
        run_stage(plan, stage, out)
        timings[stage] = time.perf_counter() - t0
        note = _stage_note(stage, out)
        echo(f"[{k}/{len(STAGES)}] {stage:<9} done in {timings[stage]:.1f} s{note}")
    timings["total"] = time.perf_counter() - start
    (out / "run" / "demo.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return out / "run" / "report.html"


def _stage_note(stage: str, out: Path) -> str:
    """A short result of the stage for the progress line."""
    run = out / "run"
    if stage == "calibrate" and (s := read_json(run / "summary.json")):
        return f": best loss {fmt(s.get('best_loss_kN2'))} kN^2"
    if stage == "posterior" and (s := read_json(run / "posterior" / "summary.json")):
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
        help="run the whole chain on an embedded synthetic case and write a report",
        description="Write synthetic press data from the embedded demo project (thesis-like "
        "bar and centre charges at 0.3/0.7/1.1 mm/s, an effect on in the truth and "
        "withheld from the calibrated model), then calibrate, sample the posterior "
        "with predictive bands on the held-out configurations, diagnose the gap "
        "and write the report (OUT/run/report.html). About 2 minutes; --quick "
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
        help="4 configurations and small budgets (a smoke test of the chain)",
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
