"""Dask distributed execution: one task per candidate and configuration on a cluster."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

from smcbayes.errors import ConfigError
from smcbayes.simulation.objective import Objective, Task, TaskResult


def _import_distributed() -> Any:
    try:
        import distributed
    except ImportError:
        raise ConfigError("--scheduler needs Dask distributed; install it with "
                          "`pip install 'smcbayes[dask]'`") from None
    return distributed


def _evaluate(objective: Objective, task: Task) -> TaskResult:
    return objective.evaluate(task)


class DaskExecutor:
    """Submit tasks to a Dask scheduler; a lost worker's tasks are rerun elsewhere by Dask.

    Args:
        scheduler: address such as ``tcp://10.0.0.5:8786``, or a ``distributed.Client``.
        retries: extra attempts for a task that raised on a worker.
    """

    def __init__(self, scheduler: Any, retries: int = 2) -> None:
        self.scheduler = scheduler
        self.retries = retries
        self.rows_per_task: int | None = 1
        self._client: Any = None
        self._own_client = False
        self._objective: Any = None

    def start(self, objective: Objective) -> None:
        """Connect to the scheduler and ship the objective to every worker."""
        distributed = _import_distributed()
        if isinstance(self.scheduler, distributed.Client):
            self._client = self.scheduler
        else:
            try:
                self._client = distributed.Client(self.scheduler, timeout="30s")
            except OSError as err:
                raise ConfigError(f"--scheduler {self.scheduler}: cannot connect ({err}); "
                                  "start one with `dask scheduler` and `dask worker ADDRESS`") from None
            self._own_client = True
        self._objective = objective

    def run(self, tasks: Sequence[Task]) -> Iterator[TaskResult]:
        """Yield results as tasks finish on the cluster."""
        distributed = _import_distributed()
        futures = {}
        for task in tasks:
            fut = self._client.submit(_evaluate, self._objective, task, pure=False,
                                      retries=self.retries)
            futures[fut.key] = (fut, task)
        for fut in distributed.as_completed([f for f, _ in futures.values()]):
            task = futures[fut.key][1]
            try:
                yield fut.result()
            except distributed.KilledWorker as err:
                yield TaskResult.failed(task, f"Dask worker lost repeatedly ({err})")
            except (OSError, RuntimeError, ValueError, ArithmeticError) as err:
                yield TaskResult.failed(task, f"{type(err).__name__} on a Dask worker: {err}")

    def close(self) -> None:
        """Close the client if this executor opened it."""
        if self._own_client and self._client is not None:
            self._client.close()
        self._client = None
