"""The posterior stage on all nine measured training trials of the thesis: time, verdict, check.

The target of the real-data posterior: on the thesis's nine training configurations with
compressibility (``configs/thesis.toml``: 7 free parameters, the solid density and the bulk
viscosity fixed by the project), the stage's own diagnostics pass (``reliable: true``) within
2 minutes on 2 cores, and the emulator's check error at the reported posterior's draws is at
most 1 nat on average.

One calibration (``smcbayes calibrate configs/thesis.toml --effect compressibility``, the
project's default budgets) is made once into the work directory and reused while its
settings are the same.  Each seed's posterior stage then runs on a fresh copy of it, in a
fresh interpreter, as a user runs it (``python -m smcbayes.cli posterior RUN --emulator
curves --correct-draws 0 --seed S``), so that start-up, imports and the compiled kernels'
cache loading count.  Seeds run one after the other: two stages at once on 2 cores would
time each other.  The load average is printed beside each time, because other processes on
a shared machine stretch wall time.

With ``--reference-draws N`` a reference posterior is drawn once as well, on another fresh
copy: the stage with the importance correction by the forward model (``--correct-draws N
--seed R``, R from ``--reference-seed``, the project's default emulator for its proposal;
the built-in model's runs cost milliseconds), whose weighted sample is the reference, exact
once its weights settle (its ESS, k-hat and verdict are printed and kept).  Each seed's
reported posterior is then compared with it as the accuracy benchmark compares with its
exact posterior: the largest difference of a 5/50/95 % quantile (share of the parameter's
range; target 0.10), of a correlation (target 0.15) and the MMTV (target 0.2), and whether
a posterior called reliable missed them.  A second reference with another seed shows how
far the reference itself may be off.  The reference is reused while the calibration, the
draws and its seed are the same.

Per seed: wall time, the verdict and its reasons, the emulator check (mean absolute error
at 100 posterior draws, nats), the forward runs that shaped the posterior (``inference``)
and those for bands and checks, the active learning's rounds and whether it was validated,
the reported posterior's spread (how far the emulator's sample functions move a 5/50/95 %
quantile, share of the range) with its standard error and the note on a marginal pass, and
the stage's own time split.

    python benchmarks/real_posterior.py [--seeds 0,1,2] [--emulator curves] [--correct-draws 0]
        [--round-runs N] [--reference-draws N] [--reference-seed R] [--workdir DIR]
        [--data-dir DIR] [--name real_posterior]

Writes ``benchmarks/results/NAME.json``.  Needs ../shared/data/thesis-press next to the
repository (``--data-dir``); without it, prints why and exits 0.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DATA = ROOT / ".." / "shared" / "data" / "thesis-press"
PROJECT = ROOT / "configs" / "thesis.toml"
RESULTS = ROOT / "benchmarks" / "results"
EFFECTS = ("compressibility",)
TARGET_S = 120.0
TARGET_CHECK_NATS = 1.0


def calibrated(workdir: Path, project: Path, data_dir: Path, seed: int) -> tuple[Path, float | None]:
    """The nine-trial calibration in ``workdir/calibration``, made unless one with the same
    project file, data and seed is there; its wall time when made now (else ``None``)."""
    import smcbayes
    from smcbayes.config import load_project

    run = workdir / "calibration"
    settings = {"project_sha256": hashlib.sha256(project.read_bytes()).hexdigest(),
                "data_dir": str(data_dir.resolve()), "effects": list(EFFECTS), "seed": seed}
    record = workdir / "calibration.json"
    if (run / "summary.json").is_file() and record.is_file() and json.loads(record.read_text()) == settings:
        return run, None
    shutil.rmtree(run, ignore_errors=True)
    workdir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    smcbayes.calibrate(load_project(project, data_dir), run, effects=list(EFFECTS), figures=False, seed=seed)
    record.write_text(json.dumps(settings, indent=2) + "\n")
    return run, time.perf_counter() - t0


def posterior_command(calibration: Path, run: Path, options: list[str], log: Path) -> tuple[int, float]:
    """``smcbayes posterior`` with ``options`` on a fresh copy ``run`` of ``calibration``, in a
    fresh interpreter, its output to ``log``: the exit code and the wall time (s)."""
    shutil.rmtree(run, ignore_errors=True)
    # only the calibration's own earlier posterior is left out, not a folder of that name deeper down
    shutil.copytree(calibration, run,
                    ignore=lambda folder, names: ["posterior"] if Path(folder) == calibration else [])
    cmd = [sys.executable, "-m", "smcbayes.cli", "posterior", str(run), *options]
    env = {**os.environ, "MPLBACKEND": "Agg"}
    t0 = time.perf_counter()
    with log.open("w", encoding="utf-8") as fh:
        proc = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, check=False, env=env, cwd=ROOT)
    return proc.returncode, time.perf_counter() - t0


def run_stage(calibration: Path, workdir: Path, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    """One seed's posterior stage on a fresh copy of ``calibration``, in a fresh interpreter;
    its output goes to ``workdir/seed-S.log``.  A failed stage gives a record with its exit
    code and the end of its log, so that the other seeds' records are still written."""
    run = workdir / f"seed-{seed}"
    options = ["--emulator", args.emulator, "--correct-draws", str(args.correct_draws), "--seed", str(seed)]
    options += [] if args.round_runs is None else ["--round-runs", str(args.round_runs)]
    log = workdir / f"seed-{seed}.log"
    load_before = os.getloadavg()[0]
    code, wall = posterior_command(calibration, run, options, log)
    if code != 0:
        tail = log.read_text(encoding="utf-8").splitlines()[-20:]
        return {"seed": seed, "wall_s": wall, "returncode": code, "log_tail": tail,
                "met": {"reliable": False, "check": False, "time": False}}
    summary = json.loads((run / "posterior" / "summary.json").read_text(encoding="utf-8"))
    return {**record_of(summary, seed, wall, (load_before, os.getloadavg()[0])), "run": str(run)}


