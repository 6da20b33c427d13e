"""Where evaluations run: one small contract, several back ends.

An executor is started with an objective and then runs lists of tasks, yielding each
:class:`~smcbayes.simulation.objective.TaskResult` as soon as it finishes (in any order).
A task that raises or whose worker dies comes back as failed rows, never as an exception.

- :class:`~smcbayes.simulation.executors.local.LocalExecutor`: in-process (1 worker) or a
  local process pool (default);
- :class:`~smcbayes.simulation.executors.dask.DaskExecutor`: a Dask distributed cluster
  (``--scheduler tcp://host:8786``), one task per candidate and configuration.

The external-simulator adapter (:mod:`smcbayes.simulation.executors.external`) is a
simulator, not a scheduler: it runs the user's command for each task under any executor.
"""

from smcbayes.simulation.executors.base import Executor, make_executor

__all__ = ["Executor", "make_executor"]
