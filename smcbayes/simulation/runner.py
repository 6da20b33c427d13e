"""One path for every batch of forward runs: a simulator behind an executor.

Calibration, the posterior's likelihood and sensitivities, the predictive bands and the
report's curves all run their forward batches through a :class:`Runner`: the run's own
simulator (native or external) wrapped in its objective, on the run's executor (in
process, a local process pool or a Dask cluster).  The runner counts the forward runs it
made, so every stage can say what it cost.

Failed runs are retried here, in the executor layer, the way Dakota's failure capture
does ("retry N"; Adams et al., Dakota User's Manual, "Simulation Failure Capturing"): a
row whose simulation failed or timed out is run again, up to ``retries`` times, inside
the task that ran it (:class:`RetryObjective`), before it counts as failed.  Living below
the optimiser, the retries serve every stage alike (calibration, posterior, bands, best
curves) on every executor (in process, pool, Dask worker), and they keep runs
deterministic and resumable: a task's outcome depends only on its rows and their attempt
numbers, and the evaluation log records an evaluation only once all its attempts are
done, so a resumed run repeats exactly the attempts an uninterrupted run makes.  The
native model is deterministic (a retry fails the same way), so its failures are not
retried; the retries are for external solvers that fail transiently.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from types import TracebackType
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.parameters import ParameterSpace
from smcbayes.forward.result import STATUS_OK, SimulationResult
from smcbayes.simulation.executors.base import Executor
from smcbayes.simulation.executors.local import LocalExecutor
from smcbayes.simulation.objective import Objective, SimulatorObjective, Task, TaskResult

Array = NDArray[np.float64]


def _pad(values: Array, length: int, hold: bool) -> Array:
    """``(P, T)`` -> ``(P, length)``, holding each row's end value (or NaN)."""
    extra = length - values.shape[1]
    if extra <= 0:
        return values
    tail = np.repeat(values[:, -1:], extra, axis=1) if hold else np.full((values.shape[0], extra), np.nan)
    return np.concatenate([values, tail], axis=1)


def _pad_time(time_s: Array, length: int) -> Array:
    extra = length - time_s.shape[1]
    if extra <= 0:
        return time_s
    steps = time_s[:, -1:] + 1e-9 * np.arange(1, extra + 1)[None, :]
    return np.concatenate([time_s, steps], axis=1)


def concat_rows(parts: Sequence[SimulationResult]) -> SimulationResult:
    """Stack the rows of several results of one configuration (curves padded to a common
    length by holding their end values, as the external adapter does)."""
    if len(parts) == 1:
        return parts[0]
    length = max(p.time_s.shape[1] for p in parts)

    def cat(name: str) -> Array:
        return np.concatenate([_pad(getattr(p, name), length, hold=True) for p in parts])

    return SimulationResult(
        parts[0].config_id, np.concatenate([_pad_time(p.time_s, length) for p in parts]),
        cat("gap_mm"), cat("displacement_mm"), cat("force_kN"), cat("fill_fraction"),
        cat("solid_fraction"), cat("phase").astype(np.int8),
        np.concatenate([p.switch_time_s for p in parts]), [s for p in parts for s in p.status],
        parts[0].effects)


class RunCache(Protocol):
    """Forward runs kept from earlier batches (implemented by the run layer's
    :class:`~smcbayes.run.cache.ForwardCache`), keyed by configuration and parameter row."""

    def lookup(self, config_id: str, theta: Array, curves: bool) -> list[TaskResult | None]:
        """Per row of ``theta`` ``(P, d)``: its one-row result (with curves if ``curves``), or ``None``."""
        ...

    def begin(self, runs: int) -> None:
        """``runs`` forward runs (rows x configurations) are about to be made."""
        ...

    def store(self, result: TaskResult, theta: Array) -> None:
        """Keep a finished task's rows; ``theta`` ``(len(result.indices), d)`` are its rows."""
        ...

    def commit(self) -> None:
        """Make everything stored so far durable (the end of a batch)."""
        ...


