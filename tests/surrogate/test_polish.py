"""The calibration's local search: it lowers the loss within its budget, resumes exactly,
feeds the GP only its best point, and runs by default only with a fast simulator."""

from __future__ import annotations

import json
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
    start = min(r["loss"] for r in bo.state.evaluations.values()
                if r["round"] < min(p["round"] for p in polished))
    assert bo.polish is not None and bo.polish.start_loss == start
    assert bo.polish.best_loss == bo.best()["loss"] < start
    # the start point is answered from the log, not run again
    start_params = bo.state.evaluations[bo.polish.start_index]["params"]
    assert all(bo.state.evaluations[i]["params"] != start_params for p in polished for i in p["indices"])
    assert not bo.polish.converged and "its budget spent" in bo.stop_reason
    # with room to converge it stops by its own tolerance, at the minimum
    bo = run(tmp_path / "long", objective(), polish=2000)
    assert bo.polish.converged and bo.polish.evaluations < 2000
    best = bo.best()["params"]
    u = space().to_unit(np.array([[best["tau_c_MPa"], best["m"]]]))[0]
    np.testing.assert_allclose(u, objective().truth_unit, atol=1e-3)


def test_an_interrupted_local_search_resumes_to_the_uninterrupted_run(tmp_path: Path) -> None:
    inner = objective()
    with pytest.raises(KeyboardInterrupt):  # evaluation 14 is the search's seventh
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
        assert bo.polish.best_loss == min(r["loss"]
                                          for r in local + [bo.state.evaluations[bo.polish.start_index]]
                                          if r["loss"] is not None)


def test_a_smaller_budget_on_resume_ends_the_search_there(tmp_path: Path) -> None:
    run(tmp_path, objective(), polish=20)
    bo = run(tmp_path, objective(), polish=8)
    assert bo.polish.evaluations == 8
    first = min(r["round"] for r in bo.state.rounds.values() if r["kind"] == POLISH)
    eight = [r["loss"] for r in bo.state.evaluations.values() if first <= r["round"] < first + 8]
    assert bo.polish.best_loss == min([bo.polish.start_loss, *eight])
    assert bo.polish.best_loss > bo.best()["loss"]  # the logged rounds past 8 found better


def test_a_raised_budget_judges_the_optimisation_by_its_own_losses(tmp_path: Path) -> None:
    """After a search, a resumed optimisation with the tolerance rule compares its own best
    losses: the search's gain (rounds before the new ones) is not its progress."""
    first = run(tmp_path, objective(), polish=10)
    own_before = min(r["loss"] for r in first.state.evaluations.values()
                     if first.state.rounds[r["round"]]["kind"] != POLISH)
    assert first.polish.best_loss < 0.5 * own_before  # the search halved the loss
    bo = run(tmp_path, objective(), polish=0, budget=30, tolerance=0.5, patience=1)
    kinds = [r["kind"] for _, r in sorted(bo.state.rounds.items())]
    new = [r["loss"] for r in bo.state.evaluations.values() if r["round"] == len(kinds) - 1]
    assert min(new) > 0.5 * own_before  # the optimisation's own next point did not
    assert kinds[-2:] == [POLISH, "bo"] and bo.stop_reason.startswith("best loss improved by less than")


def test_summaries_during_the_search_say_running(tmp_path: Path) -> None:
    seen: list[tuple[str, bool]] = []
    settings = BOSettings(budget=8, init=5, restarts=2, raw_samples=32)
    tmp_path.mkdir(exist_ok=True)
    bo = BayesOpt(objective(), settings, RunLog(tmp_path / "log.jsonl"), LocalExecutor(1), polish=60,
                  on_round=lambda b: seen.append((b.stop_reason, b.polish is not None)))
    bo.run()
    during = [s for s in seen[4:-1]]  # after the design and the 3 optimisation rounds
    assert during and all(reason == "" and not done for reason, done in during)
    assert seen[-1][1] and "local search" in seen[-1][0]


def test_a_resumed_search_that_meets_another_point_ends_there(tmp_path: Path, caplog) -> None:
    run(tmp_path, objective(), polish=12)
    log = tmp_path / "log.jsonl"
    lines = log.read_text().splitlines()
    state = RunLog(log).read()
    sixth = sorted(r for r, rec in state.rounds.items() if rec["kind"] == POLISH)[5]
    out = []
    for line in lines:  # move the search's sixth point: as if another machine had logged it
        rec = json.loads(line)
        if rec.get("type") == "round" and rec["round"] == sixth:
            rec["unit"] = [[min(u + 0.01, 1.0) for u in rec["unit"][0]]]
        out.append(json.dumps(rec))
    log.write_text("\n".join(out) + "\n")
    with caplog.at_level("WARNING", logger="smcbayes.surrogate.polish"):
        bo = run(tmp_path, objective(), polish=12)
    assert bo.polish.evaluations == 5 and not bo.polish.converged
    assert sum("another point" in r.message for r in caplog.records) == 1


def test_the_progress_total_follows_the_search(caplog) -> None:
    """A search that converges before its budget ends the progress with one final line at
    the evaluations made; nothing is reported after it."""
    from smcbayes import progress
    from smcbayes.surrogate.calibration import progress_reporter
    from smcbayes.surrogate.loop import Progress

    progress.enable(interval_s=1e9)  # plain lines only when finished
    try:
        with caplog.at_level("INFO", logger="smcbayes.progress"):
            report = progress_reporter(10)
            for done in range(1, 8):
                report(Progress(done, 10, 1.0, 0.0, 0.0, 0))
            report(Progress(7, 7, 1.0, 0.0, 0.0, 0))  # the search converged early: done
            report(Progress(8, 7, 1.0, 0.0, 0.0, 0))
    finally:
        progress.enable(False)
    lines = [r.message for r in caplog.records if "calibration:" in r.message]
    # the first line, then the final one once: at 7 of 7, not 7 of 10 nor 8 of 7
    assert len(lines) == 2 and "1/10 eval" in lines[0] and "7/7 eval" in lines[1]


def test_the_report_states_the_search() -> None:
    from smcbayes.report.sections_run import _polish_row

    assert _polish_row(None) == []
    [(name, text)] = _polish_row({"evaluations": 600, "converged": False, "start_loss_kN2": 41.05,
                                  "best_loss_kN2": 12.5})
    assert name == "local search (forward model)"
    assert "600 evaluations (its budget spent)" in text and "41" in text and "12.5" in text
