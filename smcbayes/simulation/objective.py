"""What every stage sees of the physics: evaluate parameter vectors on one configuration.

A :class:`Task` is a block of parameter vectors (free parameters, user units) and one
configuration; an :class:`Objective` turns it into a :class:`TaskResult` of per-row errors
and statuses, and the simulated curves when the task asks for them (``curves=True``).
A :class:`Simulator` is anything that turns parameter vectors into curves: the native
forward model and the external-command adapter are the two implementations.  The loss of
an evaluation is the mean of its per-configuration errors over the objective's
configurations (thesis eq. 3.7, ``1/p * sum_k``).  Objectives must be
picklable: executors ship them to worker processes or cluster nodes.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import LossSpec
from smcbayes.data.dataset import Dataset
from smcbayes.data.loss import evaluate_loss
from smcbayes.errors import SolverError
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.parameters import ParameterSpace
from smcbayes.forward.result import STATUS_OK, SimulationResult

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Task:
    """Parameter vectors to evaluate on one configuration.

    Attributes:
        indices: evaluation numbers of the rows, length ``P``.
        theta: free-parameter vectors in user units, shape ``(P, d)``.
        config_id: the configuration.
        curves: return the simulated curves with the errors.
        attempt: 0 for the first run of these rows, ``k`` for their ``k``-th retry after a
            failure (:class:`~smcbayes.simulation.runner.RetryObjective`).
    """

    indices: tuple[int, ...]
    theta: Array
    config_id: str
    curves: bool = False
    attempt: int = 0


@dataclass(frozen=True)
class TaskResult:
    """Errors of a task's rows on its configuration.

    Attributes:
        indices: evaluation numbers, length ``P``.
        config_id: the configuration.
        error: weighted error of each row (the configuration's loss term), shape ``(P,)``;
            NaN where the row failed.
        force_mse_kN2: force mean squared error, shape ``(P,)`` (kN^2).
        displacement_mse_mm2: displacement mean squared error, shape ``(P,)`` (mm^2).
        status: ``"ok"`` or ``"failed: reason"`` per row.
        seconds: wall time of the whole task (s), retries included.
        curves: the simulated curves of the rows (``P`` rows) if the task asked for them.
        retried: row runs repeated after failures (retries), on top of the ``P`` first runs.
    """

    indices: tuple[int, ...]
    config_id: str
    error: Array
    force_mse_kN2: Array
    displacement_mse_mm2: Array
    status: list[str]
    seconds: float
    curves: SimulationResult | None = None
    retried: int = 0

    @staticmethod
    def failed(task: Task, reason: str, seconds: float = 0.0) -> TaskResult:
        """Every row of ``task`` failed for ``reason``."""
        nan = np.full(len(task.indices), np.nan)
        status = [f"failed: {reason}"] * len(task.indices)
        return TaskResult(task.indices, task.config_id, nan, nan.copy(), nan.copy(), status, seconds)


class Objective(Protocol):
    """The contract between the optimiser and whatever computes errors."""

    space: ParameterSpace
    config_ids: list[str]

    def evaluate(self, task: Task) -> TaskResult:
        """Errors of the task's rows on its configuration; never raises for a bad row."""
        ...


class Simulator(Protocol):
    """The one simulator contract of every stage: parameter vectors -> curves.

    Implemented by :class:`~smcbayes.forward.model.ForwardModel` (the native 1-D and 2-D
    solvers) and :class:`~smcbayes.simulation.executors.external.ExternalSimulator` (the
    user's own solver).  A row that fails has a ``"failed: reason"`` status and NaN curves;
    ``simulate`` raises only for bad input (:class:`~smcbayes.errors.InputError`) or a
    failure of the whole batch (:class:`~smcbayes.errors.SolverError`).
    """

    space: ParameterSpace

    def simulate(self, theta: Array, config_ids: Sequence[str]) -> dict[str, SimulationResult]:
        """Curves for ``theta`` ``(P, d)`` (free parameters, user units) on each configuration."""
        ...


def _row_status(result: SimulationResult, error: Array) -> list[str]:
    out = []
    for status, value in zip(result.status, error, strict=True):
        if status != STATUS_OK:
            out.append(status if status.startswith("failed") else f"failed: {status}")
        elif not np.isfinite(value):
            out.append("failed: non-finite error (simulated curve has NaN or inf)")
        else:
            out.append(STATUS_OK)
    return out


class SimulatorObjective:
    """Errors of a simulator's curves against a measured dataset (the data layer's loss).

    Args:
        simulator: a :class:`~smcbayes.forward.model.ForwardModel` or an external adapter.
        dataset: measured curves; configurations without data give NaN errors.
        config_ids: configurations that enter the loss (e.g. the training set).
        loss_spec: weights, grid and clipping of the loss; default when ``None``.
    """

    def __init__(self, simulator: Simulator, dataset: Dataset, config_ids: Sequence[str],
                 loss_spec: LossSpec | None = None) -> None:
        self.simulator = simulator
        self.space = simulator.space
        self.dataset = dataset
        self.config_ids = list(config_ids)
        self.loss_spec = loss_spec

    @property
    def deterministic(self) -> bool:
        """Whether a failed row would fail again: true of the native model, whose retries
        are skipped; an external command may fail transiently (licence, disk, node)."""
        return isinstance(self.simulator, ForwardModel)

    def evaluate(self, task: Task) -> TaskResult:
        """Simulate the task's rows on its configuration and score them.

        Only the objective's own configurations (those of the loss) are scored; any other
        (a validation trial, with or without data) gets NaN errors and the simulator's
        statuses: its curves can still be asked for.  A solver's numerical failure
        (:class:`SolverError`, an arithmetic or linear-algebra error) fails the task's rows;
        any other exception is a bug and propagates.
        """
        start = time.perf_counter()
        try:
            results = self.simulator.simulate(task.theta, [task.config_id])
        except (SolverError, ArithmeticError, np.linalg.LinAlgError) as err:
            return TaskResult.failed(task, f"{type(err).__name__}: {err}", time.perf_counter() - start)
        result = results[task.config_id]
        curves = result if task.curves else None
        if task.config_id not in self.config_ids:
            nan = np.full(result.rows, np.nan)
            status = [s if s == STATUS_OK or s.startswith("failed") else f"failed: {s}"
                      for s in result.status]
            return TaskResult(task.indices, task.config_id, nan, nan.copy(), nan.copy(), status,
                              time.perf_counter() - start, curves)
        spec = self.loss_spec if self.loss_spec is not None else LossSpec()
        loss = evaluate_loss(results, self.dataset, spec, ids=[task.config_id])
        error = np.asarray(loss.total, dtype=float).reshape(-1)
        status = _row_status(result, error)
        bad = np.array([s != STATUS_OK for s in status])
        error = np.where(bad, np.nan, error)
        return TaskResult(task.indices, task.config_id, error,
                          np.asarray(loss.force_mse_kN2, dtype=float)[:, 0],
                          np.asarray(loss.displacement_mse_mm2, dtype=float)[:, 0],
                          status, time.perf_counter() - start, curves)


class QuadraticObjective:
    """An analytic test objective with a known minimum, for checking the optimiser.

    Configuration ``k`` contributes ``scale * (floor + sum_j c_kj (u_j - u*_j)^2)`` with
    ``u`` the unit-cube coordinates, so the loss is smooth, positive and minimal at the
    truth; ``delay_s`` imitates a slow simulator.

    Args:
        space: parameter space (defines the unit cube).
        truth: true free-parameter values in user units, length ``d``.
        config_ids: names of the pseudo-configurations.
        seed: draws the per-configuration curvatures ``c_kj`` in [0.5, 2].
        delay_s: sleep per task (s).
    """

    def __init__(self, space: ParameterSpace, truth: Sequence[float], config_ids: Sequence[str],
                 seed: int = 0, delay_s: float = 0.0, scale: float = 1e3, floor: float = 1e-3) -> None:
        self.space = space
        self.config_ids = list(config_ids)
        self.truth_unit = space.to_unit(np.asarray(truth, dtype=float)[None, :])[0]
        rng = np.random.default_rng(seed)
        self.curvature = {c: rng.uniform(0.5, 2.0, space.dim) for c in self.config_ids}
        self.delay_s = delay_s
        self.scale = scale
        self.floor = floor
        self.deterministic = True

    def evaluate(self, task: Task) -> TaskResult:
        """Analytic errors of the task's rows."""
        start = time.perf_counter()
        if self.delay_s > 0:
            time.sleep(self.delay_s)
        u = self.space.to_unit(task.theta)
        c = self.curvature[task.config_id]
        err = self.scale * (self.floor + ((u - self.truth_unit) ** 2 * c).sum(axis=1))
        status = [STATUS_OK] * len(task.indices)
        return TaskResult(task.indices, task.config_id, err, err.copy(),
                          np.zeros_like(err), status, time.perf_counter() - start)


class InterruptingObjective:
    """A test objective that stops the process, as Ctrl-C does, at the first run of one
    evaluation, then passes everything to ``inner``.

    Args:
        inner: the objective that answers.
        index: the evaluation whose first run raises :class:`KeyboardInterrupt`.
    """

    def __init__(self, inner: Objective, index: int) -> None:
        self.inner = inner
        self.space = inner.space
        self.config_ids = inner.config_ids
        self.index = index
        self.armed = True

    def evaluate(self, task: Task) -> TaskResult:
        """``inner``'s answer, or the interruption."""
        if self.armed and self.index in task.indices:
            self.armed = False
            raise KeyboardInterrupt
        return self.inner.evaluate(task)


class FlakyObjective:
    """A test objective that fails a share of its runs at random, reproducibly.

    Each (evaluation, configuration, attempt) fails with probability ``share``, decided by
    a hash of the three and ``seed``: independent transient failures, the same in every
    run, interrupted or not (a retry is a new draw).

    Args:
        inner: the objective whose rows are failed.
        share: probability that one run fails (0-1).
        seed: seeds the failure draws.
    """

    deterministic = False

    def __init__(self, inner: Objective, share: float = 0.2, seed: int = 0) -> None:
        self.inner = inner
        self.space = inner.space
        self.config_ids = inner.config_ids
        self.share = share
        self.seed = seed

    def fails(self, index: int, config_id: str, attempt: int) -> bool:
        """Whether that run fails."""
        key = f"{self.seed}/{index}/{config_id}/{attempt}".encode()
        return int(hashlib.sha256(key).hexdigest()[:13], 16) / 16**13 < self.share

    def evaluate(self, task: Task) -> TaskResult:
        """The inner errors, with the drawn failures as failed rows."""
        res = self.inner.evaluate(task)
        bad = np.array([self.fails(i, task.config_id, task.attempt) for i in task.indices], dtype=bool)
        status = ["failed: injected transient failure" if b else s
                  for s, b in zip(res.status, bad, strict=True)]
        nan_where = lambda a: np.where(bad, np.nan, a)  # noqa: E731
        return TaskResult(res.indices, res.config_id, nan_where(res.error), nan_where(res.force_mse_kN2),
                          nan_where(res.displacement_mse_mm2), status, res.seconds, res.curves)


def combine(errors: Mapping[str, float], config_ids: Sequence[str]) -> float:
    """Loss of one evaluation: mean of its per-configuration errors (NaN if any is missing)."""
    values = [errors.get(c, np.nan) for c in config_ids]
    return float(np.mean(values)) if values else float("nan")
