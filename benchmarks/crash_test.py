"""Kill every stage at random moments, rerun it, and check it ends as an uninterrupted run.

For each stage (calibrate, posterior, diagnose) on a small synthetic case (the 2-D slip check
``configs/verify-slip-2d.toml`` with noisy data at tau_c = 0.01 MPa, m = 1.5): an
uninterrupted reference run, then a run killed with SIGKILL at seeded random moments
(``--kills`` times) and rerun with the same command (``--resume`` for the calibration)
until it completes.  Checked: the calibration's ``evaluations.jsonl`` records, the
posterior's summary numbers and its sample, the diagnosis's ranking and scores.  Reported:
forward runs repeated, i.e. begun by a killed process and lost in flight (calibration:
evaluations of the round logged but not finished at the kill; later stages: the forward
cache's batch markers minus the runs it kept).  Prints a table and writes
``benchmarks/results/crash_test.json``.

    python benchmarks/crash_test.py [--kills 3] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
CLI = [sys.executable, "-m", "smcbayes.cli"]

CALIBRATE = ["--budget", "14", "--init", "6", "--seed", "0", "--no-figures"]
POSTERIOR = ["--walkers", "8", "--steps", "200", "--functions", "2", "--correct-draws", "1500",
             "--draws", "10", "--refine", "18", "--seed", "1"]
DIAGNOSE = ["--population", "10", "--generations", "3", "--restarts", "1", "--effects",
            "press_compliance", "--seed", "0", "--no-figures"]
VOLATILE = ("seconds", "stage_seconds", "seconds_wall", "seconds_evaluations", "forward_runs_reused",
            "forward_runs_made", "stop_reason_time")


def run(args: Sequence[str], log: Path) -> float:
    """Run the CLI to completion; returns its wall time (s)."""
    t0 = time.perf_counter()
    with log.open("a") as fh:
        subprocess.run([*CLI, *args], check=True, stdout=fh, stderr=fh, cwd=ROOT)
    return time.perf_counter() - t0


def run_killed(args: Sequence[str], after_s: float, log: Path) -> bool:
    """Start the CLI and SIGKILL it after ``after_s``; returns whether it was killed."""
    with log.open("a") as fh:
        proc = subprocess.Popen([*CLI, *args], stdout=fh, stderr=fh, cwd=ROOT)
        try:
            proc.wait(timeout=after_s)
            return False
        except subprocess.TimeoutExpired:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
            return True


def lines(path: Path) -> list[dict[str, Any]]:
    out = []
    for line in path.read_text().splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out


def calibration_in_flight(run_dir: Path) -> int:
    """Evaluations of logged rounds not finished (lost at a kill, made again on resume)."""
    log = run_dir / "evaluations.jsonl"
    if not log.is_file():
        return 0
    recs = lines(log)
    planned = {i for r in recs if r.get("type") == "round" for i in r.get("indices", [])}
    done = {r["index"] for r in recs if r.get("type") == "evaluation"}
    return len(planned - done)


def cache_lost(folder: Path) -> int:
    """Forward runs begun but never kept, summed over the stage's cache files."""
    started = stored = 0
    for path in (folder / "forward_cache").glob("*.jsonl"):
        for rec in lines(path):
            started += int(rec.get("batch", 0))
            stored += "k" in rec
    return started - stored


def strip(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: strip(v) for k, v in obj.items() if k not in VOLATILE}
    if isinstance(obj, list):
        return [strip(v) for v in obj]
    return obj


