"""The Bayesian-optimisation loop (thesis Algorithm 1), resumable and executor-agnostic.

Round 0 evaluates a Latin hypercube design; every later round fits the GP to all finished
evaluations of the earlier rounds and proposes ``batch`` candidates by (q)LogEI.  A
round's candidates are logged before they run, and each evaluation as soon as all its
configurations are done, so a run killed at any moment resumes where it stopped, and
(every random step being seeded from the run seed and the round) ends exactly where an
uninterrupted run ends.

A simulation that fails is retried ``retries`` times inside its task, below the loop
(:class:`~smcbayes.simulation.runner.RetryObjective`, as every stage's runner does), so
the loop sees a configuration as failed only once its attempts are used up.  The loss
stays honest: an evaluation with a configuration still failed is failed (its loss, the
mean over all configurations, does not exist), logged with the reasons, and given to the
GP at the worst loss seen (``failed = "impute"``) or left out (``"exclude"``).  A run
whose evaluations all fail proposes at random and ends at its budget.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import CalibrationSpec
from smcbayes.run.runlog import LogState, RunLog
from smcbayes.simulation.executors.base import Executor
from smcbayes.simulation.objective import Objective, Task, TaskResult, combine
from smcbayes.simulation.runner import RunCache, with_retries
from smcbayes.surrogate.design import latin_hypercube, round_rng, round_seed
from smcbayes.surrogate.polish import POLISH, PolishResult, is_search, phase_rounds, run_polish

Array = NDArray[np.float64]


BOSettings = CalibrationSpec
"""The loop's settings are the ``[calibration]`` table (one model, one set of defaults)."""


@dataclass(frozen=True)
class Progress:
    """What the loop reports after each finished evaluation."""

    done: int
    budget: int
    best_loss: float
    elapsed_s: float
    remaining_s: float
    failures: int


def training_data(state: LogState, space_to_unit: Callable[[Array], Array], names: list[str],
                  failed: str, before_round: int | None = None) -> tuple[Array, Array]:
    """GP inputs ``(N, d)`` (unit cube) and targets ``(N,)`` (log loss) from the log.

    Failed evaluations are left out (``failed="exclude"``) or given the worst successful
    log loss (``"impute"``), which steers the search away from where the solver fails.
    """
    recs = [r for i, r in sorted(state.evaluations.items())
            if before_round is None or r["round"] < before_round]
    recs = thin_polish(recs, state)
    if not recs:
        return np.zeros((0, len(names))), np.zeros(0)
    theta = np.array([[r["params"][n] for n in names] for r in recs], dtype=float)
    loss = np.array([r["loss"] if r["loss"] is not None else np.nan for r in recs], dtype=float)
    ok = np.isfinite(loss) & (loss > 0)
    y = np.full(loss.shape, np.nan)
    y[ok] = np.log(loss[ok])
    if failed == "impute" and ok.any():
        y[~ok] = y[ok].max()
        keep = np.ones_like(ok)
    else:
        keep = ok
    return space_to_unit(theta[keep]), y[keep]


def search_points(state: LogState, space_to_unit: Callable[[Array], Array],
                  names: list[str]) -> tuple[Array, Array]:
    """Every evaluation of the local searches with a finite positive loss, as GP inputs
    ``(M, d)`` (unit cube) and targets ``(M,)`` (log loss, kN^2), in log order: what
    :func:`thin_polish` reduces to each search's best."""
    recs = [r for _, r in sorted(state.evaluations.items())
            if is_search(state, r["round"]) and r["loss"] is not None
            and np.isfinite(r["loss"]) and r["loss"] > 0]
    if not recs:
        return np.zeros((0, len(names))), np.zeros(0)
    theta = np.array([[r["params"][n] for n in names] for r in recs], dtype=float)
    return space_to_unit(theta), np.log(np.array([r["loss"] for r in recs], dtype=float))


def thin_polish(recs: list[dict[str, Any]], state: LogState) -> list[dict[str, Any]]:
    """``recs`` with the local searches' evaluations reduced to the best of each search.

    Powell's line searches put hundreds of points a hair apart along a few directions:
    as GP training data they would add nothing but ill-conditioning and cost, while the
    best point they found is what the GP must know."""
    phase_of = _search_starts(state)
    kept, best = [], {}
    for r in recs:
        phase = phase_of.get(r["round"])
        if phase is None:
            kept.append(r)
        elif r["loss"] is not None and (phase not in best or r["loss"] < best[phase]["loss"]):
            best[phase] = r
    return sorted(kept + list(best.values()), key=lambda r: r["index"])


