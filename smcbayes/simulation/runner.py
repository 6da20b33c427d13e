"""One path for every batch of forward runs: a simulator behind an executor.

Calibration, the posterior's likelihood and sensitivities, the predictive bands and the
report's curves all run their forward batches through a :class:`Runner`: the run's own
simulator (native or external) wrapped in its objective, on the run's executor (in
process, a local process pool or a Dask cluster).  The runner counts the forward runs it
made, so every stage can say what it cost.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from types import TracebackType

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.parameters import ParameterSpace
from smcbayes.forward.result import SimulationResult
from smcbayes.simulation.executors.base import Executor
from smcbayes.simulation.executors.local import LocalExecutor
from smcbayes.simulation.objective import SimulatorObjective, Task, TaskResult

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


class Runner:
    """A run's simulator and objective bound to its executor.

    Args:
        objective: the run's objective (its simulator, data and loss).
        executor: where batches run (default: in this process).

    Attributes:
        forward_runs: parameter sets simulated so far, counted once per configuration.
    """

    def __init__(self, objective: SimulatorObjective, executor: Executor | None = None) -> None:
        self.objective = objective
        self.executor: Executor = executor if executor is not None else LocalExecutor(1)
        self.forward_runs = 0
        self._started = False

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
            self.executor.start(self.objective)
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

    def run(self, theta: Array, config_ids: Sequence[str], curves: bool = False) -> dict[str, list[TaskResult]]:
        """Evaluate ``theta`` ``(P, d)`` (free parameters, user units) on ``config_ids``.

        Returns each configuration's task results in row order.
        """
        self.start()
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        out: dict[str, list[TaskResult]] = {cid: [] for cid in config_ids}
        for result in self.executor.run(self._tasks(theta, config_ids, curves)):
            out[result.config_id].append(result)
        self.forward_runs += theta.shape[0] * len(out)
        for parts in out.values():
            parts.sort(key=lambda r: r.indices[0] if r.indices else -1)
        return out

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
