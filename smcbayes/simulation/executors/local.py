"""Local execution: in the calling process, or in a pool of worker processes."""

from __future__ import annotations

import multiprocessing
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool

from smcbayes.errors import ConfigError
from smcbayes.simulation.objective import Objective, Task, TaskResult

_OBJECTIVE: Objective | None = None


def _init_worker(objective: Objective) -> None:
    global _OBJECTIVE
    _OBJECTIVE = objective


def _run_task(task: Task) -> TaskResult:
    if _OBJECTIVE is None:
        raise RuntimeError("worker started without an objective")
    return _OBJECTIVE.evaluate(task)


class LocalExecutor:
    """Run tasks in this process (``workers == 1``) or in a spawned process pool.

    The pool uses the ``spawn`` start method: forking a process that has run torch's
    thread pools can deadlock the children.  The objective is sent once per worker.

    Args:
        workers: number of processes; 1 runs inline.
    """

    def __init__(self, workers: int = 1) -> None:
        if workers < 1:
            raise ConfigError(f"--workers {workers}: must be at least 1")
        self.workers = workers
        self.rows_per_task: int | None = None
        self._objective: Objective | None = None
        self._pool: ProcessPoolExecutor | None = None

    def start(self, objective: Objective) -> None:
        """Bind the objective; starts the pool when ``workers > 1``."""
        self._objective = objective
        if self.workers > 1:
            self._pool = self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_init_worker, initargs=(self._objective,))

    def run(self, tasks: Sequence[Task]) -> Iterator[TaskResult]:
        """Yield results in completion order; a crashed worker fails its tasks."""
        if self._objective is None:
            raise RuntimeError("LocalExecutor.run before start")
        if self._pool is None:
            for task in tasks:
                yield self._objective.evaluate(task)
            return
        futures: dict[Future[TaskResult], Task] = {self._pool.submit(_run_task, t): t for t in tasks}
        broken = False
        for fut in as_completed(futures):
            try:
                yield fut.result()
            except BrokenProcessPool:
                broken = True
                yield TaskResult.failed(futures[fut], "worker process died")
        if broken:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()

    def close(self) -> None:
        """Shut the pool down."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
