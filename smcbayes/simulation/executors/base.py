"""The executor contract and the factory used by the command line."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Protocol

from smcbayes.simulation.executors.local import LocalExecutor
from smcbayes.simulation.objective import Objective, Task, TaskResult


class Executor(Protocol):
    """Runs tasks of one objective; results come back as they finish.

    Attributes:
        rows_per_task: how many parameter vectors go into one task (``None``: all rows of
            a round per configuration, which suits batched solvers).

    An executor of a cluster may also have ``worker_timeout_s``: how long its tasks may
    wait with no worker before ``run`` raises :class:`~smcbayes.errors.SolverError`; the
    calibration sets it from ``[calibration] worker_timeout_s``.
    """

    rows_per_task: int | None

    def start(self, objective: Objective) -> None:
        """Bind the objective (ship it to the workers)."""
        ...

    def run(self, tasks: Sequence[Task]) -> Iterator[TaskResult]:
        """Yield one result per task, in completion order."""
        ...

    def close(self) -> None:
        """Release workers and connections."""
        ...


def make_executor(workers: int = 1, scheduler: str | None = None,
                  worker_timeout_s: float | None = None) -> Executor:
    """A Dask executor when ``scheduler`` is given (giving up after ``worker_timeout_s``
    without workers, default ``[calibration] worker_timeout_s``), else a local one with
    ``workers`` processes."""
    if scheduler:  # Dask is an optional extra: imported only when a cluster is named
        from smcbayes.simulation.executors.dask import WORKER_TIMEOUT_S, DaskExecutor

        return DaskExecutor(scheduler, worker_timeout_s=worker_timeout_s or WORKER_TIMEOUT_S)

    return LocalExecutor(workers)