def _take(result: SimulationResult, rows: Sequence[int]) -> SimulationResult:
    """The ``rows`` of a result, as a result of their own."""
    idx = list(rows)
    return SimulationResult(result.config_id, result.time_s[idx], result.gap_mm[idx],
                            result.displacement_mm[idx], result.force_kN[idx], result.fill_fraction[idx],
                            result.solid_fraction[idx], result.phase[idx], result.switch_time_s[idx],
                            [result.status[i] for i in idx], result.effects)


class RetryObjective:
    """An objective whose failed rows are run again, up to ``retries`` times.

    The rows of a task that come back failed (``"failed: reason"``: a solver error, a
    timeout, a non-finite curve) form a smaller task with ``attempt`` 1, 2, ... and replace
    their failed results when they succeed; a row still failed after the last attempt
    keeps its last reason, with the number of attempts.  A ``deterministic`` inner
    objective (the native model) is not retried: its failure would repeat.  Picklable when
    the inner objective is, so it runs on the executor's workers.

    Args:
        inner: the objective to retry.
        retries: extra attempts per failed row (0: none).
    """

    def __init__(self, inner: Objective, retries: int) -> None:
        self.inner = inner
        self.retries = retries
        self.space = inner.space
        self.config_ids = inner.config_ids

    def evaluate(self, task: Task) -> TaskResult:
        """The task's results, its failed rows retried (attempts counted in ``retried``)."""
        result = self.inner.evaluate(task)
        if self.retries <= 0 or getattr(self.inner, "deterministic", False):
            return result
        error, force = result.error.copy(), result.force_mse_kN2.copy()
        disp, status = result.displacement_mse_mm2.copy(), list(result.status)
        # which result holds each row's curves, and at which of its rows
        source: list[tuple[TaskResult, int]] = [(result, j) for j in range(len(task.indices))]
        seconds, retried, attempt = result.seconds, 0, 0
        failed = [j for j, s in enumerate(status) if s != STATUS_OK]
        while failed and attempt < self.retries:
            attempt += 1
            again = self.inner.evaluate(Task(tuple(task.indices[j] for j in failed), task.theta[failed],
                                             task.config_id, task.curves, attempt))
            seconds += again.seconds
            retried += len(failed)
            for k, j in enumerate(failed):
                error[j], force[j] = again.error[k], again.force_mse_kN2[k]
                disp[j], status[j] = again.displacement_mse_mm2[k], again.status[k]
                source[j] = (again, k)
            failed = [j for j in failed if status[j] != STATUS_OK]
        for j in failed:
            status[j] = f"{status[j]} (after {attempt + 1} attempts)"
        curves = _merge_curves(task, source, status) if task.curves else None
        return TaskResult(result.indices, result.config_id, error, force, disp, status, seconds,
                          curves, result.retried + retried)


def _merge_curves(task: Task, source: Sequence[tuple[TaskResult, int]],
                  status: list[str]) -> SimulationResult | None:
    """One result of the task's rows, each taken from the attempt that last ran it."""
    if all(r.curves is None for r, _ in source):
        return None
    parts = []
    for r, k in source:
        if r.curves is None:  # the whole attempt failed: NaN rows shaped like the others
            part = _failed_curves(r, [p for p, _ in source])
            parts.append(_take(part, [k]))
        else:
            parts.append(_take(r.curves, [k]))
    merged = concat_rows(parts)
    return SimulationResult(merged.config_id, merged.time_s, merged.gap_mm, merged.displacement_mm,
                            merged.force_kN, merged.fill_fraction, merged.solid_fraction, merged.phase,
                            merged.switch_time_s, list(status), merged.effects)


def with_retries(objective: Objective, retries: int) -> Objective:
    """``objective`` with its failed rows retried ``retries`` times (itself when 0)."""
    return RetryObjective(objective, retries) if retries > 0 else objective


