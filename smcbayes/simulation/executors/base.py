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


def make_executor(workers: int = 1, scheduler: str | None = None) -> Executor:
    """A Dask executor when ``scheduler`` is given, else a local one with ``workers`` processes."""
    if scheduler:  # Dask is an optional extra: imported only when a cluster is named
        from smcbayes.simulation.executors.dask import DaskExecutor

        return DaskExecutor(scheduler)

    return LocalExecutor(workers)