def reference(calibration: Path, workdir: Path, args: argparse.Namespace) -> dict[str, Any] | None:
    """The reference posterior (see the module docstring) in ``workdir/reference``, drawn unless
    one of the same calibration, draws and seed is there; ``None`` without
    ``--reference-draws``.  Returns its run directory, the correction's ESS, k-hat and
    whether it settled, the stage's verdict, its forward runs and wall time (``None`` when
    reused)."""
    if args.reference_draws <= 0:
        return None
    run, record = workdir / "reference", workdir / "reference.json"
    settings = {"calibration": json.loads((workdir / "calibration.json").read_text()),
                "draws": args.reference_draws, "seed": args.reference_seed}
    summary_path = run / "posterior" / "summary.json"
    wall = None
    if not (summary_path.is_file() and record.is_file() and json.loads(record.read_text()) == settings):
        record.unlink(missing_ok=True)
        options = ["--correct-draws", str(args.reference_draws), "--seed", str(args.reference_seed)]
        code, wall = posterior_command(calibration, run, options, workdir / "reference.log")
        if code != 0:
            log = workdir / "reference.log"
            raise SystemExit(f"the reference stage failed (exit code {code}); see {log}")
        record.write_text(json.dumps(settings, indent=2) + "\n")
    summary = json.loads(summary_path.read_text(encoding="utf-8"))
    corr = summary.get("correction") or {}
    return {"run": str(run), "wall_s": wall, "ess": corr.get("ess"), "k_hat": corr.get("k_hat"),
            "settled": bool(corr.get("settled")), "ess_target": corr.get("ess_target"),
            "reliable": bool(summary.get("reliable")), "forward_runs": corr.get("evaluations"),
            "draws": args.reference_draws, "seed": args.reference_seed}


