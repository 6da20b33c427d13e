"""The BO loop on analytic objectives: recovery, determinism, failures, tolerance rule."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from smcbayes.errors import ConfigError
from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.run.runlog import RunLog
from smcbayes.simulation.executors.local import LocalExecutor
from smcbayes.simulation.objective import FlakyObjective as FlakyObjectiveAttempts
from smcbayes.simulation.objective import InterruptingObjective, QuadraticObjective, Task, TaskResult
from smcbayes.surrogate.loop import BayesOpt, BOSettings, training_data


def slip_space() -> ParameterSpace:
    return ParameterSpace(BASE_PARAMETERS).with_fixed({"n": 0.4, "tau_star_Pa": 1e4, "B_Pa_s": 1e4})


def run(tmp: Path, objective, **kw) -> BayesOpt:
    settings = BOSettings(**{"budget": 14, "init": 5, "restarts": 4, "raw_samples": 64, **kw})
    tmp.mkdir(parents=True, exist_ok=True)
    return BayesOpt(objective, settings, RunLog(tmp / "log.jsonl"), LocalExecutor(1)).run()


class FlakyObjective:
    """Fails a pseudo-random ~20 % of (evaluation, configuration) pairs, reproducibly."""

    def __init__(self, inner: QuadraticObjective, share: float = 0.2) -> None:
        self.inner, self.share = inner, share
        self.space, self.config_ids = inner.space, inner.config_ids

    def evaluate(self, task: Task) -> TaskResult:
        res = self.inner.evaluate(task)
        err = res.error.copy()
        status = list(res.status)
        for j, i in enumerate(task.indices):
            h = int(hashlib.sha1(f"{i}".encode()).hexdigest()[:8], 16) / 16**8
            if h < self.share:
                err[j] = np.nan
                status[j] = "failed: injected solver failure"
        return TaskResult(res.indices, res.config_id, err, res.force_mse_kN2, res.displacement_mse_mm2,
                          status, res.seconds)


def test_recovers_minimum_of_analytic_objective(tmp_path: Path) -> None:
    space = slip_space()
    obj = QuadraticObjective(space, [0.02, 1.3], ["a", "b", "c"], seed=1)
    bo = run(tmp_path, obj, budget=20)
    best = bo.best()
    u = space.to_unit(np.array([[best["params"]["tau_c_MPa"], best["params"]["m"]]]))[0]
    assert np.all(np.abs(u - obj.truth_unit) < 0.05)
    assert len(bo.state.evaluations) == 20
    # loss is the mean of the configuration errors
    rec = bo.state.evaluations[7]
    assert rec["loss"] == pytest.approx(np.mean(list(rec["errors"].values())), rel=1e-12)


def test_same_seed_same_run_and_batches(tmp_path: Path) -> None:
    space = slip_space()
    obj = QuadraticObjective(space, [0.05, 1.6], ["a"], seed=0)
    a = run(tmp_path / "a", obj, batch=3, budget=11)
    b = run(tmp_path / "b", obj, batch=3, budget=11)
    c = run(tmp_path / "c", obj, batch=3, budget=11, seed=1)
    pa = [r["params"] for _, r in sorted(a.state.evaluations.items())]
    pb = [r["params"] for _, r in sorted(b.state.evaluations.items())]
    pc = [r["params"] for _, r in sorted(c.state.evaluations.items())]
    assert pa == pb and pa != pc
    assert [len(r["indices"]) for _, r in sorted(a.state.rounds.items())] == [5, 3, 3]


def test_twenty_percent_failures_are_logged_and_run_finishes(tmp_path: Path) -> None:
    space = slip_space()
    obj = FlakyObjective(QuadraticObjective(space, [0.02, 1.3], ["a", "b"], seed=1))
    bo = run(tmp_path, obj, budget=20)
    recs = [r for _, r in sorted(bo.state.evaluations.items())]
    failed = [r for r in recs if r["status"] != "ok"]
    assert len(recs) == 20 and 1 <= len(failed) <= 10
    assert all(r["loss"] is None and "injected solver failure" in r["reason"] for r in failed)
    assert bo.failures() == len(failed)
    x, y = training_data(bo.state, space.to_unit, space.free_names, "exclude")
    assert x.shape[0] == 20 - len(failed) and np.all(np.isfinite(y))
    x, y = training_data(bo.state, space.to_unit, space.free_names, "impute")
    assert x.shape[0] == 20 and np.max(y) == pytest.approx(np.log(np.nanmax(bo.losses())))


def test_tolerance_rule_stops_early(tmp_path: Path) -> None:
    space = slip_space()
    obj = QuadraticObjective(space, [0.02, 1.3], ["a"], seed=1)
    bo = run(tmp_path, obj, budget=60, tolerance=0.5, patience=2)
    assert len(bo.state.evaluations) < 60
    assert "over 2 rounds" in bo.stop_reason


def test_bad_settings_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="init"):
        BOSettings(budget=3, init=5).check()


NINE = [f"c{k}" for k in range(9)]


def test_retries_keep_evaluations_of_nine_flaky_configurations(tmp_path: Path) -> None:
    """20 % of runs fail at random: the default retries lose (almost) no evaluation."""
    space = slip_space()
    flaky = FlakyObjectiveAttempts(QuadraticObjective(space, [0.02, 1.3], NINE, seed=1), share=0.2, seed=3)
    bare = run(tmp_path / "bare", flaky, budget=12, init=12, retries=0)
    default = run(tmp_path / "default", flaky, budget=12, init=12)
    assert default.settings.retries == 3
    assert bare.failures() >= 6  # 1 - 0.8^9 = 87 % of evaluations lost without retries
    assert default.failures() <= 1
    assert len(default.state.evaluations) == 12


def test_interrupted_flaky_run_resumes_to_the_uninterrupted_run(tmp_path: Path) -> None:
    space = slip_space()
    flaky = FlakyObjectiveAttempts(QuadraticObjective(space, [0.02, 1.3], NINE[:3], seed=1), 0.3, seed=5)

    kw = {"budget": 10, "init": 4, "batch": 3}
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path / "cut", InterruptingObjective(flaky, 7), **kw)
    run(tmp_path / "cut", flaky, **kw)
    run(tmp_path / "whole", flaky, **kw)
    strip = lambda name: [{k: v for k, v in r.items() if k != "seconds"}  # noqa: E731
                          for _, r in sorted(
                              RunLog(tmp_path / name / "log.jsonl").read().evaluations.items())]
    assert strip("cut") == strip("whole") and len(strip("whole")) == 10
    assert any(r["status"] != "ok" for r in strip("whole"))


def test_a_run_whose_evaluations_all_fail_ends_at_its_budget(tmp_path: Path) -> None:
    space = slip_space()
    broken = FlakyObjectiveAttempts(QuadraticObjective(space, [0.02, 1.3], ["a", "b"]), share=1.0)
    bo = run(tmp_path, broken, budget=8, init=4, batch=2, retries=1)
    assert len(bo.state.evaluations) == 8 and bo.failures() == 8
    assert bo.best() is None and bo.stop_reason.startswith("budget")
    assert all("after 2 attempts" in r["reason"] for r in bo.state.evaluations.values())