def crash_cycle(name: str, first: list[str], again: list[str], ref_s: float, kills: int,
                rng: np.random.Generator, log: Path, lost: Callable[[], int]) -> dict[str, Any]:
    """Kill ``kills`` times at random moments within the reference's wall time, then run
    ``again`` until it completes."""
    killed, repeated, moments = 0, 0, []
    cmd = first
    for _ in range(kills):
        after = float(rng.uniform(0.25, 0.95) * ref_s)
        before = lost()
        if not run_killed(cmd, after, log):
            break
        killed += 1
        moments.append(round(after, 1))
        repeated += max(lost() - before, 0) if name != "calibrate" else lost()
        cmd = again
    t = run(cmd if killed else again, log)
    return {"kills": killed, "kill_moments_s": moments, "repeated_runs": repeated, "last_run_s": t}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", action="store_true", help="keep the work folder")
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    work = Path(tempfile.mkdtemp(prefix="crash-test-"))
    log = work / "cli.log"
    rows: list[dict[str, Any]] = []
    try:
        run(["synth", str(ROOT / "configs" / "verify-slip-2d.toml"), "--truth", "tau_c_MPa=0.01",
             "--truth", "m=1.5", "--noise-kN", "5", "--correlated-kN", "3", "--correlation-s", "0.5",
             "--seed", "3", "--out", str(work / "data")], log)
        project = str(work / "data" / "project.toml")

        # calibration
        ref, crash = work / "cal-ref", work / "cal-crash"
        t_ref = run(["calibrate", project, "--out", str(ref), *CALIBRATE], log)
        res = crash_cycle("calibrate", ["calibrate", project, "--out", str(crash), *CALIBRATE],
                          ["calibrate", project, "--out", str(crash), *CALIBRATE, "--resume"],
                          t_ref, a.kills, rng, log, lambda: calibration_in_flight(crash))

        def evals(d: Path) -> list[dict[str, Any]]:
            return [strip(r) for r in lines(d / "evaluations.jsonl") if r.get("type") == "evaluation"]

        res.update(stage="calibrate", reference_s=t_ref, equal=evals(ref) == evals(crash),
                   compared=f"{len(evals(ref))} evaluation records")
        rows.append(res)

        # posterior (on copies of the reference calibration)
        p_ref, p_crash = work / "post-ref", work / "post-crash"
        shutil.copytree(ref, p_ref)
        shutil.copytree(ref, p_crash)
        t_ref = run(["posterior", str(p_ref), *POSTERIOR], log)
        cmd = ["posterior", str(p_crash), *POSTERIOR]
        res = crash_cycle("posterior", cmd, cmd, t_ref, a.kills, rng, log,
                          lambda: cache_lost(p_crash / "posterior"))
        s_ref = json.loads((p_ref / "posterior" / "summary.json").read_text())
        s_new = json.loads((p_crash / "posterior" / "summary.json").read_text())
        import arviz as az

        def sample(d: Path) -> np.ndarray:
            idata = az.from_netcdf(str(d / "posterior" / "posterior.nc"))
            return np.column_stack([idata.posterior[v].values.reshape(-1)
                                    for v in sorted(idata.posterior.data_vars)])

        res.update(stage="posterior", reference_s=t_ref,
                   equal=strip(s_ref) == strip(s_new) and np.array_equal(sample(p_ref), sample(p_crash)),
                   compared="summary.json numbers, posterior sample",
                   forward_runs_reused=s_new.get("forward_runs_reused"),
                   forward_runs_made_last=s_new.get("forward_runs_made"))
        rows.append(res)

        # diagnosis
        d_ref, d_crash = work / "diag-ref", work / "diag-crash"
        t_ref = run(["diagnose", str(p_ref), "--out", str(d_ref), *DIAGNOSE], log)
        cmd = ["diagnose", str(p_ref), "--out", str(d_crash), *DIAGNOSE]
        res = crash_cycle("diagnose", cmd, cmd, t_ref, a.kills, rng, log, lambda: cache_lost(d_crash))
        s_ref = json.loads((d_ref / "summary.json").read_text())
        s_new = json.loads((d_crash / "summary.json").read_text())
        res.update(stage="diagnose", reference_s=t_ref,
                   equal=strip(s_ref["ranking"]) == strip(s_new["ranking"])
                   and s_ref["decision"] == s_new["decision"],
                   compared="ranking (scores, losses, fitted parameters) and decision",
                   forward_runs_reused=s_new.get("forward_runs_reused"),
                   forward_runs_made_last=s_new.get("forward_runs_made"))
        rows.append(res)
    finally:
        if not a.keep:
            shutil.rmtree(work, ignore_errors=True)
    print(f"{'stage':<10} {'ref s':>6} {'kills':>5} {'repeated':>8} {'reused':>7} {'equal':>6}  compared")
    for r in rows:
        print(f"{r['stage']:<10} {r['reference_s']:>6.1f} {r['kills']:>5} {r['repeated_runs']:>8} "
              f"{str(r.get('forward_runs_reused', '-')):>7} {str(r['equal']):>6}  {r['compared']}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "crash_test.json").write_text(json.dumps({"seed": a.seed, "kills": a.kills, "stages": rows},
                                                        indent=2, default=float) + "\n")
    return 0 if all(r["equal"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
