"""Evaluations lost to transient simulator failures, with and without retries.

A calibration on 9 configurations whose simulations fail at random with probability 0.2
(independently per evaluation, configuration and attempt: an external solver with
transient faults, imitated by :class:`~smcbayes.simulation.objective.FlakyObjective` over
an analytic objective so the measurement takes seconds).  An evaluation is lost when any
of its configurations is still failed after its retries, so with ``r`` retries

    P(lost) = 1 - (1 - 0.2^(r+1))^9  ->  r=0: 87 %, r=1: 31 %, r=2: 7.0 %, r=3: 1.4 %.

Target: at most 5 % of evaluations lost with the default settings (``retries = 3``).
Prints the share lost per setting and writes ``benchmarks/results/failure_capture.json``.

Usage: ``python benchmarks/failure_capture.py [--budget 24] [--seeds 3] [--share 0.2]``
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

from smcbayes.config import CalibrationSpec
from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.run.runlog import RunLog
from smcbayes.simulation.executors.local import LocalExecutor
from smcbayes.simulation.objective import FlakyObjective, QuadraticObjective
from smcbayes.surrogate.loop import BayesOpt

CONFIGS = [f"c{k}" for k in range(9)]
TARGET = 0.05


def calibrate(budget: int, seed: int, share: float, retries: int | None, folder: Path) -> dict[str, Any]:
    """One calibration; ``retries=None`` keeps the default."""
    space = ParameterSpace(BASE_PARAMETERS).with_fixed({"n": 0.4, "tau_star_Pa": 1e4})
    objective = FlakyObjective(QuadraticObjective(space, [1e4, 0.02, 1.3], CONFIGS, seed=seed),
                               share=share, seed=seed)
    given = {"budget": budget, "init": min(8, budget), "seed": seed}
    if retries is not None:
        given["retries"] = retries
    settings = CalibrationSpec(**given)
    start = time.perf_counter()
    bo = BayesOpt(objective, settings, RunLog(folder / "log.jsonl"), LocalExecutor(1)).run()
    return {"seed": seed, "retries": settings.retries, "evaluations": len(bo.state.evaluations),
            "lost": bo.failures(), "best_loss": None if bo.best() is None else bo.best()["loss"],
            "seconds": time.perf_counter() - start}


def expected_lost(share: float, retries: int, configs: int = len(CONFIGS)) -> float:
    """P(an evaluation is lost) for independent failures."""
    return 1.0 - (1.0 - share ** (retries + 1)) ** configs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=int, default=24)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--share", type=float, default=0.2)
    args = parser.parse_args()
    default = CalibrationSpec().retries
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for retries in (0, 1, 2, None):
            for seed in range(args.seeds):
                folder = Path(tmp) / f"r{retries}-s{seed}"
                folder.mkdir()
                rows.append(calibrate(args.budget, seed, args.share, retries, folder))
    out: dict[str, Any] = {"share_failing": args.share, "configurations": len(CONFIGS),
                           "budget": args.budget, "seeds": args.seeds, "default_retries": default,
                           "target_lost": TARGET, "settings": []}
    print(f"{len(CONFIGS)} configurations, {args.share:.0%} of runs failing, budget {args.budget}, "
          f"{args.seeds} seeds")
    for retries in sorted({r["retries"] for r in rows}):
        sel = [r for r in rows if r["retries"] == retries]
        lost = sum(r["lost"] for r in sel) / sum(r["evaluations"] for r in sel)
        line = {"retries": retries, "default": retries == default, "lost_share": lost,
                "expected_lost_share": expected_lost(args.share, retries),
                "seconds": sum(r["seconds"] for r in sel), "runs": sel}
        out["settings"].append(line)
        verdict = ("" if retries != default else
                   ("  target met" if lost <= TARGET else "  MISSED target"))
        print(f"retries {retries}{' (default)' if retries == default else ''}: "
              f"{lost:6.1%} of evaluations lost "
              f"(expected {expected_lost(args.share, retries):5.1%}){verdict}")
    path = Path(__file__).resolve().parent / "results" / "failure_capture.json"
    path.write_text(json.dumps(out, indent=2), encoding="utf-8")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
