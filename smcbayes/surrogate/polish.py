"""Local search from the calibrated point, run on the forward model itself.

The Bayesian optimisation places a few dozen evaluations over the whole search box, the
thesis's answer to a simulator that costs minutes a run.  With a 7-8-dimensional box and a
curved valley (the slip law's tau_c and m trade off, so do the compaction law's modulus
and exponent) its best point can lie far up the valley's wall.  With a forward model that
runs in milliseconds, a derivative-free local search from that point is cheap: Powell's
method of conjugate directions (Powell 1964, "An efficient method for finding the minimum
of a function of several variables without calculating derivatives", Comput. J.
7:155-162), with bounded line searches in the unit cube (SciPy's implementation), on
log(loss), whose scale does not change with the size of the misfit.  It needs no gradient,
so the loss's kinks (a curve reaching the force limit a step earlier or later) do not
mislead it the way finite differences would.

Each evaluation of the search is one round of the run's log (kind ``"polish"``), logged
before it runs and recorded as soon as it is done, as every evaluation of the
calibration.  Powell's method is deterministic, so a search that was killed is resumed by
running it again from the same start: it asks for the same points in the same order, and
those the log already holds are taken from it instead of being run again.  A search
starts from the best evaluation logged before it; a later search (after a resume that
raised the budget of the Bayesian optimisation) starts from the best point then.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

from smcbayes.forward.parameters import ParameterSpace
from smcbayes.run.runlog import LogState

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

POLISH = "polish"
"""The ``kind`` of a local-search round in the evaluation log."""
FAILED_PENALTY = 10.0
"""A failed evaluation counts as the start's log loss plus this much (a fixed value, so a
rerun sees the same numbers whatever the log holds by then)."""
XTOL, FTOL = 1e-4, 1e-6
"""Powell's stopping tolerances: unit-cube step and relative change of log(loss)."""
REPLAY_TOL = 1e-9
"""A rerun's point may differ from the logged one by round-off of another machine."""
SUMMARY_EVERY = 25
"""The run's summary is rewritten after this many evaluations of the search (and at its end)."""


class SearchLog(Protocol):
    """What the local search needs of the calibration loop
    (:class:`~smcbayes.surrogate.loop.BayesOpt`): its parameter space, the log's state,
    and logging and running a round."""

    space: ParameterSpace
    state: LogState

    def log_round(self, rnd: int, first_index: int, unit: Array,
                  kind: str | None = None) -> dict[str, Any]: ...

    def evaluate_round(self, record: dict[str, Any]) -> None: ...


class _BudgetSpent(Exception):
    """The local search has used its evaluations (raised to stop SciPy's loop)."""


class _ReplayMismatch(Exception):
    """A resumed search asks for another point than its log holds (raised to stop it)."""


@dataclass(frozen=True)
class PolishResult:
    """What a local search did.

    Attributes:
        evaluations: evaluations it logged (taken from the log on a resume included).
        start_loss, best_loss: loss (kN^2) at its start and the lowest it found.
        start_index: the evaluation it started from.
        converged: Powell's tolerances stopped it (else its budget did).
    """

    evaluations: int
    start_loss: float
    best_loss: float
    start_index: int
    converged: bool

    def as_dict(self) -> dict[str, Any]:
        """The summary's ``polish`` entry."""
        return {"method": "Powell", "evaluations": self.evaluations, "start_index": self.start_index,
                "start_loss_kN2": self.start_loss, "best_loss_kN2": self.best_loss,
                "converged": self.converged}


def is_search(state: LogState, rnd: int) -> bool:
    """Whether logged round ``rnd`` is an evaluation of a local search."""
    return state.rounds[rnd].get("kind") == POLISH


def phase_rounds(state: LogState) -> list[int]:
    """The rounds of the last local search, in order: the polish rounds after the last round
    of another kind (empty when the log ends with a round of the optimisation)."""
    out: list[int] = []
    for rnd in sorted(state.rounds, reverse=True):
        if not is_search(state, rnd):
            break
        out.append(rnd)
    return out[::-1]


