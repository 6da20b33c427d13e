"""The calibration's local search: it lowers the loss within its budget, resumes exactly,
feeds the GP only its best point, and runs by default only with a fast simulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smcbayes.config import CalibrationSpec, load_project
from smcbayes.config.settings import POLISH_FAST
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.run.runlog import RunLog
from smcbayes.simulation.executors.local import LocalExecutor
from smcbayes.simulation.objective import (
    InterruptingObjective,
    QuadraticObjective,
    SimulatorObjective,
    Task,
    TaskResult,
)
from smcbayes.simulation.problem import ExternalSpec, Problem, build_problem
from smcbayes.surrogate.loop import BayesOpt, BOSettings, training_data
from smcbayes.surrogate.polish import POLISH

ROOT = Path(__file__).resolve().parents[2]
TRUTH = [0.02, 1.3]


def space() -> ParameterSpace:
    return ParameterSpace(BASE_PARAMETERS).with_fixed({"n": 0.4, "tau_star_Pa": 1e4, "B_Pa_s": 1e4})


def objective() -> QuadraticObjective:
    return QuadraticObjective(space(), TRUTH, ["a", "b"], seed=1)


def run(tmp: Path, obj, polish: int, **kw) -> BayesOpt:
    settings = BOSettings(**{"budget": 8, "init": 5, "restarts": 2, "raw_samples": 32, **kw})
    tmp.mkdir(parents=True, exist_ok=True)
    return BayesOpt(obj, settings, RunLog(tmp / "log.jsonl"), LocalExecutor(1), polish=polish).run()


def records(tmp: Path) -> list[dict]:
    state = RunLog(tmp / "log.jsonl").read()
    return [{k: v for k, v in r.items() if k != "seconds"} for _, r in sorted(state.evaluations.items())]


def test_the_local_search_lowers_the_loss_within_its_budget(tmp_path: Path) -> None:
    bo = run(tmp_path / "short", objective(), polish=12)
    polished = [r for r in bo.state.rounds.values() if r["kind"] == POLISH]
    assert len(polished) == 12 and all(len(r["indices"]) == 1 for r in polished)
    assert len(bo.state.evaluations) == 8 + 12
    start = min(r["loss"] for r in bo.state.evaluations.values() if r["round"] < min(p["round"] for p in polished))
    assert bo.polish is not None and bo.polish.start_loss == start
    assert bo.polish.best_loss == bo.best()["loss"] < start
    assert not bo.polish.converged and "its budget spent" in bo.stop_reason
    # with room to converge it stops by its own tolerance, at the minimum
    bo = run(tmp_path / "long", objective(), polish=2000)
    assert bo.polish.converged and bo.polish.evaluations < 2000
    best = bo.best()["params"]
    u = space().to_unit(np.array([[best["tau_c_MPa"], best["m"]]]))[0]
    np.testing.assert_allclose(u, objective().truth_unit, atol=1e-3)


def test_an_interrupted_local_search_resumes_to_the_uninterrupted_run(tmp_path: Path) -> None:
    inner = objective()
    with pytest.raises(KeyboardInterrupt):  # evaluation 14 is the search's sixth
        run(tmp_path / "cut", InterruptingObjective(inner, 14), polish=15)
    assert len(records(tmp_path / "cut")) == 14
    run(tmp_path / "cut", inner, polish=15)
    run(tmp_path / "whole", inner, polish=15)
    assert records(tmp_path / "cut") == records(tmp_path / "whole")
    assert len(records(tmp_path / "whole")) == 8 + 15
    # a rerun of the finished run replays the search from the log and runs nothing
    again = run(tmp_path / "whole", inner, polish=15)
    assert records(tmp_path / "whole") == records(tmp_path / "cut") and again.polish.evaluations == 15


def test_a_raised_budget_searches_again_and_then_polishes_the_new_best(tmp_path: Path) -> None:
    run(tmp_path, objective(), polish=6)
    bo = run(tmp_path, objective(), polish=6, budget=10)
    kinds = [r["kind"] for _, r in sorted(bo.state.rounds.items())]
    assert kinds == ["init"] + ["bo"] * 3 + [POLISH] * 6 + ["bo"] * 2 + [POLISH] * 6
    assert len(bo.state.evaluations) == 8 + 6 + 2 + 6
    # the GP of the optimisation sees each search's best point, not its line searches
    x, _ = training_data(bo.state, bo.space.to_unit, bo.space.free_names, "impute")
    assert x.shape[0] == 8 + 2 + 2


def test_the_default_local_search_depends_on_the_simulator(tmp_path: Path) -> None:
    assert CalibrationSpec().polish_evaluations(fast=True) == POLISH_FAST > 0
    assert CalibrationSpec().polish_evaluations(fast=False) == 0
    assert CalibrationSpec(polish=7).polish_evaluations(fast=False) == 7
    project = load_project(ROOT / "configs" / "verify-slip-2d.toml")
    native = build_problem(project, tmp_path / "a", fidelity="1d")
    assert native.fast
    external = ExternalSpec("python sim.py {params} {output}")
    assert not build_problem(project, tmp_path / "b", fidelity="1d", external=external).fast
    # the 2-D solver costs seconds a run (its truth is not simulated here: the 1-D data serve)
    model = ForwardModel(native.project, fidelity="2d")
    two_d = Problem(native.project, model, SimulatorObjective(model, native.dataset, native.train_ids),
                    native.train_ids, native.truth)
    assert not two_d.fast


def test_the_tolerance_rule_ignores_the_local_search(tmp_path: Path) -> None:
    """A run the tolerance rule stopped takes the same decision when rerun: its local
    search's improving rounds do not start the optimisation again."""
    kw = {"budget": 20, "tolerance": 0.05, "patience": 2}
    # ten evaluations: the search's last one improves the loss by an order of magnitude
    first = run(tmp_path, objective(), polish=10, **kw)
    assert first.stop_reason.startswith("best loss improved by less than")
    local = [r["loss"] for _, r in sorted(first.state.evaluations.items())
             if first.state.rounds[r["round"]]["kind"] == POLISH]
    assert local[-1] < 0.5 * min(local[:-1])
    before = records(tmp_path)
    again = run(tmp_path, objective(), polish=10, **kw)
    assert records(tmp_path) == before and again.stop_reason == first.stop_reason


