"""Dask distributed execution: one task per candidate and configuration on a cluster.

Dask reruns the tasks of a lost worker elsewhere, but with no worker left it waits for
one forever; the executor instead stops with a :class:`~smcbayes.errors.SolverError`
after ``worker_timeout_s`` without any worker, so the run ends and resumes (``--resume``)
once workers are back.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from typing import Any

from smcbayes.config import CalibrationSpec
from smcbayes.errors import ConfigError, SolverError
from smcbayes.simulation.objective import Objective, Task, TaskResult

WORKER_TIMEOUT_S: float = CalibrationSpec.model_fields["worker_timeout_s"].default
POLL_S = 1.0
"""Longest wait (s) for a result before the executor looks for workers again."""


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
        worker_timeout_s: how long (s) tasks may wait with no worker at all before
            :meth:`run` raises (the calibration sets it from ``[calibration]``).
    """

    def __init__(self, scheduler: Any, retries: int = 2, worker_timeout_s: float = WORKER_TIMEOUT_S) -> None:
        self.scheduler = scheduler
        self.retries = retries
        self.worker_timeout_s = worker_timeout_s
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
        """Yield results as tasks finish on the cluster.

        Raises:
            SolverError: no worker was connected for ``worker_timeout_s`` while tasks waited
                (their futures are cancelled; finished results were yielded already).
        """
        distributed = _import_distributed()
        order = {}
        for n, task in enumerate(tasks):
            fut = self._client.submit(_evaluate, self._objective, task, pure=False,
                                      retries=self.retries)
            order[fut.key] = (n, fut, task)
        pending = {fut for _, fut, _ in order.values()}
        alone_since: float | None = None
        while pending:
            try:
                done, _ = distributed.wait(list(pending), timeout=min(POLL_S, self.worker_timeout_s),
                                           return_when="FIRST_COMPLETED")
            except TimeoutError:  # nothing finished in this poll
                done = set()
            for fut in sorted(done, key=lambda f: order[f.key][0]):
                pending.discard(fut)
                yield self._result(fut, order[fut.key][2], distributed)
            if done or self._workers() > 0:
                alone_since = None
                continue
            alone_since = time.monotonic() if alone_since is None else alone_since
            if time.monotonic() - alone_since >= self.worker_timeout_s:
                self._client.cancel(list(pending))
                address = self._client.scheduler.address
                raise SolverError(f"no Dask worker left at {address} for {self.worker_timeout_s:g} s; "
                                  f"start workers with `dask worker {address}` and resume with --resume")

    def _workers(self) -> int:
        """Workers connected to the scheduler now."""
        return len(self._client.nthreads())

    @staticmethod
    def _result(fut: Any, task: Task, distributed: Any) -> TaskResult:
        try:
            return fut.result()
        except distributed.KilledWorker as err:
            return TaskResult.failed(task, f"Dask worker lost repeatedly ({err})")
        except OSError as err:  # the connection to the worker; a bug in the task propagates
            return TaskResult.failed(task, f"{type(err).__name__} on a Dask worker: {err}")

    def close(self) -> None:
        """Close the client if this executor opened it."""
        if self._own_client and self._client is not None:
            self._client.close()
        self._client = None