def start_record(state: LogState, before_round: int) -> dict[str, Any] | None:
    """The best successful evaluation of the rounds before ``before_round`` (earliest on ties)."""
    ok = [r for _, r in sorted(state.evaluations.items())
          if r["round"] < before_round and r["loss"] is not None]
    return min(ok, key=lambda r: r["loss"]) if ok else None


def run_polish(bo: SearchLog, budget: int, first_round: int,
               on_summary: Callable[[], None] | None = None) -> PolishResult | None:
    """Run (or resume) the local search of ``bo``'s run from its best point.

    Args:
        bo: the calibration loop, its optimisation finished (its log read).
        budget: most evaluations of the search.
        first_round: the round number of the search's first evaluation (the search's rounds
            follow one another).
        on_summary: called every :data:`SUMMARY_EVERY` evaluations (to rewrite the summary).

    Returns:
        What the search did, or ``None`` when there is nothing to start from or no budget.
    """
    start = start_record(bo.state, first_round)
    if start is None or budget <= 0:
        return None
    space = bo.space
    u0 = np.clip(space.to_unit(np.array([[start["params"][n] for n in space.free_names]]))[0], 0.0, 1.0)
    failed_value = math.log(start["loss"]) + FAILED_PENALTY
    count = [0]

    def log_loss(u: Array) -> float:
        u = np.clip(u, 0.0, 1.0)
        if np.array_equal(u, u0):  # SciPy asks for the start first: it is logged already
            return math.log(start["loss"])
        if count[0] >= budget:
            raise _BudgetSpent
        rec = _evaluate(bo, first_round + count[0], u)
        count[0] += 1
        if on_summary is not None and count[0] % SUMMARY_EVERY == 0:
            on_summary()
        return math.log(rec["loss"]) if rec["loss"] is not None else failed_value

    converged = _powell(log_loss, u0)
    # a resume with a smaller budget leaves logged rounds past it out of this search
    losses = [r["loss"] for r in bo.state.evaluations.values()
              if first_round <= r["round"] < first_round + count[0] and r["loss"] is not None]
    result = PolishResult(count[0], float(start["loss"]), float(min([start["loss"], *losses])),
                          int(start["index"]), converged)
    logger.info("local search: %d evaluations, loss %.6g -> %.6g kN^2 (%s)", result.evaluations,
                result.start_loss, result.best_loss, "converged" if converged else "budget spent")
    return result


def _powell(fun: Callable[[Array], float], u0: Array) -> bool:
    """Minimise ``fun`` over the unit cube from ``u0``; whether Powell's tolerances stopped it."""
    try:
        minimize(fun, u0, method="Powell", bounds=[(0.0, 1.0)] * u0.size,
                 options={"xtol": XTOL, "ftol": FTOL, "maxfev": 10**9})
    except _BudgetSpent:
        return False
    except _ReplayMismatch as err:
        # another SciPy or machine than the one that logged it: what follows in the log
        # answers other points, so the search ends at what it has
        logger.warning("local search: %s; it ends here, at the best point logged so far", err)
        return False
    return True


def _evaluate(bo: SearchLog, rnd: int, u: Array) -> dict[str, Any]:
    """The evaluation of round ``rnd`` at ``u`` ``(d,)``: from the log when it holds the round
    (a resumed search), else logged and run now."""
    record = bo.state.rounds.get(rnd)
    if record is None:
        # every logged evaluation belongs to a logged round: the next index follows the rounds'
        index = 1 + max((i for r in bo.state.rounds.values() for i in r["indices"]), default=-1)
        record = bo.log_round(rnd, index, u[None, :], kind=POLISH)
    elif np.max(np.abs(np.asarray(record["unit"][0]) - u)) > REPLAY_TOL:
        raise _ReplayMismatch(f"round {rnd} of the log is at another point than the resumed search asks for")
    bo.evaluate_round(record)
    return bo.state.evaluations[record["indices"][0]]
