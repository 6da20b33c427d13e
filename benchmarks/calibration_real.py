"""Calibration on the 9 real training configurations of the thesis.

Runs `smcbayes calibrate` (library path: same code as the command) on configs/thesis.toml
with the base (incompressible) model on the full loss, the base model on the thesis's
clipped loss (force compared up to the incompressible flow-stop time, what the thesis
minimised; its best was 18384 kN^2, a sum over the 9 configurations) and with the
compressibility effect on the full loss; 30 Latin hypercube + 60 BO evaluations each.
Reports per-configuration force RMSE (kN) over the full closing, the loss as calibrated,
the clipped loss at the best point (mean and sum over configurations), and wall time.

With compressibility, the solid density is fixed at 1.5 g/cm3 (the consolidated CF-epoxy
SMC, README of the data) and the bulk viscosity at 0; the compaction modulus and exponent
are calibrated with the five base parameters.

    python benchmarks/calibration_real.py [--budget 90] [--init 30] [--keep DIR] [--only base]

Needs ../shared/data/thesis-press next to the repository. Prints a table and writes
benchmarks/results/calibration_real.json.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from smcbayes.config import load_project
from smcbayes.run import RunDir, RunIdentity
from smcbayes.simulation.executors.local import LocalExecutor
from smcbayes.simulation.objective import SimulatorObjective, Task, combine
from smcbayes.simulation.problem import build_problem
from smcbayes.surrogate.calibration import calibrate
from smcbayes.surrogate.loop import BOSettings

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data" / "thesis-press"
THESIS_BEST_CLIPPED_KN2 = 18384.70
VARIANTS = {
    "base": ([], {}, "none"),
    "base-clipped": ([], {}, "flow_stop"),
    "compressibility": (["compressibility"], {"rho_solid_g_cm3": 1.5, "bulk_viscosity_MPa_s": 0.0}, "none"),
}


def loss_at(problem, theta: np.ndarray, clip: str) -> tuple[float, dict[str, float]]:
    """Loss (mean over configurations, kN^2) and per-configuration errors at one vector."""
    obj = SimulatorObjective(problem.model, problem.objective.dataset, problem.train_ids,
                             problem.project.loss.model_copy(update={"clip": clip}))
    errs = {c: float(obj.evaluate(Task((0,), theta[None, :], c)).error[0]) for c in obj.config_ids}
    return combine(errs, obj.config_ids), errs


def run_variant(name: str, run_dir: Path, budget: int, init: int) -> dict:
    effects, fixed, clip = VARIANTS[name]
    project = load_project(ROOT / "configs" / "thesis.toml", DATA.resolve())
    project = project.model_copy(update={"loss": project.loss.model_copy(update={"clip": clip})})
    settings = BOSettings(budget=budget, init=init, batch=1, kernel="matern52", seed=0,
                          local_evaluations=15, local_radius=0.1)
    RunDir(run_dir).prepare(RunIdentity(project.model_dump(mode="json"), effects, fixed, None, None,
                                        settings.model_dump(mode="json", exclude={"truth"})), resume=False)
    problem = build_problem(project, run_dir, effects, fixed)
    start = time.perf_counter()
    info = calibrate(problem, settings, run_dir, LocalExecutor(1), progress=None)
    wall = time.perf_counter() - start
    space = problem.model.space
    best = {k: v["value"] for k, v in info["best_params"].items()}
    theta = np.array([best[n] for n in space.free_names])
    clipped, clipped_errs = loss_at(problem, theta, "flow_stop")
    _, full_errs = loss_at(problem, theta, "none")
    rmse = {c: float(np.sqrt(v)) for c, v in full_errs.items()}
    return {"effects": effects, "fixed": fixed, "loss_clip": clip, "free": space.free_names, "best_params": best,
            "best_loss_kN2": info["best_loss_kN2"], "clipped_loss_kN2": clipped,
            "clipped_loss_sum_kN2": float(sum(clipped_errs.values())),
            "clipped_errors_kN2": clipped_errs, "rmse_kN": rmse,
            "evaluations": info["evaluations"], "failures": info["failures"],
            "wall_s": wall, "seconds_evaluations": info["seconds_evaluations"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=int, default=90)
    parser.add_argument("--init", type=int, default=30)
    parser.add_argument("--keep", type=Path, default=None, help="keep the run directories here")
    parser.add_argument("--only", choices=tuple(VARIANTS), default=None)
    args = parser.parse_args()
    if not DATA.is_dir():
        print(f"skipped: {DATA} not found")
        return
    path = ROOT / "benchmarks" / "results" / "calibration_real.json"
    out: dict = json.loads(path.read_text()) if args.only and path.exists() else {}
    out.update({"budget": args.budget, "init": args.init, "thesis_best_clipped_kN2": THESIS_BEST_CLIPPED_KN2})
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        for name in ([args.only] if args.only else list(VARIANTS)):
            res = run_variant(name, root / name, args.budget, args.init)
            out[name] = res
            print(f"\n{name}: {res['evaluations']} evaluations ({res['failures']} failed) in "
                  f"{res['wall_s']:.0f} s; loss {res['best_loss_kN2']:.1f} kN^2; clipped loss "
                  f"{res['clipped_loss_kN2']:.1f} kN^2 (mean; sum {res['clipped_loss_sum_kN2']:.0f}; "
                  f"thesis best {THESIS_BEST_CLIPPED_KN2})")
            print("  best: " + ", ".join(f"{k}={v:.4g}" for k, v in res["best_params"].items()))
            print(f"  {'configuration':<16}{'force RMSE (kN)':>16}{'clipped MSE (kN^2)':>20}")
            for c, v in res["rmse_kN"].items():
                print(f"  {c:<16}{v:>16.1f}{res['clipped_errors_kN2'][c]:>20.1f}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