def against_reference(rec: dict[str, Any], ref: dict[str, Any]) -> dict[str, Any]:
    """How far a seed's reported posterior lies from the reference (quantiles and
    correlations as the accuracy benchmark measures them, MMTV)."""
    from _posterior_common import posterior_samples
    from posterior_accuracy import Q_TARGET, R_TARGET, compare

    from smcbayes.posterior.stage import load_run

    exact = posterior_samples(Path(ref["run"]))["weighted"]
    drawn = posterior_samples(Path(rec["run"]))["reported"]
    names = list(load_run(Path(rec["run"])).space.free_names)
    c = compare(names, exact, drawn, np.zeros(drawn.shape[1]))
    met = bool(c["quantiles_met"] and c["correlations_met"] and c["mmtv"] < 0.2)
    return {"max_quantile_diff": c["max_quantile_diff"], "max_correlation_diff": c["max_correlation_diff"],
            "mmtv": c["mmtv"], "met": met,
            "targets": {"quantiles": Q_TARGET, "correlations": R_TARGET, "mmtv": 0.2},
            "quantiles_unit": {p["name"]: {"reference": p["exact_q05_q50_q95_unit"],
                                           "reported": p["emulated_q05_q50_q95_unit"]}
                               for p in c["parameters"]}}


def record_of(summary: dict[str, Any], seed: int, wall_s: float, load: tuple[float, float]) -> dict[str, Any]:
    """What the benchmark keeps of one stage's ``posterior/summary.json``."""
    from smcbayes.posterior.reliability import marginal_spread_note

    check = summary.get("emulator_check") or {}
    runs = summary.get("forward_evaluations") or {}
    learning = summary.get("active_learning") or {}
    spread = summary.get("emulator_spread") or {}
    reliability = summary.get("reliability") or {}
    rec = {"seed": seed, "wall_s": wall_s, "load_average_before_after": list(load),
           "reliable": bool(summary.get("reliable")), "reasons": reliability.get("reasons", []),
           "check_mean_abs_error_nats": check.get("mean_abs_error"), "check_points": check.get("points"),
           "inference_runs": runs.get("inference"), "active_learning_runs": learning.get("evaluations"),
           "checks_and_bands_runs": runs.get("checks_and_bands"),
           "rounds": learning.get("rounds"), "validated": learning.get("converged"),
           "spread": spread.get("max_quantile_shift"), "spread_se": spread.get("max_quantile_shift_se"),
           "marginal_note": marginal_spread_note(spread), "notes": reliability.get("notes", []),
           "stage_seconds": summary.get("stage_seconds")}
    rec["met"] = {"reliable": rec["reliable"],
                  "check": rec["check_mean_abs_error_nats"] is not None
                  and rec["check_mean_abs_error_nats"] <= TARGET_CHECK_NATS,
                  "time": wall_s <= TARGET_S}
    return rec


def print_record(rec: dict[str, Any]) -> None:
    """One seed's line and its unmet targets."""
    def fmt(v: Any, spec: str) -> str:
        return "-" if v is None else format(v, spec)

    if "returncode" in rec:
        print(f"seed {rec['seed']}: FAILED (exit code {rec['returncode']}) after {rec['wall_s']:.0f} s:")
        print("\n".join("  " + line for line in rec["log_tail"]))
        return
    verdict = "reliable" if rec["reliable"] else "unreliable"
    print(f"seed {rec['seed']}: {rec['wall_s']:.0f} s (load {rec['load_average_before_after'][0]:.1f}), "
          f"{verdict}, check {fmt(rec['check_mean_abs_error_nats'], '.2f')} nats, spread "
          f"{fmt(rec['spread'], '.3f')} (standard error {fmt(rec.get('spread_se'), '.3f')}), "
          f"{rec['inference_runs']} runs shaped it (active learning "
          f"{rec['active_learning_runs']} in {rec['rounds']} rounds, "
          f"{'validated' if rec['validated'] else 'not validated'}), {rec['checks_and_bands_runs']} for "
          "checks and bands")
    against = rec.get("reference")
    if against is not None:
        print(f"  against the reference: quantiles {against['max_quantile_diff']:.3f}, correlations "
              f"{against['max_correlation_diff']:.3f}, MMTV {against['mmtv']:.3f}"
              + ("" if against["met"] else
                 " (targets missed" + (", though reliable)" if rec["reliable"] else ")")))
    missed = [k for k, ok in rec["met"].items() if not ok]
    if missed:
        print("  MISSED: " + ", ".join(missed))
    for reason in rec["reasons"]:
        print(f"  - {reason}")
    if rec.get("marginal_note"):
        print(f"  note: {rec['marginal_note']}")


