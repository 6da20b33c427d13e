"""The thesis's 2-D check, the process pool and failure reporting on the real forward model."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smcbayes.config import CalibrationSpec, load_project, override
from smcbayes.run.runlog import RunLog
from smcbayes.simulation.executors.local import LocalExecutor
from smcbayes.simulation.objective import Task, TaskResult
from smcbayes.simulation.problem import build_problem
from smcbayes.surrogate.calibration import calibrate
from smcbayes.surrogate.loop import BayesOpt

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "verify-slip-2d.toml"


def settings(project, **kw) -> CalibrationSpec:
    """The project's own [calibration] table (every setting) with the test's overrides."""
    return override(project.calibration, kw)


def test_slip_2d_recovers_truth(tmp_path: Path) -> None:
    """5 LHS + 25 BO evaluations: best within 2 % of the range of the truth in both parameters."""
    project = load_project(CONFIG)
    problem = build_problem(project, tmp_path)
    s = settings(project, seed=2)
    assert (s.init, s.budget) == (5, 30)
    bo = BayesOpt(problem.objective, s, RunLog(tmp_path / "log.jsonl"), LocalExecutor(1)).run()
    best = bo.best()["params"]
    assert best["n"] == 0.4 and best["B_Pa_s"] == 1e4  # fixed parameters stay fixed
    err_log_tau = abs(np.log10(best["tau_c_MPa"]) - np.log10(0.01)) / (np.log10(1.0) - np.log10(0.005))
    err_m = abs(best["m"] - 1.5) / (1.9 - 1.0)
    assert err_log_tau <= 0.02 and err_m <= 0.02


def test_process_pool_equals_inline(tmp_path: Path) -> None:
    project = load_project(CONFIG)
    problem = build_problem(project, tmp_path)
    s = settings(project, budget=6, init=4, batch=2)
    runs = []
    for workers in (1, 2):
        log = RunLog(tmp_path / f"log{workers}.jsonl")
        bo = BayesOpt(problem.objective, s, log, LocalExecutor(workers)).run()
        runs.append([{k: v for k, v in r.items() if k != "seconds"}
                     for _, r in sorted(bo.state.evaluations.items())])
    assert runs[0] == runs[1] and len(runs[0]) == 6
    assert all(r["status"] == "ok" for r in runs[0])


class FailSome:
    """Test-only wrapper: every evaluation whose index is a multiple of 5 fails (20 %)."""

    def __init__(self, inner) -> None:
        self.inner, self.space, self.config_ids = inner, inner.space, inner.config_ids

    def __getattr__(self, name: str):
        return getattr(self.inner, name)  # simulator, dataset, loss_spec of the real objective

    def evaluate(self, task: Task) -> TaskResult:
        res = self.inner.evaluate(task)
        bad = np.array([i % 5 == 0 for i in task.indices])
        status = ["failed: injected" if b else s for b, s in zip(bad, res.status, strict=True)]
        return TaskResult(res.indices, res.config_id, np.where(bad, np.nan, res.error),
                          res.force_mse_kN2, res.displacement_mse_mm2, status, res.seconds, res.curves)


def test_failures_are_reported_in_summary(tmp_path: Path) -> None:
    project = load_project(CONFIG)
    problem = build_problem(project, tmp_path)
    problem.objective = FailSome(problem.objective)
    info = calibrate(problem, settings(project, budget=10, polish=0), tmp_path, LocalExecutor(1),
                     figures=False, progress=None)
    assert info["evaluations"] == 10 and info["failures"] == 2
    assert [f["index"] for f in info["failure_reasons"]] == [0, 5]
    assert all("injected" in f["reason"] for f in info["failure_reasons"])
    assert info["best_loss_kN2"] is not None and info["stop_reason"].startswith("budget")
    assert (tmp_path / "summary.json").is_file() and (tmp_path / "gp.pt").is_file()
