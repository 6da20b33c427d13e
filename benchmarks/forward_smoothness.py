"""Smoothness of the 1-D solver's switch time in the parameters, on the demonstration's
compliant press.  Prints its figures and writes benchmarks/results/forward_smoothness.json.

Run:  python benchmarks/forward_smoothness.py [--lines 12] [--points 151] [--span 0.03]
          [--seed 1] [--compare DIR]

The embedded demonstration's twelve configurations with the frame's stiffness on
(``press_compliance``): along ``--lines`` random lines through the demonstration's truth
(unit cube of its six free parameters, ``--points`` points over ``--span``), the switch
time of every configuration.  A smooth model has second differences of the order of the
trend's curvature, tiny at this spacing; a jump of the switch time as a parameter moves
an event of the marching across a step's end shows as one large second difference.
Printed: each line's largest second difference of the switch time over the
configurations (ms), their range and median over the lines, and how many second
differences exceed 1 ms (the JSON keeps each line's, with its trend).  The emulators and
the calibration's GP assume a smooth response: such jumps become noise they cannot learn.

``--compare DIR`` runs the same measurement with the code of another checkout ``DIR``
(its ``smcbayes`` package first on the path) in the same call, e.g. the code before a
change of the solver.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def measure(lines: int, points: int, span: float, seed: int) -> dict[str, Any]:
    """The switch times' second differences along the lines (see the module docstring)."""
    from smcbayes.commands.demo import load_plan
    from smcbayes.config import build_project
    from smcbayes.forward.model import ForwardModel

    plan = load_plan(quick=False)
    project = build_project(plan.project, "<demo>", Path.cwd())
    model = ForwardModel(project, effects=[plan.effect])
    space = model.space
    names = list(space.free_names)
    centre = space.to_unit(np.array([plan.truth[n] for n in names]))[0]
    rng = np.random.default_rng(seed)
    steps = np.linspace(-0.5 * span, 0.5 * span, points)
    out: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    for _ in range(lines):
        d = rng.standard_normal(len(names))
        values = space.from_unit(np.clip(centre[None, :] + steps[:, None] * (d / np.linalg.norm(d))[None, :],
                                         0.0, 1.0))
        results = model.simulate(values)
        second = np.array([np.abs(np.diff(r.switch_time_s, 2)) for r in results.values()])  # (K, points - 2)
        out.append({"max_second_difference_ms": float(1e3 * np.nanmax(second)),
                    "over_1ms": int(np.sum(second > 1e-3)),
                    "trend_ms": float(1e3 * np.nanmax([abs(r.switch_time_s[-1] - r.switch_time_s[0])
                                                       for r in results.values()]))})
    return {"lines": out, "configurations": len(model.config_ids), "parameters": names,
            "seconds": time.perf_counter() - t0}


def report(label: str, res: dict[str, Any]) -> None:
    """Print one code's figures."""
    worst = [line["max_second_difference_ms"] for line in res["lines"]]
    over = sum(line["over_1ms"] for line in res["lines"])
    print(f"{label}: largest second difference of the switch time per line "
          f"{min(worst):.4f}-{max(worst):.4f} ms "
          f"(median {np.median(worst):.4f}); {over} second differences above 1 ms; {res['seconds']:.0f} s")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=12)
    ap.add_argument("--points", type=int, default=151)
    ap.add_argument("--span", type=float, default=0.03, help="length of each line (unit cube)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--compare", default=None, help="another checkout whose code to measure too")
    ap.add_argument("--json", action="store_true", help=argparse.SUPPRESS)  # one measurement, as JSON
    args = ap.parse_args()
    res = measure(args.lines, args.points, args.span, args.seed)
    if args.json:
        print(json.dumps(res))
        return 0
    record = {"settings": vars(args), "current": res}
    if args.compare:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--json", "--lines", str(args.lines),
               "--points", str(args.points), "--span", str(args.span), "--seed", str(args.seed)]
        env = {**os.environ, "PYTHONPATH": str(Path(args.compare).resolve())}
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
        record["compare"] = json.loads(done.stdout.strip().splitlines()[-1])
        report(f"compare ({args.compare})", record["compare"])
    report("current", res)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "forward_smoothness.json").write_text(json.dumps(record, indent=2) + "\n")
    print(f"wrote {RESULTS / 'forward_smoothness.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