def test_failed_evaluations_of_the_local_search_are_logged_and_skipped(tmp_path: Path) -> None:
    inner = objective()

    class FailingAbove:
        """Fails every evaluation with tau_c above the truth (a solver failure region)."""

        space, config_ids = inner.space, inner.config_ids

        def evaluate(self, task: Task) -> TaskResult:
            res = inner.evaluate(task)
            bad = task.theta[:, 0] > 0.03
            err = np.where(bad, np.nan, res.error)
            status = ["failed: injected" if b else s for b, s in zip(bad, res.status, strict=True)]
            return TaskResult(res.indices, res.config_id, err, err.copy(), res.displacement_mse_mm2,
                              status, res.seconds)

    for failed in ("impute", "exclude"):
        bo = run(tmp_path / failed, FailingAbove(), polish=40, failed=failed, retries=0)
        local = [r for r in bo.state.evaluations.values() if bo.state.rounds[r["round"]]["kind"] == POLISH]
        assert len(local) == bo.polish.evaluations > 0
        assert any(r["status"] == "failed" for r in local)
        assert bo.polish.best_loss == min(r["loss"] for r in local + [bo.state.evaluations[bo.polish.start_index]]
                                          if r["loss"] is not None)


def test_a_smaller_budget_on_resume_ends_the_search_there(tmp_path: Path) -> None:
    run(tmp_path, objective(), polish=20)
    bo = run(tmp_path, objective(), polish=8)
    assert bo.polish.evaluations == 8
    first = min(r["round"] for r in bo.state.rounds.values() if r["kind"] == POLISH)
    eight = [r["loss"] for r in bo.state.evaluations.values() if first <= r["round"] < first + 8]
    assert bo.polish.best_loss == min([bo.polish.start_loss, *eight])
    assert bo.polish.best_loss > bo.best()["loss"]  # the logged rounds past 8 found better