class Runner:
    """A run's simulator and objective bound to its executor.

    Args:
        objective: the run's objective (its simulator, data and loss).
        executor: where batches run (default: in this process).
        cache: earlier forward runs to reuse and where to keep new ones (``None``: none).
        retries: extra attempts of a failed row (:class:`RetryObjective`).

    Attributes:
        forward_runs: parameter sets asked for so far, counted once per configuration
            (made or reused: what shaped the results), failed attempts that were retried
            included.
        forward_runs_reused: of those, the ones taken from ``cache``.
    """

    def __init__(self, objective: SimulatorObjective, executor: Executor | None = None,
                 cache: RunCache | None = None, retries: int = 0) -> None:
        self.objective = objective
        self.executor: Executor = executor if executor is not None else LocalExecutor(1)
        self.cache = cache
        self.retries = retries
        self.forward_runs = 0
        self.forward_runs_reused = 0
        self._started = False

    @property
    def forward_runs_made(self) -> int:
        """Forward runs simulated by this runner (not taken from the cache)."""
        return self.forward_runs - self.forward_runs_reused

    @property
    def space(self) -> ParameterSpace:
        """The parameter space of the simulator."""
        return self.objective.space

    def __enter__(self) -> Runner:
        self.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def start(self) -> None:
        """Start the executor (ship the objective to its workers) if not yet started."""
        if not self._started:
            self.executor.start(with_retries(self.objective, self.retries))
            self._started = True

    def close(self) -> None:
        """Release the executor's workers."""
        if self._started:
            self.executor.close()
            self._started = False

    def _tasks(self, theta: Array, config_ids: Iterable[str], curves: bool) -> list[Task]:
        rows = theta.shape[0]
        size = self.executor.rows_per_task or max(rows, 1)
        return [Task(tuple(range(lo, min(lo + size, rows))), theta[lo:lo + size], cid, curves)
                for cid in config_ids for lo in range(0, rows, size)]

    def run(self, theta: Array, config_ids: Sequence[str],
            curves: bool = False) -> dict[str, list[TaskResult]]:
        """Evaluate ``theta`` ``(P, d)`` (free parameters, user units) on ``config_ids``.

        Returns each configuration's task results in row order.
        """
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        if self.cache is not None:
            return self._run_cached(self.cache, theta, config_ids, curves)
        self.start()
        out: dict[str, list[TaskResult]] = {cid: [] for cid in config_ids}
        for result in self.executor.run(self._tasks(theta, config_ids, curves)):
            out[result.config_id].append(result)
            self.forward_runs += result.retried
        self.forward_runs += theta.shape[0] * len(out)
        for parts in out.values():
            parts.sort(key=lambda r: r.indices[0] if r.indices else -1)
        return out

    def _run_cached(self, cache: RunCache, theta: Array, config_ids: Sequence[str],
                    curves: bool) -> dict[str, list[TaskResult]]:
        """:meth:`run` through ``cache``: only rows it lacks are simulated, and they are
        kept (durably at the end of the batch).  Returns one result per configuration,
        rows in order, whatever mix of kept and new rows made it."""
        hits = {cid: cache.lookup(cid, theta, curves) for cid in dict.fromkeys(config_ids)}
        size = self.executor.rows_per_task
        tasks = []
        for cid, rows in hits.items():
            missing = [i for i, h in enumerate(rows) if h is None]
            step = size or max(len(missing), 1)
            tasks += [Task(tuple(missing[lo:lo + step]), theta[missing[lo:lo + step]], cid, curves)
                      for lo in range(0, len(missing), step)]
        made = sum(len(t.indices) for t in tasks)
        fresh: dict[str, list[TaskResult]] = {cid: [] for cid in hits}
        if tasks:
            self.start()
            cache.begin(made)
            for result in self.executor.run(tasks):
                cache.store(result, theta[list(result.indices)])
                fresh[result.config_id].append(result)
                self.forward_runs += result.retried
            cache.commit()
        self.forward_runs += theta.shape[0] * len(hits)
        self.forward_runs_reused += theta.shape[0] * len(hits) - made
        return {cid: [_merge(theta.shape[0], cid, rows, fresh[cid], curves)] for cid, rows in hits.items()}

    def simulate(self, theta: Array, config_ids: Sequence[str]) -> dict[str, SimulationResult]:
        """Curves of ``theta`` ``(P, d)`` on each configuration (the :class:`Simulator` contract)."""
        out = {}
        for cid, parts in self.run(theta, config_ids, curves=True).items():
            curves = [r.curves if r.curves is not None else _failed_curves(r, parts) for r in parts]
            out[cid] = concat_rows(curves)
        return out

    def errors(self, theta: Array, config_ids: Sequence[str] | None = None) -> Array:
        """Per-configuration loss terms ``(P, K)`` of ``theta`` (NaN where a row failed)."""
        ids = list(self.objective.config_ids if config_ids is None else config_ids)
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        out = np.full((theta.shape[0], len(ids)), np.nan)
        for k, (_, parts) in enumerate(self.run(theta, ids).items()):
            for r in parts:
                out[list(r.indices), k] = r.error
        return out

    def loss(self, theta: Array) -> Array:
        """Global loss ``(P,)`` of ``theta`` on the objective's configurations: the mean of
        the per-configuration terms (thesis eq. 3.7), NaN where any failed."""
        return np.mean(self.errors(theta), axis=1)


