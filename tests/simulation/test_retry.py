"""Failed runs are retried below the optimiser, for every stage, deterministically."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from smcbayes.config import load_project
from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.forward.result import SimulationResult
from smcbayes.simulation.objective import FlakyObjective, QuadraticObjective, SimulatorObjective, Task
from smcbayes.simulation.problem import build_problem
from smcbayes.simulation.runner import RetryObjective, Runner

ROOT = Path(__file__).resolve().parents[2]
IDS = [f"c{k}" for k in range(9)]


def quadratic() -> QuadraticObjective:
    space = ParameterSpace(BASE_PARAMETERS).with_fixed({"n": 0.4, "tau_star_Pa": 1e4, "B_Pa_s": 1e4})
    return QuadraticObjective(space, [0.02, 1.3], IDS, seed=2)


class CountingQuadratic(QuadraticObjective):
    """Counts the rows it ran."""

    runs = 0

    def evaluate(self, task: Task):  # type: ignore[no-untyped-def]
        self.runs += len(task.indices)
        return super().evaluate(task)


def theta(rows: int) -> np.ndarray:
    q = quadratic()
    return q.space.from_unit(np.random.default_rng(0).random((rows, q.space.dim)))


def test_retries_turn_transient_failures_into_results() -> None:
    flaky = FlakyObjective(quadratic(), share=0.2, seed=1)
    task = Task(tuple(range(40)), theta(40), "c0")
    first = flaky.evaluate(task)
    failed_first = sum(s != "ok" for s in first.status)
    assert failed_first >= 4
    retried = RetryObjective(flaky, 3).evaluate(task)
    assert retried.status.count("ok") >= 39 and retried.retried >= failed_first
    ok = [j for j, s in enumerate(retried.status) if s == "ok"]
    np.testing.assert_array_equal(retried.error[ok], quadratic().evaluate(task).error[ok])
    # the same task retried again gives the same outcome (draws per evaluation and attempt)
    again = RetryObjective(flaky, 3).evaluate(task)
    assert again.status == retried.status and again.retried == retried.retried


def test_a_row_failed_on_every_attempt_names_the_attempts() -> None:
    always = FlakyObjective(quadratic(), share=1.0)
    res = RetryObjective(always, 2).evaluate(Task((0, 1), theta(2), "c3"))
    assert res.status == ["failed: injected transient failure (after 3 attempts)"] * 2
    assert np.all(np.isnan(res.error)) and res.retried == 4


def test_a_deterministic_objective_is_not_retried() -> None:
    counting = CountingQuadratic(quadratic().space, [0.02, 1.3], IDS)
    counting.deterministic = True
    RetryObjective(counting, 3).evaluate(Task((0, 1, 2), theta(3), "c0"))
    assert counting.runs == 3


class OnceFailing:
    """A simulator whose first run of each row fails (a transient fault), then succeeds."""

    def __init__(self, inner: object) -> None:
        self.inner, self.space, self.seen = inner, inner.space, set()  # type: ignore[attr-defined]

    def simulate(self, theta: np.ndarray, config_ids: Sequence[str]) -> dict[str, SimulationResult]:
        out = self.inner.simulate(theta, config_ids)  # type: ignore[attr-defined]
        for cid, res in out.items():
            for i, row in enumerate(theta):
                key = (cid, tuple(row))
                if key not in self.seen:
                    self.seen.add(key)
                    res.status[i] = "failed: licence server busy"
                    res.force_kN[i] = np.nan
        return out


def test_the_runner_of_every_stage_retries_and_counts_the_runs(tmp_path: Path) -> None:
    problem = build_problem(load_project(ROOT / "configs" / "verify-slip-2d.toml"), tmp_path / "run",
                            fidelity="1d")
    cid = problem.train_ids[0]
    flaky = SimulatorObjective(OnceFailing(problem.model), problem.dataset, [cid], problem.project.loss)
    assert not flaky.deterministic and problem.objective.deterministic
    points = np.array([[0.02, 1.2], [0.3, 1.8]])
    with Runner(flaky, retries=1) as runner:
        curves = runner.simulate(points, [cid])[cid]
        assert curves.status == ["ok", "ok"] and np.all(np.isfinite(curves.force_kN))
        assert runner.forward_runs == 4  # two rows, each run twice
    native = problem.model.simulate(points, [cid])[cid]
    np.testing.assert_allclose(curves.force_kN[:, :native.force_kN.shape[1]], native.force_kN)
    # the posterior's runner takes the run's [calibration] retries
    assert problem.runner().retries == problem.project.calibration.retries == 3
    with Runner(SimulatorObjective(OnceFailing(problem.model), problem.dataset, [cid]), retries=0) as bare:
        assert bare.simulate(points, [cid])[cid].status == ["failed: licence server busy"] * 2


@pytest.mark.parametrize("retries", [0, 3])
def test_retried_errors_fill_the_failed_rows(retries: int) -> None:
    with Runner(FlakyObjective(quadratic(), 0.2, seed=4),  # type: ignore[arg-type]
                retries=retries) as runner:
        errors = runner.errors(theta(12))
    missing = int(np.isnan(errors).sum())
    assert (missing == 0) if retries else (missing >= 10)