def seed_list(text: str) -> list[int]:
    """Comma-separated integers (seeds, or counts), at least one, none negative."""
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"give integers, comma-separated, not {text!r}") from None
    if not values or min(values) < 0:
        raise argparse.ArgumentTypeError(f"give one or more integers of 0 or more, not {text!r}")
    return values


def parse() -> argparse.Namespace:
    """The command line."""
    from smcbayes.config import PosteriorSpec, choices_of

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=seed_list, default=[0, 1, 2], help="posterior seeds, comma-separated "
                    "(default 0,1,2)")
    ap.add_argument("--calibration-seed", type=int, default=0)
    ap.add_argument("--emulator", choices=choices_of(PosteriorSpec, "emulator"), default="curves",
                    help="the posterior's emulator (--emulator; default curves)")
    ap.add_argument("--correct-draws", type=int, default=0,
                    help="forward-model correction draws (0: none, as for an expensive simulator)")
    ap.add_argument("--round-runs", type=int, default=None,
                    help="forward runs per active-learning round (default: the stage's)")
    ap.add_argument("--reference-draws", type=int, default=0,
                    help="draws of the importance correction by the forward model whose posterior each "
                    "seed is compared with (0: no reference; 40000 take about 5 minutes on the nine "
                    "trials, and did not settle there)")
    ap.add_argument("--reference-seed", type=int, default=0, help="seed of the reference stage")
    ap.add_argument("--workdir", default=None, help="default: benchmarks/results/NAME/work")
    ap.add_argument("--data-dir", default=str(DATA))
    ap.add_argument("--project", default=str(PROJECT))
    ap.add_argument("--name", default="real_posterior")
    return ap.parse_args()


def main() -> int:
    """Calibrate once, run each seed's stage, print and write the results."""
    args = parse()
    if not Path(args.data_dir).is_dir():
        print(f"skipped: no measured data at {args.data_dir} (pass --data-dir)")
        return 0
    workdir = Path(args.workdir or RESULTS / args.name / "work")
    calibration, calibration_s = calibrated(workdir, Path(args.project), Path(args.data_dir),
                                            args.calibration_seed)
    print(f"calibration: {'reused' if calibration_s is None else f'{calibration_s:.0f} s'} ({calibration})")
    exact = reference(calibration, workdir, args)
    if exact is not None:
        made = "reused" if exact["wall_s"] is None else f"{exact['wall_s']:.0f} s"
        print(f"reference: {made}, {exact['forward_runs']} forward runs, importance ESS {exact['ess']:.0f}, "
              f"k-hat {exact['k_hat']:.2f} ({exact['run']})")
        if not exact["settled"]:
            # a second reference with another --reference-seed shows how far off it may be
            print(f"  the reference did not settle (ESS short of {exact['ess_target']}): the comparisons "
                  "below are as uncertain as it is")
    records = []
    for seed in args.seeds:
        rec = run_stage(calibration, workdir, seed, args)
        if exact is not None and "returncode" not in rec:
            rec["reference"] = against_reference(rec, exact)
        records.append(rec)
        print_record(rec)
    met = {k: sum(r["met"][k] for r in records) for k in ("reliable", "check", "time")}
    print(f"targets (each seed: reliable, check <= {TARGET_CHECK_NATS:g} nat, <= {TARGET_S:.0f} s): "
          + ", ".join(f"{k} {v} of {len(records)}" for k, v in met.items()))
    if exact is not None:
        compared = [r for r in records if "reference" in r]
        print(f"against the reference: {sum(r['reference']['met'] for r in compared)} of {len(compared)} "
              f"within the targets; reliable yet outside them: "
              f"{sum(r['reliable'] and not r['reference']['met'] for r in compared)}")
    out = {"settings": vars(args), "cpu_count": os.cpu_count(), "calibration_s": calibration_s,
           "targets": {"wall_s": TARGET_S, "check_nats": TARGET_CHECK_NATS}, "reference": exact,
           "seeds": records, "met": met}
    path = RESULTS / f"{args.name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2, default=float) + "\n", encoding="utf-8")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
