"""Wall time of ``smcbayes demo`` (full and ``--quick``), as a user runs it.

Each demo runs in a fresh interpreter (``python -m smcbayes.cli demo``) into a temporary
folder, so start-up and imports count; the per-stage times come from the demo's own
record (``run-effect/demo.json``).  The load average of the machine is printed next to the
times because other processes on a shared machine stretch wall time.  Next to the times it
records whether the loop closed: the effect the diagnosis named and the training loss of
the base run and of the run with that effect on.

Targets on a 2-core machine: full demo <= 300 s, quick demo <= 60 s (a missed target is
printed as MISSED).  Writes ``benchmarks/results/demo_time.json``.

Usage: ``python benchmarks/demo_time.py [--only full|quick]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_S = {"full": 300.0, "quick": 60.0}
RESULTS = Path(__file__).resolve().parent / "results" / "demo_time.json"


def run_one(mode: str) -> dict:
    """Run one demo in a fresh interpreter; wall, CPU and stage times."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "demo"
        cmd = [sys.executable, "-m", "smcbayes.cli", "demo", "--out", str(out)]
        cmd += ["--quick"] if mode == "quick" else []
        load_before = os.getloadavg()
        cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        wall = time.perf_counter() - t0
        cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        if proc.returncode != 0:
            raise SystemExit(f"demo {mode} failed ({proc.returncode}):\n{proc.stderr}")
        record = json.loads((out / "run-effect" / "demo.json").read_text(encoding="utf-8"))
        report_ok = (out / "run-effect" / "report.html").is_file()
        loss = {
            name: json.loads((out / name / "summary.json").read_text(encoding="utf-8"))[
                "best_loss_kN2"
            ]
            for name in ("run-base", "run-effect")
        }
    return {
        "mode": mode,
        "wall_s": wall,
        "target_s": TARGET_S[mode],
        "met": wall <= TARGET_S[mode],
        "cpu_user_s": cpu1.ru_utime - cpu0.ru_utime,
        "cpu_system_s": cpu1.ru_stime - cpu0.ru_stime,
        "stages_s": record.get("timings_s", {}),
        "report_written": report_ok,
        "effect_named": record.get("effect_named"),
        "best_loss_kN2": loss,
        "load_average_before": list(load_before),
        "load_average_after": list(os.getloadavg()),
        "stdout": proc.stdout.splitlines(),
    }


def main() -> None:
    """Run the demos, print a table, write the JSON."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", choices=("full", "quick"), default=None)
    args = p.parse_args()
    modes = [args.only] if args.only else ["quick", "full"]
    rows = [run_one(m) for m in modes]
    head = f"{'demo':<6}{'wall s':>9}{'target s':>10}{'CPU s':>8}"
    print(f"{head}  load avg (1 min) before/after  loss base -> effect (kN^2)  stages")
    for r in rows:
        stages = ", ".join(f"{k} {v:.1f}" for k, v in r["stages_s"].items() if k != "total")
        flag = "" if r["met"] else "  MISSED"
        print(
            f"{r['mode']:<6}{r['wall_s']:>9.1f}{r['target_s']:>10.0f}{r['cpu_user_s']:>8.1f}  "
            f"{r['load_average_before'][0]:.2f} / {r['load_average_after'][0]:.2f}"
            f"{'':>18}{r['best_loss_kN2']['run-base']:.4g} -> "
            f"{r['best_loss_kN2']['run-effect']:.4g} ({r['effect_named']})  {stages}{flag}"
        )
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    info = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
        },
        "runs": rows,
    }
    RESULTS.write_text(json.dumps(info, indent=2) + "\n", encoding="utf-8")
    print(f"written: {RESULTS}")


if __name__ == "__main__":
    main()