def _row_curves(result: SimulationResult, i: int) -> SimulationResult:
    """Row ``i`` of ``result`` as a one-row result."""
    def take(name: str) -> Array:
        return getattr(result, name)[i:i + 1]

    return SimulationResult(result.config_id, take("time_s"), take("gap_mm"), take("displacement_mm"),
                            take("force_kN"), take("fill_fraction"), take("solid_fraction"),
                            take("phase"), take("switch_time_s"), [result.status[i]], result.effects)


def _merge(rows: int, config_id: str, kept: Sequence[TaskResult | None], fresh: Sequence[TaskResult],
           curves: bool) -> TaskResult:
    """One result of ``rows`` rows (indices ``0..rows-1``) from kept one-row results and the
    new tasks' results (whose indices are row numbers)."""
    error, force, disp = (np.full(rows, np.nan) for _ in range(3))
    status = [""] * rows
    parts: list[SimulationResult | None] = [None] * rows
    seconds = 0.0
    for i, h in enumerate(kept):
        if h is not None:
            error[i], force[i], disp[i] = h.error[0], h.force_mse_kN2[0], h.displacement_mse_mm2[0]
            status[i] = h.status[0]
            parts[i] = h.curves
    for r in fresh:
        idx = list(r.indices)
        error[idx], force[idx], disp[idx] = r.error, r.force_mse_kN2, r.displacement_mse_mm2
        seconds += r.seconds
        full = r.curves if r.curves is not None else _failed_curves(r, fresh) if curves else None
        for j, i in enumerate(idx):
            status[i] = r.status[j]
            parts[i] = None if full is None else _row_curves(full, j)
    joined = None
    if curves and rows:
        joined = concat_rows([p if p is not None else _failed_curves(
            TaskResult((i,), config_id, error[i:i + 1], force[i:i + 1], disp[i:i + 1], [status[i]], 0.0),
            fresh) for i, p in enumerate(parts)])
    return TaskResult(tuple(range(rows)), config_id, error, force, disp, status, seconds, joined)


def _failed_curves(result: TaskResult, parts: Sequence[TaskResult]) -> SimulationResult:
    """NaN curves for the rows of a task that failed as a whole (a lost worker), shaped
    like a successful part of the same batch."""
    template = next((r.curves for r in parts if r.curves is not None), None)
    n = len(result.indices)
    length = 2 if template is None else template.time_s.shape[1]
    nan = np.full((n, length), np.nan)
    return SimulationResult(result.config_id, nan, nan.copy(), nan.copy(), nan.copy(), nan.copy(),
                            nan.copy(), np.zeros((n, length), dtype=np.int8), np.full(n, np.nan),
                            list(result.status), () if template is None else template.effects)