def _search_starts(state: LogState) -> dict[int, int]:
    """Round -> the first round of its local search, for every round of a local search."""
    out: dict[int, int] = {}
    first = -1
    for rnd in sorted(state.rounds):
        if not is_search(state, rnd):
            first = -1
            continue
        if first < 0 or rnd - 1 not in out:
            first = rnd
        out[rnd] = first
    return out


class BayesOpt:
    """One calibration run over an objective, logged in ``log``.

    Args:
        objective: evaluates parameter vectors on configurations.
        settings: loop settings.
        log: the run's evaluation log (may hold a previous, interrupted run).
        executor: where evaluations run (started by :meth:`run`).
        on_progress: called after every finished evaluation.
        on_round: called after each round with the loop (e.g. to write the summary).
        polish: most evaluations of the local search from the best point once the
            optimisation has stopped (:mod:`smcbayes.surrogate.polish`); 0: none.
        cache: where the design's and the optimisation's evaluations keep their simulated
            curves (not the local search's, which are many and near one point): the GP's
            training points, from which the posterior's curve emulator starts, so that it
            need not simulate them again; ``None``: kept nowhere.
    """

    def __init__(self, objective: Objective, settings: BOSettings, log: RunLog, executor: Executor,
                 on_progress: Callable[[Progress], None] | None = None,
                 on_round: Callable[[BayesOpt], None] | None = None, polish: int = 0,
                 cache: RunCache | None = None) -> None:
        settings.check()
        self.objective = objective
        self.space = objective.space
        self.settings = settings
        self.log = log
        self.executor = executor
        self.on_progress = on_progress
        self.on_round = on_round
        self.state = LogState()
        self.stop_reason = ""
        self._start = time.perf_counter()
        self._evaluated_now = 0
        self.last_surrogate: Any = None
        self.last_candidate: Array | None = None
        self.polish_budget = polish
        self.cache = cache
        self.polish: PolishResult | None = None
        self._search_from: int | None = None

    # -- bookkeeping ---------------------------------------------------------------
    def losses(self) -> Array:
        """Loss of every logged evaluation in index order, NaN for failures, ``(N,)``."""
        return np.array([r["loss"] if r["loss"] is not None else np.nan
                         for _, r in sorted(self.state.evaluations.items())], dtype=float)

    def best(self) -> dict[str, Any] | None:
        """The evaluation record with the lowest loss (earliest on ties), or ``None``."""
        ok = [r for _, r in sorted(self.state.evaluations.items()) if r["loss"] is not None]
        return min(ok, key=lambda r: r["loss"]) if ok else None

    def failures(self) -> int:
        """Number of failed evaluations."""
        return sum(1 for r in self.state.evaluations.values() if r["status"] != "ok")

    def _best_after(self, rnd: int) -> float:
        """Best loss of the optimisation's own evaluations (a local search's left out) up to
        round ``rnd``."""
        vals = [r["loss"] for r in self.state.evaluations.values()
                if r["round"] <= rnd and r["loss"] is not None
                and not is_search(self.state, r["round"])]
        return min(vals) if vals else math.inf

    def _should_stop(self, searched_rounds: list[int], proposed: int) -> bool:
        """Whether the optimisation stops: ``proposed`` evaluations of its ``searched_rounds``
        (the design's and its own rounds, in order; a local search's never count, so a rerun
        takes the decision the first run took)."""
        s = self.settings
        if proposed >= s.budget:
            self.stop_reason = f"budget of {s.budget} evaluations reached"
            return True
        bo_rounds = len(searched_rounds) - 1  # rounds completed after the initial design
        if s.tolerance > 0 and bo_rounds >= s.patience:
            old = self._best_after(searched_rounds[-1 - s.patience])
            new = self._best_after(searched_rounds[-1])
            if math.isfinite(old) and old - new < s.tolerance * abs(old):
                self.stop_reason = (f"best loss improved by less than {s.tolerance:.3g} "
                                    f"(relative) over {s.patience} rounds")
                return True
        return False

    # -- proposing -------------------------------------------------------------------
    def _propose(self, rnd: int, proposed: int) -> Array:
        s = self.settings
        if rnd == 0:
            return latin_hypercube(min(s.init, s.budget), self.space.dim, round_rng(s.seed, 0))
        q = min(s.batch, s.budget - proposed)
        x, y = training_data(self.state, self.space.to_unit, self.space.free_names, s.failed, rnd)
        if x.shape[0] < 2 or np.ptp(y) == 0:
            return round_rng(s.seed, rnd).random((q, self.space.dim))
        # torch: loaded once a GP is fitted, so a loop on a test objective stays light
        from smcbayes.surrogate.acquisition import propose
        from smcbayes.surrogate.gp import fit_surrogate, gp_session

        seed = round_seed(s.seed, rnd)
        with gp_session():
            self.last_surrogate = fit_surrogate(x, y, s.kernel, seed, s.noise_variance)
            cand, _ = propose(self.last_surrogate, q, seed, s.restarts, s.raw_samples,
                              self._local_box(proposed))
        return cand

    def _local_box(self, proposed: int) -> tuple[Array, Array] | None:
        """Trust region around the best point for the final ``local_evaluations``."""
        s = self.settings
        best = self.best()
        if best is None or s.local_evaluations <= 0 or s.budget - proposed > s.local_evaluations:
            return None
        u = self.space.to_unit(np.array([[best["params"][n] for n in self.space.free_names]]))[0]
        lo = np.clip(u - s.local_radius, 0.0, 1.0)
        return lo, np.clip(lo + 2 * s.local_radius, 0.0, 1.0)

    def log_round(self, rnd: int, first_index: int, unit: Array, kind: str | None = None) -> dict[str, Any]:
        """Log round ``rnd``'s candidates ``unit`` ``(q, d)`` (unit cube), evaluations
        ``first_index`` on, before they run; ``kind`` defaults to ``init`` for round 0, else
        ``bo``."""
        theta = self.space.from_unit(unit)
        kind = kind or ("init" if rnd == 0 else "bo")
        record = {"type": "round", "round": rnd, "kind": kind,
                  "indices": list(range(first_index, first_index + unit.shape[0])),
                  "unit": unit.tolist(), "params": theta.tolist(),
                  "names": self.space.free_names, "seed": round_seed(self.settings.seed, rnd)}
        self.log.append(record)
        self.state.rounds[rnd] = record
        return record

    # -- evaluating --------------------------------------------------------------------
    def _tasks(self, indices: list[int], theta: Array, curves: bool = False) -> list[Task]:
        size = self.executor.rows_per_task or max(len(indices), 1)
        tasks = []
        for cid in self.objective.config_ids:
            for lo in range(0, len(indices), size):
                tasks.append(Task(tuple(indices[lo:lo + size]), theta[lo:lo + size], cid, curves))
        return tasks

    def _record(self, index: int, rnd: int, theta_row: Array,
                parts: dict[str, tuple[TaskResult, int]]) -> dict[str, Any]:
        """The log record of evaluation ``index`` from its configurations' (result, row) pairs."""
        ids = self.objective.config_ids
        errors = {c: float(parts[c][0].error[parts[c][1]]) for c in ids}
        reasons = [f"{c}: {parts[c][0].status[parts[c][1]]}" for c in ids
                   if parts[c][0].status[parts[c][1]] != "ok"]
        loss = combine(errors, ids)
        if not reasons and not (math.isfinite(loss) and loss > 0):
            reasons = [f"loss {loss!r} is not finite and positive"]
        seconds = sum(parts[c][0].seconds / len(parts[c][0].indices) for c in ids)
        params = self.space.batch(theta_row[None, :])
        return {"type": "evaluation", "index": index, "round": rnd,
                "params": {k: float(v[0]) for k, v in params.items()},
                "errors": errors,
                "force_mse_kN2": {c: float(parts[c][0].force_mse_kN2[parts[c][1]]) for c in ids},
                "displacement_mse_mm2": {c: float(parts[c][0].displacement_mse_mm2[parts[c][1]])
                                         for c in ids},
                "loss": None if reasons else loss, "status": "failed" if reasons else "ok",
                "reason": "; ".join(reasons) or None, "seconds": seconds}

    def evaluate_round(self, record: dict[str, Any]) -> None:
        """Run the evaluations of a logged round that the log does not hold yet, logging each
        as soon as all its configurations are done."""
        rnd = record["round"]
        theta_all = np.array(record["params"], dtype=float)
        rows = [(i, k) for k, i in enumerate(record["indices"]) if i not in self.state.evaluations]
        if not rows:
            return
        indices = [i for i, _ in rows]
        theta = theta_all[[k for _, k in rows]]
        row_of = {i: theta[j] for j, i in enumerate(indices)}
        pending: dict[int, dict[str, tuple[TaskResult, int]]] = {i: {} for i in indices}
        n_cfg = len(self.objective.config_ids)
        cache = None if self.cache is None or is_search(self.state, rnd) else self.cache
        if cache is not None:
            cache.begin(len(indices) * n_cfg)
        for result in self.executor.run(self._tasks(indices, theta, curves=cache is not None)):
            if cache is not None:
                # kept before the evaluation is logged: a logged evaluation has its curves
                cache.store(result, np.array([row_of[i] for i in result.indices]))
            for j, i in enumerate(result.indices):
                pending[i][result.config_id] = (result, j)
                if len(pending[i]) == n_cfg:
                    rec = self._record(i, rnd, row_of[i], pending.pop(i))
                    self.log.append(rec)
                    self.state.evaluations[i] = rec
                    self._evaluated_now += 1
                    self._report()
        if cache is not None:
            cache.commit()

    def _report(self, final: bool = False) -> None:
        """Progress after an evaluation; ``final``: the run is done (a local search that
        converged ends before its budget)."""
        if self.on_progress is None:
            return
        done = len(self.state.evaluations)
        best = self.best()
        elapsed = time.perf_counter() - self._start
        rate = elapsed / self._evaluated_now if self._evaluated_now else math.nan
        # earlier local searches (before a raised budget) count as done work; a search the
        # log ends with is the one about to be replayed, not an earlier one
        current = self._search_from if self._search_from is not None else \
            next(iter(phase_rounds(self.state)), math.inf)
        earlier = sum(1 for r in self.state.evaluations.values()
                      if is_search(self.state, r["round"]) and r["round"] < current)
        total = done if final else max(self.settings.budget + earlier + self.polish_budget, done)
        remaining = rate * max(total - done, 0)
        self.on_progress(Progress(done, total, best["loss"] if best else math.nan,
                                  elapsed, remaining, self.failures()))

    # -- the loop ----------------------------------------------------------------------
    def run(self) -> BayesOpt:
        """Run (or resume) until the budget or the tolerance rule stops it, then the local
        search from the best point (``polish``)."""
        self.state = self.log.read(repair=True)
        self._start = time.perf_counter()
        if hasattr(self.executor, "worker_timeout_s"):  # a cluster executor: the run's patience
            self.executor.worker_timeout_s = self.settings.worker_timeout_s
        self.executor.start(with_retries(self.objective, self.settings.retries))
        try:
            rnd = self._optimise()
            phase = phase_rounds(self.state)
            self._search_from = phase[0] if phase else rnd
            # the summaries written during the search say the run is still running
            reason, self.stop_reason = self.stop_reason, ""
            self.polish = run_polish(self, self.polish_budget, self._search_from,
                                     lambda: self.on_round(self) if self.on_round is not None else None)
            self.stop_reason = reason
            if self.polish is not None:
                self.stop_reason += (f"; then {self.polish.evaluations} evaluations of a local search "
                                     f"({'converged' if self.polish.converged else 'its budget spent'})")
                if self.on_round is not None:
                    self.on_round(self)
            self._report(final=True)
        finally:
            self.executor.close()
        return self

    def _optimise(self) -> int:
        """The design and the optimisation's rounds (those of the log first); returns the
        number of the first round not logged.  A local search's rounds in the log are
        completed but count neither towards the budget nor as proposals."""
        rnd, index, searched = 0, 0, 0
        searched_rounds: list[int] = []
        while True:
            record = self.state.rounds.get(rnd)
            if record is None:
                if self._should_stop(searched_rounds, searched):
                    return rnd
                record = self.log_round(rnd, index, self._propose(rnd, searched))
            local = record.get("kind") == POLISH
            if not local:
                self.last_candidate = np.array(record["unit"], dtype=float)
                searched += len(record["indices"])
                searched_rounds.append(rnd)
            self.evaluate_round(record)
            index += len(record["indices"])
            rnd += 1
            # a logged local search is replayed by hundreds of one-point rounds: no summary each
            if self.on_round is not None and not local:
                self.on_round(self)

    def settings_dict(self) -> dict[str, Any]:
        """The settings as a plain dict (for the summary)."""
        return self.settings.model_dump(mode="json")
